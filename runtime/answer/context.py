"""One question being executed: the map's index, the conventions, and what the answer read (its evidence).

An executor is a function `(node, ctx) -> (value, explanation)`; `ctx` is created for that one call by
`execute.execute` and records the instances used, the per-view spread of the asked quantity and the names that
matched several instances, from which the answer's evidence is built. Nothing outlives the call.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..query.ir import At, Closest, Described, InstanceId, NearestTo, Ref, Superlative, SUPERLATIVES, everything
from ..query.vocabulary import name_key
from .boxes import measure, relation_holds
from .index import MapIndex
from .spatial import closest_pair
from .result import NotFound, ReasonerConfig, Unsupported


class Ctx:
    """index: the map's `MapIndex`; conf: `ReasonerConfig`; options: the question's options (may be empty);
    used / spread / ambiguous: the evidence collected while executing."""

    def __init__(self, index: MapIndex, conf: ReasonerConfig, options: tuple = ()):
        self.index, self.map, self.conf, self.options = index, index.map, conf, options
        self.used: list[Any] = []
        self.spread: tuple[str, list[float], str | None] | None = None  # (quantity, per-view values, unit)
        self.ambiguous: list[dict[str, Any]] = []
        self.cache: dict[Any, Any] = {}  # this question's derived structures (spatial indices of its references)

    # ------------------------------------------------------------------ names
    def find(self, ref: Ref) -> list[Any]:
        return self.index.find(ref.name, ref.words)

    @staticmethod
    def one(ref: Ref) -> str:
        """The question's words for one instance, singular ("the office chairs" -> "office chair")."""
        return name_key(ref.words) or ref.name

    def missing(self, refs: list[Ref]) -> None:
        """NotFound for the references the map has no instance of (with similar map names as hints)."""
        seen: dict[str, Ref] = {}
        for r in refs:
            seen.setdefault(r.name, r)
        gone = [r for r in seen.values() if not self.find(r)]
        if gone:
            raise NotFound([self.one(r) for r in gone],
                           [h for r in gone for h in self.index.hints(r.words, self.conf.n_hints)])

    def instances(self, ref: Ref) -> list[Any]:
        """The instances of one reference, its selectors applied (recorded as used)."""
        self.missing([ref])
        out = self.select(ref, self.find(ref))
        self.used += out
        return out

    def require(self, refs: list[Ref], select: bool = True) -> dict[str, list[Any]]:
        """name -> selected instances of each reference; NotFound for any the map lacks (and any a selector
        needs). select False: the instances unselected (the caller selects, e.g. from a walker's position)."""
        self.missing(list(refs) + [Ref(s.name, s.phrase) for r in refs for s in r.select
                                   if isinstance(s, (NearestTo, At))])
        if not select:
            return {r.name: self.find(r) for r in refs}
        out = {r.name: self.select(r, self.find(r)) for r in refs}
        self.used += [o for v in out.values() for o in v]
        return out

    def select(self, ref: Ref, inst: list[Any], viewer_xy: np.ndarray | None = None) -> list[Any]:
        """Apply the reference's selectors ("the biggest table", "the chair nearest the door", "chair #3", "the
        laptop on the desk", "the closest sofa": from `viewer_xy [2]`, else the last camera); colours, materials
        and ordinals are not in a map: unsupported, said so."""
        if not ref.select:
            return inst
        for s in ref.select:
            if isinstance(s, Described) and not self.index.has_category(s.phrase):
                raise Unsupported(f"'{s.phrase}': the map has no colours, materials or order of instances, so it "
                                  f"cannot tell which {ref.words} that is; ask about the {ref.words} without "
                                  f"'{' '.join(s.words)}'")
        out = inst
        if not out:
            return out  # nothing to pick from: the caller says the name is missing
        for s in ref.select:
            if isinstance(s, Superlative):
                key, pick = SUPERLATIVES[s.word]
                out = [pick(out, key=lambda o: measure(o, key))]
            elif isinstance(s, InstanceId):
                out = [o for o in out if int(o.id) == s.id]
                if not out:
                    raise NotFound([f"{self.one(ref)} #{s.id}"], [f"{self.one(ref)} #{o.id}" for o in inst[:3]])
            elif isinstance(s, At):
                at = Ref(s.name, s.phrase)
                self.missing([at])
                others = self.find(at)
                out = [o for o in out if any(relation_holds(o, r, s.relation, self.conf) for r in others
                                             if r is not o)]
                if not out:
                    raise Unsupported(f"no {ref.words} is {s.relation} the {s.words} in the map")
            elif isinstance(s, Closest):
                if viewer_xy is None:
                    viewer_xy = self.viewer(f"'the {s.extreme} {ref.words}' needs",
                                            f"for the {ref.words} nearest another object")[:2, 3]
                far = s.extreme == "farthest"
                out = [(max if far else min)(out, key=lambda o: float(np.linalg.norm(o.center[:2] - viewer_xy)))]
        for s in ref.select:
            if isinstance(s, NearestTo):
                near = Ref(s.name, s.phrase)
                self.missing([near])  # "the chair nearest the door" needs a door in the map
                try:  # the instance nearest any of them (the first of equals)
                    out = [closest_pair(out, self.find(near))[1]]
                except Unsupported:  # no other instance to measure to
                    out = out[:1]
        return out

    def choice(self, ref: Ref, inst: list[Any], used: Any, rule: str, values: dict[int, float] | None = None,
               unit: str | None = None) -> None:
        """Record that the question's `ref` matched several instances and which one the answer used (`rule`: how
        it was picked; `values`: the asked quantity with each instance instead, by id)."""
        if len(inst) < 2:
            return
        ids = [int(o.id) for o in inst]
        shown = ids[:self.conf.n_alternatives] + ([int(used.id)] if int(used.id) not in ids[:self.conf.n_alternatives]
                                                  else [])
        self.ambiguous.append({"name": self.one(ref), "instances": shown, "n_instances": len(ids), "used": int(used.id),
                               "rule": rule, "unit": unit,
                               "alternatives": None if values is None else
                               {int(k): round(float(v), 3) for k, v in values.items()}})

    # ------------------------------------------------------------------ places
    def viewer(self, need: str, instead: str) -> np.ndarray:
        """The viewer's pose T_wc [4, 4]: the last camera (where the video ended). Without a camera track the
        question is unsupported: "{need} a viewpoint ...; ask {instead}"."""
        if not self.map.cameras:
            raise Unsupported(f"{need} a viewpoint: this map has no camera track; ask {instead}")
        return np.asarray(self.map.cameras[-1][1], float)

    def pick_unique(self, ref: Ref, near: list[np.ndarray]) -> tuple[Any, str]:
        """The instance of `ref` to use as a position: the only one, or the one nearest the other objects."""
        inst = self.instances(ref)
        if len(inst) == 1 or not near:
            return inst[0], ""
        c = np.mean(near, 0)
        o = min(inst, key=lambda o: float(np.linalg.norm(o.center[:2] - c[:2])))
        self.choice(ref, inst, o, "the one nearest the other objects")
        return o, f"; {ref.words}: {len(inst)} instances, used #{o.id} (nearest the other objects)"


def is_everything(ref: Ref) -> bool:
    return everything(ref) or name_key(ref.name) in ("thing", "object", "item")
