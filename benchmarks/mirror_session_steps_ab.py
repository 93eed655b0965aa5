"""Mirror session steps, another tree's modules against this one's, called alternately in one process (MIR12e).

``PYTHONPATH=. python benchmarks/mirror_session_steps_ab.py /work/main [rounds [session folder]]``: the per-frame
session side of a two-actor frame (the depth-to-colour registration and the split of its player mask, shared;
per actor the IK, the target rig, the posed source and target bodies, the player's point cloud and the pose
refinement against its mask, depth and joints) with the ``frames``, ``track``, ``refine`` and ``reshape`` modules
of the other tree (loaded from its files, each other's imports among them resolved to the other tree's; the
player masks: its ``run.player_masks``, or the inline expressions it had before MIR12e) and this tree's, called
one after the other ``rounds`` times (default 21) on the last frame of a 14-frame two-actor v1 synthetic session
(written to a temporary folder, or kept in the given one; the actors' mean-shape bodies, the target +10 cm /
+10 kg, as ``bench_mirror``'s refinement timing); numba / OpenCV / BLAS on one thread; prints the median process
CPU ms per step (other, this) and the two-actor session total. The pattern of ``mirror_image_steps_ab.py``: on a
loaded shared machine only this call-by-call alternation separates them.
"""

from __future__ import annotations

import os
import tempfile

os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="mirror_ab_numba_")  # before numba is imported

import importlib.util  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.mirror_image_steps_ab import alternate_cpu_ms  # noqa: E402

_MODULES = ("frames", "track", "refine", "reshape")  # in import order: each may import the ones before it


def _load_tree(root: Path) -> dict:
    """The other tree's mirror modules, ``bodystudio.mirror.<name>`` pointing at them while each loads (so that
    its ``from bodystudio.mirror.track import ...`` gets the other tree's), restored afterwards."""
    saved = {n: sys.modules.get(f"bodystudio.mirror.{n}") for n in _MODULES}
    out = {}
    try:
        for n in _MODULES:
            spec = importlib.util.spec_from_file_location(f"other_{n}", root / f"{n}.py")
            module = importlib.util.module_from_spec(spec)
            sys.modules[f"other_{n}"] = module
            spec.loader.exec_module(module)
            sys.modules[f"bodystudio.mirror.{n}"] = module
            out[n] = module
    finally:
        for n, m in saved.items():
            if m is None:
                sys.modules.pop(f"bodystudio.mirror.{n}", None)
            else:
                sys.modules[f"bodystudio.mirror.{n}"] = m
    return out


def _session(folder: Path):
    from bodystudio.mirror import synthetic

    if not (folder / "session.json").exists():
        synthetic.synth_mirror_session(str(folder), subject_seed=3, n_frames=14, actors=2,
                                       edits={"taller": 0.1}, version="v1", walk_in=False)
    from bodystudio.capture.session import open_session

    return open_session(folder)


def _steps(mods: dict, session, model, rounds_out: dict) -> dict:
    """name -> callable of one tree's session steps on the session's last frame."""
    F, T, R, RS = (mods[n] for n in _MODULES)
    from bodystudio.mirror.init import SourceBody

    sensor = session.kinect
    frame = F.read_mirror_frame(session, session.frame_ids[-1])
    c = np.zeros(len(model.stddev))
    body = SourceBody(c, model.vertices(c), model.skeleton(c), (), 0.0, model.weights, model.faces)
    ct = RS.target_coeffs(model, c, {"taller": 0.1, "heavier": 10})
    Vt = model.vertices(ct)
    plan = R.refine_plan(body.vertices, body.faces, body.weights, body.skeleton, sensor.version,
                         twist_bones=R.TWIST_BONES)  # the run's plan (MIR12h)
    _, players = F.register_depth_to_color(frame.depth_m, frame.player, sensor)
    steps = {"registration": lambda: F.register_depth_to_color(frame.depth_m, frame.player, sensor),
             "player masks": lambda: mods["player_masks"](players, (1, 2), True)}
    for p in (1, 2):
        tracked = frame.body(p)
        pose = T.ik_pose(body.skeleton, tracked.positions, tracked.tracked, sensor.version)
        rig = RS.target_skeleton(body, Vt, model, ct)
        points = F.point_cloud(frame, sensor, p)
        points = points[points[:, 1] > 0.02]
        others = (players > 0) & (players != p)
        fg = players == p
        steps[f"IK {p}"] = (lambda tr=tracked, po=pose:
                            T.ik_pose(body.skeleton, tr.positions, tr.tracked, sensor.version, previous=po))
        steps[f"target rig {p}"] = lambda: RS.target_skeleton(body, Vt, model, ct)
        steps[f"source and target bodies {p}"] = lambda po=pose, rig=rig: RS.posed_source_and_target(body, Vt, po, rig)
        steps[f"point cloud {p}"] = lambda p=p: F.point_cloud(frame, sensor, p)
        steps[f"pose refinement {p}"] = (lambda po=pose, tr=tracked, pts=points, fg=fg, others=others:
                                         R.refine_pose(plan, body.skeleton, po, sensor.color, fg, tr.positions,
                                                       tr.tracked, pts, others, sensor.version))
        rounds_out[p] = (pose, rig, points, fg, others, tracked)
    return steps


def _inline_player_masks(players_c, players, several):
    """session_inputs' masks before MIR12e (run.py, inline)."""
    person = players_c == players[0] if not several else np.isin(players_c, players)
    others = (players_c > 0) & ~person
    return person, others, np.where(person, players_c, 0).astype(np.uint8) if several else None


def compare(other_tree: str | Path, rounds: int = 21, folder: str | Path | None = None) -> dict:
    """{step: (other ms, this ms)} and "two actors" (the sums) (see the module docstring)."""
    from benchmarks.bench_mirror import one_core
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror import frames, refine, reshape, run, track

    other = _load_tree(Path(other_tree) / "bodystudio" / "mirror")
    this = {"frames": frames, "track": track, "refine": refine, "reshape": reshape,
            "player_masks": run.player_masks}
    # the run's split of the registered player mask (session_inputs); a tree without run.player_masks had it
    # inline as these expressions (before MIR12e)
    other["player_masks"] = _inline_player_masks
    if "def player_masks(" in (Path(other_tree) / "bodystudio" / "mirror" / "run.py").read_text():
        other["player_masks"] = run.player_masks
    model = load_statistical_model("6k", progress=False)
    with tempfile.TemporaryDirectory() as tmp, one_core():
        session = _session(Path(folder) if folder else Path(tmp) / "s")
        so, st = _steps(other, session, model, {}), _steps(this, session, model, {})
        out = alternate_cpu_ms({name: (so[name], st[name]) for name in so}, rounds, digits=3)
    out["two actors"] = (round(sum(v[0] for v in out.values()), 2), round(sum(v[1] for v in out.values()), 2))
    return out


if __name__ == "__main__":
    import shutil

    try:
        print(json.dumps(compare(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 21,
                                 sys.argv[3] if len(sys.argv) > 3 else None), indent=1))
    finally:
        shutil.rmtree(os.environ["NUMBA_CACHE_DIR"], ignore_errors=True)
