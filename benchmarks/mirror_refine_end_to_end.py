"""End to end with and without ``mirror run --refine-pose``: warp_iou, PSNR and SSIM of every tracked frame.

Usage: PYTHONPATH=. python benchmarks/mirror_refine_end_to_end.py [--source NAME.npz] [--out DIR]
[--runs ik refine refine-no-trunk refine-2-steps refine-before-mir12h] SESSION [...]

Per synthetic mirror session (with ``gt/mirror``), ``run_mirror`` with the session's edits at once (no ramp, no
video) into ``DIR/<session>_<run>`` for each of ``--runs`` (default ``ik refine``: the IK pose, the refined pose;
``refine-no-trunk``: refined without E_trunk, ``refine-2-steps``: two Gauss-Newton steps, ``refine-no-edge``:
without the warp's edge clamp, MIR12g; ``refine-before-mir12h``: the root turned about its head and no spine twist,
MIR12h; ``refine-twisted``: the IK's limbs keep their warm-started twist, before MIR12p; ``refine-registered``: the
bodies registered to the outline, ``run.REGISTER_OUTLINE_ONE_PLAYER``; ``refine-posture``: E_trunk centred on the run's
running mean posture of spine_02, neck_01 and head, ``run.POSTURE_BONES``, MIR12q; ``refine-registered-posture``: both
options, MIR12r; ``refine-root-kept``: the target skeleton keeps the source's root, ``reshape.TARGET_ROOT = "source"``,
before MIR12s; ``refine-upright``: the bodies posed with an upright root, ``run.UPRIGHT_ROOT``, MIR12s;
``refine-root-kept-upright``: both; ``refine-untwist-feet``: the feet untwisted too, ``run.UNTWIST_FEET``,
mir12aa's default; ``refine-feet-twisted``: the IK's warm-started foot twist kept, before mir12aa;
``refine-pelvis-lean``: E_upright, the pelvis's lean held near upright, ``run.PELVIS_TILT_RAD =
refine.PELVIS_TILT_RAD``, mir12ad's option; the default since mir12ae); ``refine-before-mir12ae``: neither E_upright
nor the running posture (``run.PELVIS_TILT_RAD = None``, ``run.POSTURE_BONES = ()``: main before mir12ae), then
``evaluate_mirror`` on each; prints one JSON line per run with the scores and the per-step median milliseconds
(wall, so only comparable at one load).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
from pathlib import Path


@contextlib.contextmanager
def _refine_as(run: str, weights: dict | None = None):
    """``refine_pose`` (and the warp) as the ``run`` wants it while the block runs: without E_trunk
    (``refine-no-trunk``), with two steps (``refine-2-steps``), without ``warp.edge_clamped`` (``refine-no-edge``);
    the run imports ``refine_pose`` from the module when it starts, ``warp_foreground`` calls the clamp by name."""
    from bodystudio.mirror import refine

    original, twist, pivot = refine.refine_pose, refine.TWIST_BONES, refine.ROOT_PIVOT
    if run == "refine-before-mir12h":  # the run reads both when it starts
        refine.TWIST_BONES, refine.ROOT_PIVOT = (), "head"
    def overriding(**over):  # the run passes iterations and weights itself (MIR12n): these replace its own
        def refine_pose(*args, **kwargs):
            return original(*args, **{**kwargs, **over})
        return refine_pose

    if run == "refine-no-trunk":
        refine.refine_pose = overriding(weights=refine.RefineWeights(trunk_rad=None))
    elif run == "refine-2-steps":
        refine.refine_pose = overriding(iterations=2)
    elif run == "refine-weights":
        refine.refine_pose = overriding(weights=refine.RefineWeights(**(weights or {})))
    from bodystudio.mirror import run as run_module
    from bodystudio.mirror import warp

    untwist, register = run_module.UNTWIST_BONES, run_module.REGISTER_OUTLINE_ONE_PLAYER
    posture = run_module.POSTURE_BONES
    from bodystudio.mirror import reshape

    target_root = reshape.TARGET_ROOT
    if run in ("refine-root-kept", "refine-root-kept-upright"):  # the source's root kept (before MIR12s)
        reshape.TARGET_ROOT = "source"
    upright, feet = run_module.UPRIGHT_ROOT, run_module.UNTWIST_FEET
    lean = run_module.PELVIS_TILT_RAD
    if run == "refine-pelvis-lean":  # E_upright: the pelvis's lean held near upright (mir12ad)
        run_module.PELVIS_TILT_RAD = refine.PELVIS_TILT_RAD
    if run == "refine-before-mir12ae":  # neither E_upright nor the running posture (the run before mir12ae)
        run_module.PELVIS_TILT_RAD, run_module.POSTURE_BONES = None, ()
    if run == "refine-twisted":  # the IK's warm-started limb twist (before MIR12p)
        run_module.UNTWIST_BONES, run_module.UNTWIST_FEET = (), False
    if run in ("refine-untwist-feet", "refine-feet-twisted"):  # the IK's feet untwisted as its limbs or not (mir12aa)
        run_module.UNTWIST_FEET = run == "refine-untwist-feet"
    if run in ("refine-upright", "refine-root-kept-upright"):  # the root's tilt moved into the pelvis (MIR12s)
        run_module.UPRIGHT_ROOT = True
    if run in ("refine-registered", "refine-registered-posture"):  # the bodies registered to the outline (MIR12p)
        run_module.REGISTER_OUTLINE_ONE_PLAYER = True
    if run in ("refine-posture", "refine-registered-posture"):  # E_trunk on the running mean posture (MIR12q)
        run_module.POSTURE_BONES = ("spine_02", "neck_01", "head")
    clamp = warp.edge_clamped
    if run == "refine-no-edge":  # source positions outside the image stay outside (before MIR12g)
        warp.edge_clamped = lambda xy, shape, reach_px=0.0: xy
    try:
        yield
    finally:
        refine.refine_pose, refine.TWIST_BONES, refine.ROOT_PIVOT = original, twist, pivot
        warp.edge_clamped = clamp
        run_module.UNTWIST_BONES, run_module.REGISTER_OUTLINE_ONE_PLAYER = untwist, register
        run_module.POSTURE_BONES = posture
        reshape.TARGET_ROOT = target_root
        run_module.UPRIGHT_ROOT, run_module.UNTWIST_FEET = upright, feet
        run_module.PELVIS_TILT_RAD = lean


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.evaluate import evaluate_mirror
    from bodystudio.mirror.run import load_source, run_mirror

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--source", default=None, help="source body .npz name inside SESSION/mirror/")
    parser.add_argument("--runs", nargs="+", default=["ik", "refine"],
                        choices=["ik", "refine", "refine-no-trunk", "refine-2-steps", "refine-no-edge",
                                 "refine-before-mir12h", "refine-weights", "refine-twisted", "refine-registered",
                                 "refine-posture", "refine-registered-posture", "refine-root-kept", "refine-upright",
                                 "refine-root-kept-upright", "refine-untwist-feet", "refine-feet-twisted",
                                 "refine-pelvis-lean", "refine-before-mir12ae"],
                        help="the runs per session: the IK pose, the refined pose, the refined pose without E_trunk "
                             "or with two Gauss-Newton steps, or without the warp's edge clamp (MIR12g's A/Bs)")
    parser.add_argument("--weights", default="", help="refine-weights: RefineWeights fields, e.g. depth_samples=2000")
    parser.add_argument("--out", type=Path, default=None, help="folder for the run folders (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) if args.out is None else args.out
        for path in args.sessions:
            session = open_session(path)
            src = None if args.source is None else path / "mirror" / args.source
            body, _ = load_source(session, src)
            for name in args.runs:
                run = out / f"{path.name}_{name}"
                weights = {k: int(v) if v.isdigit() else float(v)
                           for k, v in (kv.split("=") for kv in args.weights.split(",") if kv)}
                with _refine_as(name, weights):
                    doc = run_mirror(session, session.metadata["edits"], None, source=src, side_by_side=False,
                                     progress=False, run_dir=run, ramp_frames=0, refine_pose=name != "ik")
                scores = evaluate_mirror(session, run, source=body)
                keep = ("warp_iou", "warp_iou_unwarped", "fg_iou", "psnr_person", "ssim_person", "joint_err_mm")
                print(json.dumps({"session": path.name, "run": name, "weights": args.weights if name == "refine-weights"
                                  else "", **{k: scores.get(k) for k in keep},
                                  "ms_per_frame": {k: round(v, 2) for k, v in doc["summary"]["ms_per_frame"].items()}}),
                      flush=True)


if __name__ == "__main__":
    main()
