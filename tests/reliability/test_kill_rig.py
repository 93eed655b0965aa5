"""`bodystudio rig` SIGKILLed while re-writing an avatar: A.glb, A.rig.json (and the BVH) stay one pair.

The fast tests replace the scan fit in the child by the 2k body model's own rig (the fit is not what is
tested; the export and the commit are), the slow one runs the real command on a small synthetic scan.
"""

import json
import shutil
import sys
import textwrap
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import kill_points, read_events, run_child, snapshot  # noqa: E402

from bodystudio.cli.main import main  # noqa: E402
from bodystudio.errors import BodyStudioError  # noqa: E402
from bodystudio.rig.evaluate import load_avatar  # noqa: E402
from bodystudio.viewer.avatar import load_avatar as view_avatar  # noqa: E402

QUICK_RIG = textwrap.dedent("""
    import types
    import numpy as np
    import bodystudio.rig.pipeline as pipeline
    from bodystudio.body import build_body
    from bodystudio.rig.avatar import Avatar
    from bodystudio.rig.weights import limit_influences

    def quick_rig(mesh, model, weights="harmonic", stage=None):
        body = build_body(resolution="2k")
        sk = body.skeleton
        colors = (np.abs(np.sin(body.vertices * 20.0)) * 255).astype(np.uint8)
        avatar = Avatar(body.vertices, body.faces, colors, sk.bone_names, sk.parents, None, sk.rest_rotations,
                        sk.rest_rotations, sk.lengths, limit_influences(body.weights), np.zeros(3),
                        loaded_heads=sk.heads.copy())
        avatar.metadata["fit_err_mm_median"] = 0.0
        for name in ("fit", "skeleton", "weights"):
            if stage is not None:
                stage(name)
        return types.SimpleNamespace(avatar=avatar, fit=None, seconds={})

    pipeline.rig_scan = quick_rig
""")


@pytest.fixture(scope="module")
def rigged(tmp_path_factory, body_2k):
    """A folder with a complete avatar (vertex colours) from the quick rig, and the setup for re-runs."""
    from bodystudio.geometry.mesh import Mesh, save_mesh

    root = tmp_path_factory.mktemp("kill_rig")
    save_mesh(root / "scan.ply", Mesh(body_2k.vertices, body_2k.faces))
    setup = root / "quick_rig.py"
    setup.write_text(QUICK_RIG)
    out = root / "out"
    proc = run_child(["rig", str(root / "scan.ply"), "--out", str(out / "a.glb"), "--template", "2k"], root,
                     setup=setup)
    assert proc.returncode == 0, proc.stderr
    run_id = json.loads((out / "a.rig.json").read_text())["run"]["run_id"]
    return root, run_id, snapshot(out)


def _copy(rigged, tmp_path):
    root, run_id, snap = rigged
    out = tmp_path / "out"
    shutil.copytree(root / "out", out)
    return out, run_id, snap


def new_run(root: Path, out: Path) -> list[str]:
    return ["rig", str(root / "scan.ply"), "--out", str(out / "a.glb"), "--template", "2k", "--texture",
            "--bvh", str(out / "a.bvh")]


def reader_state(out: Path, previous_id: str, previous: dict) -> str:
    """What `eval rig` and `view` read: 'previous', 'new' (a textured pair with its BVH) or 'refused'."""
    glb = out / "a.glb"
    try:
        avatar = load_avatar(glb)
        shown = view_avatar(glb)
    except BodyStudioError as exc:
        msg = str(exc)
        assert "\n" not in msg and "recover" in msg, msg
        with pytest.raises(BodyStudioError, match="recover"):
            view_avatar(glb)
        return "refused"
    meta = json.loads((out / "a.rig.json").read_text())
    visible = snapshot(out)
    if meta["run"]["run_id"] == previous_id:
        assert visible == previous
        return "previous"
    assert "vertex_source" in meta and set(visible) == {"a.glb", "a.rig.json", "a.bvh"}
    assert len(shown.mesh.vertices) == meta["n_vertices"] > len(avatar.vertices) == meta["n_avatar_vertices"]
    return "new"


def _recover_and_check(out, previous_id, previous) -> str:
    assert main(["recover", str(out / "a.glb")]) == 0
    state = reader_state(out, previous_id, previous)
    assert state in ("previous", "new")
    assert not any(p.name.startswith(".a.glb.") for p in out.iterdir())
    return state


@pytest.mark.parametrize("match, offset, expected, after_recover", [
    ("a.glb", 0, "previous", "previous"),  # the glb staged, nothing committed
    ("commit.json", 3, "refused", "new"),  # a.bvh and a.glb moved into place, a.rig.json still the old one
])
def test_rig_killed_between_glb_and_rig_json(rigged, tmp_path, match, offset, expected, after_recover):
    out, previous_id, previous = _copy(rigged, tmp_path)
    proc = run_child(new_run(rigged[0], out), tmp_path, after_match=match, offset=offset,
                     setup=rigged[0] / "quick_rig.py")
    assert proc.returncode == -9, proc.stderr
    assert reader_state(out, previous_id, previous) == expected
    assert _recover_and_check(out, previous_id, previous) == after_recover


def test_textured_export_reads_back_as_the_same_rig(rigged, tmp_path):
    """`eval rig` scores the avatar's own vertices whatever the export (seam duplicates collapsed)."""
    import numpy as np

    out, _, _ = _copy(rigged, tmp_path)
    plain = load_avatar(out / "a.glb")
    proc = run_child(["rig", str(rigged[0] / "scan.ply"), "--out", str(out / "t.glb"), "--template", "2k",
                      "--texture"], tmp_path, setup=rigged[0] / "quick_rig.py")
    assert proc.returncode == 0, proc.stderr
    textured = load_avatar(out / "t.glb")
    meta = json.loads((out / "t.rig.json").read_text())
    assert meta["n_vertices"] == len(view_avatar(out / "t.glb").mesh.vertices) > len(plain.vertices)
    np.testing.assert_array_equal(textured.vertices, plain.vertices)
    np.testing.assert_array_equal(textured.weights, plain.weights)
    np.testing.assert_array_equal(np.sort(textured.faces, axis=1)[np.lexsort(np.sort(textured.faces, 1).T)],
                                  np.sort(plain.faces, axis=1)[np.lexsort(np.sort(plain.faces, 1).T)])


# The slow test's kill-point children replay the fit the first run computed (same scan, template and seed, so
# the same result) instead of repeating it: every file event comes after the fit, so the events and the kill
# points are the same; the time-based kill runs the real fit (its moment depends on the fit's duration).
REPLAY_FIT = """
import pickle
import bodystudio.rig.pipeline as pipeline

def replayed_rig(mesh, model, weights="harmonic", stage=None, seed=0):
    result = pickle.loads(open({path!r}, "rb").read())
    for name in ("fit", "skeleton", "weights"):
        if stage is not None:
            stage(name)
    return result

pipeline.rig_scan = replayed_rig
"""


@pytest.mark.slow
def test_rig_killed_at_seeded_points(tmp_path, monkeypatch):
    """The real command on a small synthetic scan, killed at a seeded set of file events and times."""
    import pickle

    import bodystudio.rig.pipeline as pipeline
    from bodystudio.register.synthetic import save_synthetic_scan, synthetic_scan

    scan, gt = synthetic_scan(11, "a", 5000, 1.0, True)
    root = tmp_path / "root"
    save_synthetic_scan(root / "scan.ply", scan, gt)
    base = root / "out"
    real_rig, fit_path = pipeline.rig_scan, tmp_path / "rig_result.pkl"

    def recorded(*args, **kwargs):
        result = real_rig(*args, **kwargs)
        fit_path.write_bytes(pickle.dumps(result))
        return result

    monkeypatch.setattr(pipeline, "rig_scan", recorded)
    assert main(["rig", str(root / "scan.ply"), "--out", str(base / "a.glb"), "--template", "2k"]) == 0
    monkeypatch.undo()
    replay = tmp_path / "replay_fit.py"
    replay.write_text(REPLAY_FIT.format(path=str(fit_path)))
    rigged = (root, json.loads((base / "a.rig.json").read_text())["run"]["run_id"], snapshot(base))
    out, previous_id, previous = _copy(rigged, tmp_path / "probe")
    log = tmp_path / "events.json"
    assert run_child(new_run(root, out), tmp_path, event_log=log, setup=replay).returncode == 0
    seen = set()
    for k in kill_points(read_events(log), seed=16, n=2):
        out, previous_id, previous = _copy(rigged, tmp_path / f"k{k}")
        assert run_child(new_run(root, out), tmp_path, kill_at=k, setup=replay).returncode == -9
        seen.add(reader_state(out, previous_id, previous))
        _recover_and_check(out, previous_id, previous)
    out, previous_id, previous = _copy(rigged, tmp_path / "t")
    run_child(new_run(root, out), tmp_path, kill_after_s=4.0)
    seen.add(reader_state(out, previous_id, previous))
    _recover_and_check(out, previous_id, previous)
    assert {"previous", "refused"} <= seen
