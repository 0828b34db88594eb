"""Visual prompt: the semantic map rendered for the VLM (paper, "Spatial reasoning via visual prompts").

Three modes (the paper's main variant and its two ablations):
- ``grid``   top-down grid image, one distinct colour per object box with its label, camera positions and
             headings, a metric scale bar and axes, plus the text block (default);
- ``points`` a dense top-down render of the fused 3D points (coloured per instance) instead of boxes, plus text;
- ``text``   the text block only (no image);
- ``json``   a compact JSON "spatial code" of the objects only (no image; the training-free JSON-to-VLM method).

The image is drawn in the map's z-up world seen from above: +x to the right, +y up the image.
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import cv2
import numpy as np

from .infra.config import StageConf
from .infra import jsonio
from .infra.errors import InputError
from .geometry import box_footprint
from .map.model import SemanticMap
from pathlib import Path
from .infra.outputs import encode_png

MODES = ("grid", "points", "text", "json")


@dataclass
class PromptConfig(StageConf):
    mode: str = "grid"
    size_px: int = 768          # longest image side
    margin_px: int = 48
    grid_m: float = 1.0         # grid spacing (m)
    font_scale: float = 0.45
    camera_stride: int = 1      # draw every n-th camera

    conf_name: ClassVar[str] = "prompt config"

    def validate(self) -> None:
        if self.mode not in MODES:
            raise InputError(f"prompt config: mode must be one of {MODES}, got {self.mode!r}")
        if not (64 <= self.size_px <= 8192 and 0 <= self.margin_px < self.size_px // 2):
            raise InputError(f"prompt config: need 64 <= size_px <= 8192 and 0 <= margin_px < size_px / 2 "
                             f"(got {self.size_px}, {self.margin_px})")
        if not (self.grid_m > 0 and self.font_scale > 0 and self.camera_stride >= 1):
            raise InputError("prompt config: grid_m and font_scale must be > 0, camera_stride >= 1")


default_conf = PromptConfig()


@dataclass
class VisualPrompt:
    """image: [H, W, 3] uint8 RGB or None (text mode); text: the object block; colours: instance id -> RGB;
    px_per_m: image scale; origin_px: pixel of world (0, 0); scale_bar_m / scale_bar_px: the drawn bar."""

    image: np.ndarray | None
    text: str
    colours: dict[int, tuple[int, int, int]] = field(default_factory=dict)
    px_per_m: float = 0.0
    origin_px: tuple[float, float] = (0.0, 0.0)
    scale_bar_m: float = 0.0
    scale_bar_px: int = 0
    mode: str = "grid"
    labels_drawn: int = 0

    def world_to_px(self, xy: np.ndarray) -> np.ndarray:
        """World `[N, 2]` (x, y metres) -> image pixels `[N, 2]` (u, v)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.stack([self.origin_px[0] + xy[:, 0] * self.px_per_m,
                         self.origin_px[1] - xy[:, 1] * self.px_per_m], 1)

    def full_text(self, question: str | None = None, options: list[str] | None = None) -> str:
        """The text the VLM gets with the image (`prompt.txt`): the whole prompt for a question (`vlm_prompt`),
        else the object block."""
        body = vlm_prompt(question, options, self.text, self.mode) if question else self.text
        return body.rstrip() + "\n"

    def save_text(self, path: str, question: str | None = None, options: list[str] | None = None) -> None:
        Path(path).write_text(self.full_text(question, options))

    def save_png(self, path: str) -> None:
        if self.image is None:
            raise ValueError("text-only prompt has no image")

        with open(path, "wb") as f:
            f.write(encode_png(self.image))


def distinct_colours(n: int) -> list[tuple[int, int, int]]:
    """`n` well-separated saturated RGB colours (golden-ratio hue walk, alternating lightness); colorsys's
    HLS -> RGB, vectorised (a 100 k-object map needs one colour per object)."""
    i = np.arange(n)
    h = (0.07 + i * 0.618033988749895) % 1.0
    light = np.where(i % 2 == 0, 0.45, 0.6)
    s = 0.85
    m2 = np.where(light <= 0.5, light * (1.0 + s), light + s - light * s)
    m1 = 2.0 * light - m2

    def v(hue: np.ndarray) -> np.ndarray:
        hue = hue % 1.0
        return np.select([hue < 1 / 6, hue < 0.5, hue < 2 / 3],
                         [m1 + (m2 - m1) * hue * 6.0, m2, m1 + (m2 - m1) * (2 / 3 - hue) * 6.0], m1)

    rgb = (np.stack([v(h + 1 / 3), v(h), v(h - 1 / 3)], 1) * 255).astype(int)
    return [tuple(c) for c in rgb.tolist()]


def box_arrays(smap: SemanticMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every instance's centroid [N, 3], axis lengths [N, 3] and axes [N, 3, 3] (rows), stacked once
    (`SemanticMap.box_arrays`)."""
    return smap.box_arrays()


def footprints(C: np.ndarray, L: np.ndarray, AX: np.ndarray) -> np.ndarray:
    """Floor footprints [N, 4, 2] of boxes (centroids [N, 3], lengths [N, 3], axes [N, 3, 3]):
    `geometry.box_footprint` for all boxes at once."""
    n = len(C)
    horiz = np.argsort(np.abs(AX[:, :, 2]), axis=1, kind="stable")[:, :2]
    r = np.arange(n)
    a = AX[r, horiz[:, 0], :2] * (L[r, horiz[:, 0]] / 2)[:, None]
    b = AX[r, horiz[:, 1], :2] * (L[r, horiz[:, 1]] / 2)[:, None]
    c = C[:, :2]
    return np.stack([c - a - b, c + a - b, c + a + b, c - a + b], 1)


_LINE = "- %s #%d: centre (%.2f, %.2f, %.2f), size (%.2f x %.2f x %.2f), yaw %.0f deg"


def text_block(smap: SemanticMap, arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> str:
    """One line per object: label, centre and size (m) and yaw in map coordinates (x right, y forward, z up).
    arrays: `box_arrays(smap)` when the caller has them."""
    lines = ["Objects in the map (metres; x right, y forward, z up; size = length x width x height):"]
    C, L, AX = arrays if arrays is not None else box_arrays(smap)
    if len(C):
        yaw = np.degrees(np.arctan2(AX[:, 0, 1], AX[:, 0, 0]))
        insts = smap.instances
        names = [o.name for o in insts]
        ids = np.array([o.id for o in insts])
        rank = {k: r for r, k in enumerate(sorted(set(names)))}
        order = np.lexsort((ids, np.fromiter(map(rank.__getitem__, names), np.int64, len(names))))  # name, id
        rows = np.concatenate([C, L, yaw[:, None]], 1)[order].tolist()
        lines += [_LINE % (names[i], ids_i, *r) for i, ids_i, r in zip(order.tolist(), ids[order].tolist(), rows)]
    if smap.cameras:
        t0, T0 = smap.cameras[0]
        t1, T1 = smap.cameras[-1]
        lines.append(f"Camera: first at ({T0[0, 3]:.2f}, {T0[1, 3]:.2f}) t={t0:.1f}s, "
                     f"last at ({T1[0, 3]:.2f}, {T1[1, 3]:.2f}) t={t1:.1f}s")
    if smap.room is not None:
        lines.append(f"Room floor area about {smap.room.area():.1f} m^2")
    return "\n".join(lines)


def json_block(smap: SemanticMap) -> str:
    """Compact JSON "spatial code": {"units": "m", "axes": "x right, y forward, z up", "objects": [{"id", "label",
    "center": [x, y, z], "size": [l, w, h], "yaw_deg"}], "camera": {"first", "last"}?, "floor_area_m2"?} (2 decimals)."""
    objs = []
    for o in sorted(smap.instances, key=lambda o: (o.name, o.id)):
        ax = np.asarray(o.box.axes)
        objs.append({"id": int(o.id), "label": o.name,
                     "center": [round(float(v), 2) for v in np.asarray(o.box.centroid)],
                     "size": [round(float(v), 2) for v in np.asarray(o.box.axes_lengths)],
                     "yaw_deg": round(float(np.degrees(np.arctan2(ax[0][1], ax[0][0]))))})
    code: dict[str, Any] = {"units": "m", "axes": "x right, y forward, z up", "objects": objs}
    if smap.cameras:
        (t0, T0), (t1, T1) = smap.cameras[0], smap.cameras[-1]
        code["camera"] = {"first": [round(float(T0[0, 3]), 2), round(float(T0[1, 3]), 2), round(float(t0), 1)],
                          "last": [round(float(T1[0, 3]), 2), round(float(T1[1, 3]), 2), round(float(t1), 1)]}
    if smap.room is not None:
        code["floor_area_m2"] = round(float(smap.room.area()), 1)
    return jsonio.dumps(code, separators=(",", ":"))


def _nice_length(max_m: float) -> float:
    """Largest 1/2/5 x 10^k length not above max_m."""
    k = np.floor(np.log10(max_m))
    for m in (5, 2, 1):
        if m * 10**k <= max_m:
            return float(m * 10**k)
    return float(10**k)


_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


def _extent(smap: SemanticMap, points: np.ndarray | None, arrays: tuple[np.ndarray, ...]
            ) -> tuple[np.ndarray, np.ndarray]:
    C, L, AX = arrays
    pts = []
    if len(C):  # the 8 corners of every box: centroid + (signs * half lengths) @ axes
        corners = C[:, None, :] + np.einsum("nkj,nji->nki", _SIGNS[None] * (L[:, None, :] / 2), AX)
        pts.append(corners[:, :, :2].reshape(-1, 2))
    pts += [np.asarray(T)[None, :2, 3] for _, T in smap.cameras]
    if smap.room is not None:
        pts.append(np.asarray(smap.room.polygon).reshape(-1, 2))
    if points is not None and len(points):
        pts.append(np.asarray(points)[:, :2])
    if not pts:
        return np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    allp = np.concatenate(pts, 0)
    lo, hi = allp.min(0), allp.max(0)
    pad = np.maximum(0.25, 0.05 * (hi - lo))
    return lo - pad, hi + pad


def _canvas(smap: SemanticMap, points: np.ndarray | None, conf: PromptConfig, text: str,
            colours: dict[int, tuple[int, int, int]], arrays: tuple[np.ndarray, ...]
            ) -> tuple[VisualPrompt, np.ndarray, np.ndarray, np.ndarray]:
    """The image's scale and origin from the map's extent, a white image. Returns (prompt, image, lo, hi)."""
    lo, hi = _extent(smap, points, arrays)
    span = hi - lo
    inner = conf.size_px - 2 * conf.margin_px
    ppm = inner / float(max(span))
    W = int(round(span[0] * ppm)) + 2 * conf.margin_px
    H = int(round(span[1] * ppm)) + 2 * conf.margin_px
    origin = (conf.margin_px - lo[0] * ppm, conf.margin_px + hi[1] * ppm)
    vp = VisualPrompt(None, text, colours, ppm, origin, mode=conf.mode)
    return vp, np.full((H, W, 3), 255, np.uint8), lo, hi


def _draw_grid_room(img: np.ndarray, vp: VisualPrompt, smap: SemanticMap, lo: np.ndarray, hi: np.ndarray,
                    g: float) -> None:
    """Grid lines every g metres and the room outline."""
    H, W = img.shape[:2]
    for x in np.arange(np.ceil(lo[0] / g) * g, hi[0], g):
        u = int(round(vp.world_to_px([[x, 0]])[0, 0]))
        cv2.line(img, (u, 0), (u, H - 1), (225, 225, 225), 1)
    for y in np.arange(np.ceil(lo[1] / g) * g, hi[1], g):
        v = int(round(vp.world_to_px([[0, y]])[0, 1]))
        cv2.line(img, (0, v), (W - 1, v), (225, 225, 225), 1)
    if smap.room is not None:
        poly = vp.world_to_px(smap.room.polygon).round().astype(np.int32)
        cv2.polylines(img, [poly], True, (150, 150, 150), 2, cv2.LINE_AA)


def _draw_points(img: np.ndarray, vp: VisualPrompt, points: np.ndarray, point_ids: np.ndarray | None,
                 colours: dict[int, tuple[int, int, int]]) -> None:
    H, W = img.shape[:2]
    uv = vp.world_to_px(np.asarray(points)[:, :2]).round().astype(int)
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    col = np.array([colours.get(int(i), (80, 80, 80)) for i in (point_ids if point_ids is not None
                                                                 else np.full(len(uv), -1))], np.uint8)
    img[uv[ok, 1], uv[ok, 0]] = col[ok]


_DENSE = 2000  # objects above which outlines are drawn thin and without anti-aliasing (7x cheaper per object)


def _draw_objects(img: np.ndarray, vp: VisualPrompt, smap: SemanticMap, colours: dict[int, tuple[int, int, int]],
                  fill: bool, arrays: tuple[np.ndarray, ...]) -> None:
    """Each object's footprint outline, over one translucent layer of the filled footprints in the grid mode
    (footprints computed for all boxes at once; one blend for the whole image)."""
    if not smap.instances:
        return
    polys = vp.world_to_px(footprints(*arrays).reshape(-1, 2)).round().astype(np.int32).reshape(-1, 4, 2)
    cols = [colours[o.id] for o in smap.instances]
    if fill:
        overlay = img.copy()
        for poly, col in zip(polys, cols):
            cv2.fillPoly(overlay, [poly], col)
        img[:] = cv2.addWeighted(overlay, 0.45, img, 0.55, 0)
    thick, line = (2, cv2.LINE_AA) if len(polys) <= _DENSE else (1, cv2.LINE_8)
    for poly, col in zip(polys, cols):
        cv2.polylines(img, [poly], True, col, thick, line)


def _draw_cameras(img: np.ndarray, vp: VisualPrompt, smap: SemanticMap, stride: int) -> None:
    """Cameras: dot + heading (camera z axis projected on the floor)."""
    for i, (_, T) in enumerate(smap.cameras):
        if i % max(1, stride):
            continue
        T = np.asarray(T)
        p = vp.world_to_px(T[None, :2, 3])[0]
        f = T[:2, 2]
        n = np.linalg.norm(f)
        q = p + (np.array([f[0], -f[1]]) / n * 0.3 * vp.px_per_m if n > 1e-6 else 0)
        cv2.circle(img, (int(p[0]), int(p[1])), 3, (0, 0, 0), -1, cv2.LINE_AA)
        cv2.arrowedLine(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), (0, 0, 0), 1, cv2.LINE_AA,
                        tipLength=0.3)


def _draw_scale_axes(img: np.ndarray, vp: VisualPrompt, span_x: float, conf: PromptConfig) -> None:
    """Scale bar (bottom left) and axes (bottom right); the bar is recorded in the prompt."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    H, W = img.shape[:2]
    bar_m = _nice_length(0.3 * span_x)
    bar_px = int(round(bar_m * vp.px_per_m))
    y0 = H - conf.margin_px // 2
    x0 = conf.margin_px // 2
    cv2.line(img, (x0, y0), (x0 + bar_px, y0), (0, 0, 0), 3)
    for xx in (x0, x0 + bar_px):
        cv2.line(img, (xx, y0 - 5), (xx, y0 + 5), (0, 0, 0), 2)
    cv2.putText(img, f"{bar_m:g} m", (x0, y0 - 8), font, conf.font_scale, (0, 0, 0), 1, cv2.LINE_AA)
    ax = (W - conf.margin_px // 2 - 40, H - conf.margin_px // 2)
    cv2.arrowedLine(img, ax, (ax[0] + 35, ax[1]), (200, 0, 0), 2, tipLength=0.25)
    cv2.arrowedLine(img, ax, (ax[0], ax[1] - 35), (0, 150, 0), 2, tipLength=0.25)
    cv2.putText(img, "x", (ax[0] + 37, ax[1] + 4), font, conf.font_scale, (200, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "y", (ax[0] - 4, ax[1] - 38), font, conf.font_scale, (0, 150, 0), 1, cv2.LINE_AA)
    vp.scale_bar_m, vp.scale_bar_px = bar_m, bar_px


def render(smap: SemanticMap, conf: PromptConfig | dict[str, Any] | None = None,
           points: np.ndarray | None = None, point_ids: np.ndarray | None = None) -> VisualPrompt:
    """Render the visual prompt of `smap`.

    points: [N, 3] world points for the ``points`` mode (optional in other modes); point_ids: [N] instance ids.
    Returns a `VisualPrompt` (image [H, W, 3] uint8 RGB unless mode is ``text``).
    """
    conf = PromptConfig.merged(conf)  # defaults + overrides; an unknown key or a bad value names itself
    arrays = box_arrays(smap)
    text = text_block(smap, arrays)
    ids = [o.id for o in smap.instances]
    colours = dict(zip(ids, distinct_colours(len(ids))))
    if conf.mode == "text":
        return VisualPrompt(None, text, colours, mode="text")
    if conf.mode == "json":
        return VisualPrompt(None, json_block(smap), colours, mode="json")
    vp, img, lo, hi = _canvas(smap, points, conf, text, colours, arrays)
    _draw_grid_room(img, vp, smap, lo, hi, conf.grid_m)
    if conf.mode == "points" and points is not None and len(points):
        _draw_points(img, vp, points, point_ids, colours)
    _draw_objects(img, vp, smap, colours, conf.mode == "grid", arrays)
    _draw_cameras(img, vp, smap, conf.camera_stride)
    font = cv2.FONT_HERSHEY_SIMPLEX
    title = (f"Semantic map, top view: {len(smap.instances)} object(s), {len(smap.cameras)} camera(s), "
             f"grid {conf.grid_m:g} m")
    (tw, th), _ = cv2.getTextSize(title, font, conf.font_scale * 1.1, 1)
    t_org = (conf.margin_px // 2, max(th + 2, conf.margin_px // 2))
    more = f", labels on {len(smap.instances)} (no room for the rest; all are in the text)"
    tw_more = cv2.getTextSize(title + more, font, conf.font_scale * 1.1, 1)[0][0]  # room for the longer title
    vp.labels_drawn = _draw_labels(img, vp, smap, colours, conf,
                                   [np.array([t_org[0], 0, t_org[0] + max(tw, tw_more), t_org[1] + 4])], arrays)
    if vp.labels_drawn < len(smap.instances):
        title += more.replace(str(len(smap.instances)), str(vp.labels_drawn), 1)
    cv2.putText(img, title, t_org, font, conf.font_scale * 1.1, (0, 0, 0), 1, cv2.LINE_AA)
    _draw_scale_axes(img, vp, float((hi - lo)[0]), conf)
    vp.image = img
    return vp


_DIRS = np.array([[0, -1], [0, 1], [1, 0], [-1, 0], [1, -1], [-1, -1], [1, 1], [-1, 1]], np.float64)
_GRID_PX = 64        # cell of the index of placed labels
_MAX_FAILS = 3       # labels that found no spot around one anchor cell before the rest there are culled


def place_labels(anchors: np.ndarray, sizes: np.ndarray | Callable[[int], tuple[float, float]],
                 image_wh: tuple[int, int], pad: int = 2, reserved: list[np.ndarray] | None = None,
                 rings: int = 8) -> np.ndarray:
    """Greedy label placement: each label [w, h] px goes centred on its anchor [u, v] px if that overlaps no label
    placed before it, else at the nearest free spot on rings around the anchor (8 directions, growing radius),
    inside the image. anchors [N, 2], sizes [N, 2] (or `sizes(i) -> (w, h)`, asked only for the labels tried)
    -> top-left corners [N, 2] float, NaN for a label that found
    no free spot within reach (culled, not drawn over the others: the text block lists every object). Labels
    are placed in the given order. reserved: boxes [x0, y0, x1, y1] no label may cover (the title).

    Placed labels sit in a grid index (`_GRID_PX` cells), so a candidate spot is checked against the few labels
    near it; once `_MAX_FAILS` labels around one anchor cell found no spot, later ones there are culled without a
    search. Each label costs O(1): a 100 000-object map places its labels in well under a second."""
    anchors = np.asarray(anchors, np.float64).reshape(-1, 2)
    size_of = sizes if callable(sizes) else np.asarray(sizes, np.float64).reshape(-1, 2).__getitem__
    h_cell = 2 * float(size_of(0)[1]) + 1 if len(anchors) else 1.0  # anchor cells about two labels high
    W, H = image_wh
    out = np.full_like(anchors, np.nan)
    rects = np.zeros((max(16, len(reserved or [])), 4))
    grid: dict[tuple[int, int], list[int]] = {}
    fails: dict[int, int] = {}
    n_rects = 0

    def add(r: np.ndarray) -> None:
        nonlocal rects, n_rects
        if n_rects == len(rects):
            rects = np.concatenate([rects, np.zeros_like(rects)])
        rects[n_rects] = r
        for gx in range(int(r[0] // _GRID_PX), int(r[2] // _GRID_PX) + 1):
            for gy in range(int(r[1] // _GRID_PX), int(r[3] // _GRID_PX) + 1):
                grid.setdefault((gx, gy), []).append(n_rects)
        n_rects += 1

    for r in reserved or []:
        add(np.asarray(r, np.float64))
    radii = np.arange(1, rings + 1)[:, None, None]
    g = (anchors // h_cell).astype(np.int64)  # anchor cells, one integer each (cheap keys for 100 k labels)
    cells = (g[:, 0] * (1 << 32) + g[:, 1]).tolist()
    for i, cell in enumerate(cells):
        if fails.get(cell, 0) >= _MAX_FAILS:
            continue
        a = anchors[i]
        w, h = (float(v) for v in size_of(i))
        step = np.broadcast_to(radii * (h + 2 * pad), (rings, 8, 1))  # [rings, 8, 1]
        sx = np.where(_DIRS[None, :, :1] != 0, w / 2 + step, step)  # x: w/2 + r on the sides, else r
        ring = a + _DIRS[None] * np.concatenate([sx, step], 2) - (w / 2, h / 2)
        tl = np.concatenate([(a - (w / 2, h / 2))[None], ring.reshape(-1, 2)])
        tl = np.clip(tl, 0, [max(0.0, W - w), max(0.0, H - h)])
        far = np.hypot(*(tl + (w / 2, h / 2) - a).T) > rings * (h + 2 * pad) + w / 2 + h  # pushed off by an edge
        tl = tl[~far] if (~far).any() else tl[:1]
        box = np.concatenate([tl - pad, tl + (w + pad, h + pad)], 1)
        lo, hi = box[:, :2].min(0) // _GRID_PX, box[:, 2:].max(0) // _GRID_PX
        near = {j for gx in range(int(lo[0]), int(hi[0]) + 1) for gy in range(int(lo[1]), int(hi[1]) + 1)
                for j in grid.get((gx, gy), ())}
        if near:
            q = rects[sorted(near)]
            hit = ((box[:, None, 0] < q[None, :, 2]) & (box[:, None, 2] > q[None, :, 0])
                   & (box[:, None, 1] < q[None, :, 3]) & (box[:, None, 3] > q[None, :, 1])).any(1)
            free = np.flatnonzero(~hit)
        else:
            free = np.zeros(1, int)
        if not len(free):
            fails[cell] = fails.get(cell, 0) + 1
            continue
        out[i] = tl[free[0]]
        add(box[free[0]])
    return out


def _draw_labels(img: np.ndarray, vp: VisualPrompt, smap: SemanticMap, colours: dict[int, tuple[int, int, int]],
                 conf: PromptConfig, reserved: list[np.ndarray], arrays: tuple[np.ndarray, ...]) -> int:
    """Object labels without overlaps (`place_labels`, largest footprint first); a label moved off its box centre
    gets a leader line. Returns how many labels were drawn."""
    if not smap.instances:
        return 0
    font = cv2.FONT_HERSHEY_SIMPLEX
    C, L, _ = arrays
    order = np.argsort(-(L[:, 0] * L[:, 1]), kind="stable")
    insts = [smap.instances[i] for i in order]
    sizes: dict[int, tuple[tuple[int, int], int]] = {}  # measured only for the labels tried

    def size_of(k: int) -> tuple[float, float]:
        if k not in sizes:
            sizes[k] = cv2.getTextSize(f"{insts[k].name} {insts[k].id}", font, conf.font_scale, 1)
        (tw, th), base = sizes[k]
        return float(tw), float(th + base)

    anchors = vp.world_to_px(C[order, :2])
    tls = place_labels(anchors, size_of, (img.shape[1], img.shape[0]), reserved=reserved,
                       rings=8 if len(insts) <= _DENSE else 2)  # dense maps: labels near their boxes or none
    drawn = 0
    for k in np.flatnonzero(~np.isnan(tls[:, 0])):
        o, a, tl = insts[k], anchors[k], tls[k]
        (w, h), th = size_of(k), sizes[k][0][1]
        dark = tuple(int(v * 0.6) for v in colours[o.id])
        centre = tl + (w / 2, h / 2)
        if np.linalg.norm(centre - a) > max(w, h) / 2:
            end = np.clip(a, tl, tl + (w, h))  # nearest point of the label box
            cv2.line(img, (int(a[0]), int(a[1])), (int(end[0]), int(end[1])), dark, 1, cv2.LINE_AA)
            cv2.circle(img, (int(a[0]), int(a[1])), 2, dark, -1, cv2.LINE_AA)
        x0, y0 = int(tl[0]), int(tl[1])
        sub = img[max(0, y0 - 1):y0 + int(h) + 1, max(0, x0 - 2):x0 + int(w) + 2]
        sub[:] = (0.25 * sub + 0.75 * 255).astype(np.uint8)  # a light plate under the text: readable on any fill
        cv2.putText(img, f"{o.name} {o.id}", (x0, y0 + th), font, conf.font_scale, dark, 1, cv2.LINE_AA)
        drawn += 1
    return drawn


_footprint = box_footprint  # the helper moved to geometry (semantic_map uses it: no import circle)


def vlm_prompt(question: str, options: list[str] | None, block: str, mode: str = "grid") -> str:
    """The paper's prompt structure: what the image is, the object text block, the question, the answer format."""
    head = {"grid": "The image is a top-down map of the room built from the video: each coloured box is an "
                    "object (its label on it, or next to it joined by a thin line), black dots with arrows are the camera positions and headings, the "
                    "scale bar gives metres, x points right and y up the image.",
            "points": "The image is a top-down view of the 3D points of the objects seen in the video, one colour "
                      "per object; black dots with arrows are the camera positions and headings.",
            "text": "The room was reconstructed from the video into the object list below.",
            "json": "The room was reconstructed from the video into the JSON spatial code below: each object has "
                    "an id, a label, its centre and size in metres and its yaw (x right, y forward, z up).",
            "video": "The images are frames sampled uniformly from a video of a room, in time order."}[mode]
    parts = [head] + ([block] if block else []) + [f"Question: {question}"]
    if options:
        parts.append("Options:\n" + "\n".join(options))
        parts.append("Answer with the option's letter only.")
    else:
        parts.append("Answer with a single number only.")
    return "\n\n".join(parts)
