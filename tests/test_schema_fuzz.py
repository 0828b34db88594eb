"""Property tests of the four file schemas (issue 29): any single damaged field of a map, a bundle manifest, a
device profile or a scene annotation ends in exit 0 (the field did not matter, or the answer says what it used)
or exit 2 with one `error:` line naming the file, through the real CLI entry point (`cli.main`, in-process).
A manifest that `mosaic bundle verify` accepts must load and run every role without an internal error.

Hypothesis draws (field path, damage) pairs from every path of a valid document (derandomized: the same
examples on every run); tests/test_campaign.py runs every pair exhaustively (slow lane).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz_files import (MUTATIONS, base_annotation, base_manifest, base_map, base_profile, mutate, paths,
                        show_path, use_roles)
from mosaicthinker.runtime.cli import main
from mosaicthinker.runtime.infra.errors import MosaicError

FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
KINDS = sorted(MUTATIONS)
MAP, PROFILE, ANNOTATION = base_map(), base_profile(), base_annotation()


def run_cli(capsys, argv: list) -> tuple[int, str, str]:
    code = main([os.fsdecode(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_outcome(code: int, out: str, err: str, file: Path, case: str) -> None:
    """Exit 0, or exit 2 with `error:` lines naming the file; never a traceback or an internal error."""
    assert code in (0, 2), (case, code, out, err)
    assert "Traceback" not in err and "internal error" not in err, (case, err)
    for line in err.splitlines():
        assert line.startswith(("error:", "warning:")), (case, err)
    if code == 2:
        assert str(file) in err or file.name in err, (case, err)


def _dump_json(doc, path: Path) -> None:
    path.write_text(json.dumps(doc, indent=1))  # NaN / inf are written as the NaN / Infinity tokens


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def check_map_case(capsys, work: Path, path: tuple, kind: str) -> tuple[int, str]:
    f = work / "map.json"
    _dump_json(mutate(MAP, path, kind), f)
    case = f"map {show_path(path)} <- {kind}"
    worst = 0
    for q in ("How many chairs are in the room?", "What is the distance between the chair and the table?",
              "How big is the room (in square meters)?"):
        code, out, err = run_cli(capsys, ["ask", f, q])
        assert_outcome(code, out, err, f, case)
        worst = max(worst, code)
    return worst, case


@FUZZ
@given(st.sampled_from(list(paths(MAP))), st.sampled_from(KINDS))
def test_map_field_damage_is_exit_0_or_2(capsys, work, path, kind):
    check_map_case(capsys, work, path, kind)


def check_profile_case(capsys, work: Path, path: tuple, kind: str) -> tuple[int, str]:
    import tomli_w

    f = work / "p.toml"
    case = f"profile {show_path(path)} <- {kind}"
    try:
        f.write_bytes(tomli_w.dumps(mutate(PROFILE, path, kind)).encode())
    except TypeError:  # TOML has no null
        return -1, case
    code, out, err = run_cli(capsys, ["plan", "--profile", f, "--duration", "20", "--fps", "15"])
    assert_outcome(code, out, err, f, case)
    return code, case


@FUZZ
@given(st.sampled_from(list(paths(PROFILE))), st.sampled_from(KINDS))
def test_profile_field_damage_is_exit_0_or_2(capsys, work, path, kind):
    check_profile_case(capsys, work, path, kind)


@pytest.fixture(scope="module")
def tiny_bundle(work) -> tuple[Path, dict]:
    b = work / "bundle"
    return b, base_manifest(b)


def check_manifest_case(capsys, bundle: Path, manifest: dict, path: tuple, kind: str) -> tuple[int, str]:
    f = bundle / "manifest.json"
    case = f"manifest {show_path(path)} <- {kind}"
    _dump_json(mutate(manifest, path, kind), f)
    try:
        code, out, err = run_cli(capsys, ["bundle", "verify", bundle])
        assert_outcome(code, out, err, f, case)
        if code == 0:  # accepted: every role loads and runs, or says clearly why not
            try:
                use_roles(bundle)
            except MosaicError:
                pass
        return code, case
    finally:
        _dump_json(manifest, f)


@FUZZ
@given(st.data())
def test_manifest_field_damage_is_exit_0_or_2_and_accepted_means_usable(capsys, tiny_bundle, data):
    bundle, manifest = tiny_bundle
    path = data.draw(st.sampled_from(list(paths(manifest))))
    kind = data.draw(st.sampled_from(KINDS))
    check_manifest_case(capsys, bundle, manifest, path, kind)


def check_annotation_case(work: Path, path: tuple, kind: str) -> tuple[int, str]:
    """The annotation has no cheap CLI (`eval scene` runs the whole pipeline): its loader and what reads the
    loaded scene (the map from its boxes, the visible subset, questions from the boxes) must raise InputError
    or work."""
    from mosaicthinker.host.evaluation.scene import SceneEvalConfig, load_annotation, score_answers, visible_meta
    from mosaicthinker.runtime.infra.errors import InputError
    from mosaicthinker.runtime.map import SemanticMap

    f = work / "annotation.json"
    _dump_json(mutate(ANNOTATION, path, kind), f)
    case = f"annotation {show_path(path)} <- {kind}"
    try:
        name, scene, T = load_annotation(f)
    except InputError as e:
        assert str(f) in str(e), (case, e)
        return 2, case
    smap = SemanticMap.from_meta_info(scene, name)
    vm = visible_meta(scene, {c: [True] * len(v) for c, v in scene["object_bbox"].items()})
    score_answers(smap, name, vm, SceneEvalConfig(per_type=2, min_per_type=1))
    return 0, case


@FUZZ
@given(st.sampled_from(list(paths(ANNOTATION))), st.sampled_from(KINDS))
def test_annotation_field_damage_is_refused_or_harmless(work, path, kind):
    check_annotation_case(work, path, kind)


def test_the_base_documents_are_accepted(capsys, work, tiny_bundle):
    """The undamaged documents pass (so every refusal above is the damage's)."""
    f = work / "map.json"
    _dump_json(MAP, f)
    code, out, err = run_cli(capsys, ["ask", f, "How many chairs are in the room?"])
    assert code == 0 and out.startswith("answer: 2"), (out, err)
    bundle, _ = tiny_bundle
    code, out, err = run_cli(capsys, ["bundle", "verify", bundle])
    assert code == 0, err
    use_roles(bundle)
    assert check_profile_case(capsys, work, ("device", "notes"), "string")[0] == 0
    assert check_annotation_case(work, ("licence",), "string")[0] == 0


def test_variant_overrides_and_the_instance_segmenter_role_follow_the_schema(capsys, tiny_bundle):
    """A variant that is another model for its role (`overrides`) and perception's `instance_segmenter` role are
    checked like any role entry: fields it may not override, labels a closed vocabulary lacks, an arch of another
    role are each refused naming the field (verify exits 2); a good override passes."""
    import copy

    bundle, manifest = tiny_bundle
    f = bundle / "manifest.json"

    def verify(man: dict) -> tuple[int, str]:
        _dump_json(man, f)
        try:
            code, out, err = run_cli(capsys, ["bundle", "verify", bundle])
            return code, err
        finally:
            _dump_json(manifest, f)

    def with_override(ov: dict) -> dict:
        man = copy.deepcopy(manifest)
        det = man["roles"]["detector"]
        det["variants"]["alt"] = {**copy.deepcopy(det["variants"]["fp32"]), "overrides": ov}
        return man

    sem = manifest["roles"]["detector"]["semantics"]
    assert verify(with_override({"semantics": {**sem, "labels": ["chair"]}}))[0] == 0
    for ov, said in (({"bogus": 1}, "variants.alt.overrides has a field 'bogus'"),
                     ({"semantics": {"vocabulary": "closed"}}, "variants.alt.overrides: semantics.labels is required"),
                     ({"arch": "deeplab"}, "variants.alt.overrides.arch is 'deeplab', an architecture of the "
                                           "segmenter role")):
        code, err = verify(with_override(ov))
        assert code == 2 and said in err, (ov, err)
    man = copy.deepcopy(manifest)
    man["roles"]["instance_segmenter"] = {**copy.deepcopy(man["roles"]["detector"]),
                                          "semantics": {"vocabulary": "closed"}}
    code, err = verify(man)
    assert code == 2 and "roles.instance_segmenter" in err and "labels is required" in err, err
    man["roles"]["instance_segmenter"]["semantics"] = sem
    code, err = verify(man)  # the SSD adapter serves the detector role only
    assert code == 2 and "roles.instance_segmenter.arch is 'ssd_tflite', an architecture of the detector role" in err
