"""Where the run's leg pose goes wrong on a mirror session, and what the true legs would buy (mir12aa).

Usage: PYTHONPATH=. python benchmarks/mirror_leg_pose.py [--stride 2] [--out DIR] [--feet-twisted] SESSION [...]

Per synthetic mirror session (with ``gt/mirror``): ``run_mirror`` as ``mirror_refine_end_to_end.py --runs refine``
does (every tracked frame, ramp 0; ``--feet-twisted``: ``run.UNTWIST_FEET`` off, the run before mir12aa),
recording each frame's untwisted IK pose and the pose the bodies are posed with (refined, upright root); then

* per leg bone (thighs, calves, feet) the swing and twist error (degrees) of the IK and of the run's pose against
  the true pose, over all frames, the frames side-on to the sensor (the true root's yaw within 25 degrees of 90)
  and those facing it (within 25 degrees of 0);
* every ``stride``-th frame the run's warp replayed on its own foreground mask (``masks/foreground``: the dense
  pairs, the outline registration, the MLS field; the ``run`` row is the run's own figure) with parts of the true
  pose swapped into the run's: the legs (thighs, calves, feet), thighs and calves, feet, only the legs' swing or
  only their twist, and ``true legs, displacement only`` (the source posed by the run, the target displaced by
  ``V_T - V_S`` of the pose with the true legs), each its warp_iou over the same three groups of frames.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

LEG_BONES = ("thigh_l", "thigh_r", "calf_l", "calf_r", "foot_l", "foot_r")
SWAPS = {"true legs": LEG_BONES, "true thighs and calves": LEG_BONES[:4], "true feet": LEG_BONES[4:]}


@contextlib.contextmanager
def recorded_poses(record: dict):
    """While the block runs, ``record[frame] = {"ik": Pose, "final": Pose}``: the run's untwisted IK pose and the
    pose its bodies are posed with (the run imports these functions from their modules when it starts)."""
    from bodystudio.mirror import frames, reshape, track

    read, untwist, posed = frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target
    current = {}

    def reading(session, i):
        current["i"] = int(i)
        return read(session, i)

    def untwisting(skeleton, pose, bones=track.UNTWIST_BONES):
        out = untwist(skeleton, pose, bones)
        record.setdefault(current["i"], {})["ik"] = out
        return out

    def posing(body, target_rest, pose, target_rig=None):
        record.setdefault(current["i"], {})["final"] = pose
        return posed(body, target_rest, pose, target_rig)

    frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target = reading, untwisting, posing
    try:
        yield record
    finally:
        frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target = read, untwist, posed


def swing_only(skeleton, W, W_true, bones):
    """World rotations ``W`` with ``bones`` turned onto the true directions (their twist kept)."""
    from bodystudio.body.ik import rotation_between

    W = W.copy()
    for j in bones:
        axis = skeleton.rest_rotations[j][:, 1]
        W[j] = rotation_between(W[j] @ axis, W_true[j] @ axis) @ W[j]
    return W


def twist_only(skeleton, W, W_true, bones):
    """World rotations ``W`` with ``bones`` given the true twist about their own (kept) directions."""
    from bodystudio.body.ik import rotation_between

    W = W.copy()
    for j in bones:
        axis = skeleton.rest_rotations[j][:, 1]
        W[j] = rotation_between(W_true[j] @ axis, W[j] @ axis) @ W_true[j]
    return W


def _groups(rows):
    return {"all": rows, "side-on": [r for r in rows if abs(abs(r["yaw"]) - 90) < 25],
            "facing": [r for r in rows if abs(r["yaw"]) < 25]}


def leg_report(session_path: Path, run_dir: Path, record: dict, stride: int = 2) -> dict:
    """The leg errors and the replayed swaps of one recorded run (see the module docstring)."""
    import cv2

    from benchmarks.mirror_pose_oracle import pose_from_world, swing_twist_errors, world_rotations
    from benchmarks.mirror_worst_frames import root_yaw_deg
    from bodystudio.body.pose import Pose
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.frames import read_mirror_frame
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, frame_pairs, load_source, registered_pairs
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground

    session = open_session(session_path)
    body, model = load_source(session)
    sk = body.skeleton
    c_target = target_coeffs(model, body.coeffs, session.metadata["edits"])
    target_rest = model.vertices(c_target)
    rig = target_skeleton(body, target_rest, model, c_target)
    actors = np.load(Path(session.path) / "gt" / "mirror" / "actors.npz")
    a = list(actors["players"]).index(1)
    true_sk = Skeleton(sk.bone_names, sk.parents, actors["source_heads"][a], actors["source_tails"][a], sk.rolls)
    legs = [sk.bone_names.index(b) for b in LEG_BONES]
    camera, faces = session.kinect.color, body.faces
    errors, swaps = [], []
    for n, i in enumerate(sorted(k for k, v in record.items() if "final" in v and "ik" in v)):
        frame = session.frame(i)
        gt = frame.gt_mirror
        if gt is None or 1 not in list(gt["players"]) or frame.gt_target_person is None:
            continue
        k = list(gt["players"]).index(1)
        W_true = world_rotations(true_sk, Pose(gt["pose_rotations"][k].astype(float),
                                               gt["pose_translations"][k].astype(float)))
        final = record[i]["final"]
        W = world_rotations(sk, final)
        row = {"frame": i, "yaw": root_yaw_deg(W_true[0], camera.R)}
        for name, pose in (("IK", record[i]["ik"]), ("run", final)):
            swing, twist = swing_twist_errors(sk, world_rotations(sk, pose), W_true, legs)
            for b, s, t in zip(LEG_BONES, swing, twist, strict=True):
                row[f"{name} swing {b}"], row[f"{name} twist {b}"] = float(s), float(t)
        errors.append(row)
        if n % stride:
            continue
        fg = cv2.imread(str(run_dir / "masks" / "foreground" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        rgb = read_mirror_frame(session, i).rgb
        truth = frame.gt_target_person == 1
        worlds = {"run": W, "true legs swing": swing_only(sk, W, W_true, legs),
                  "true legs twist": twist_only(sk, W, W_true, legs)}
        for name, bones in SWAPS.items():
            idx = [sk.bone_names.index(b) for b in bones]
            worlds[name] = W.copy()
            worlds[name][idx] = W_true[idx]
        Vs, Vt = posed_source_and_target(body, target_rest, final, rig)
        row = {"frame": i, "yaw": errors[-1]["yaw"]}
        for name, Wp in [*worlds.items(), ("true legs, displacement only", worlds["true legs"])]:
            A, B = (Vs, Vt) if name == "run" else posed_source_and_target(
                body, target_rest, pose_from_world(sk, Wp, final.translation), rig)
            if name.endswith("displacement only"):
                A, B = Vs, Vs + (B - A)
            pairs = registered_pairs(frame_pairs([A], [B], faces, camera, "dense"), A, B, faces, body.weights,
                                     sk.parents, camera, fg, "dense")
            field = mls_warp_field(pairs.src_uv, pairs.dst_uv, fg.shape, kind="similarity", alpha=MLS_ALPHA,
                                   radius_px=MLS_RADIUS_PX, dense=pairs.dense, foreground=fg)
            row[name] = mask_iou(warp_foreground(rgb, fg, field)[1] > 0.5, truth)
        swaps.append(row)
    out = {"session": session_path.name}
    for label, rows in (("errors", errors), ("warp_iou", swaps)):
        groups = _groups(rows)
        out[f"{label} frames"] = {g: len(v) for g, v in groups.items()}
        for key in rows[0]:
            if key not in ("frame", "yaw"):
                out[f"{label}: {key}"] = {g: round(float(np.mean([r[key] for r in v])), 4) if v else None
                                          for g, v in groups.items()}
    return out


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError
    from bodystudio.mirror import run as run_module
    from bodystudio.mirror.evaluate import evaluate_mirror
    from bodystudio.mirror.run import load_source, run_mirror

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--stride", type=int, default=2, help="every n-th recorded frame is replayed with the swaps")
    parser.add_argument("--out", type=Path, default=None, help="folder for the run folders (default: a temporary one)")
    parser.add_argument("--feet-twisted", action="store_true",
                        help="the run with run.UNTWIST_FEET off (the IK's warm-started foot twist, before mir12aa)")
    args = parser.parse_args()
    if args.stride < 1:
        parser.error(f"--stride {args.stride}: give 1 or more")
    feet = run_module.UNTWIST_FEET
    opened = []
    for path in args.sessions:  # every session and its source body checked before any run
        try:
            session = open_session(path)
            opened.append((path, session, load_source(session)[0]))
        except BodyStudioError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) if args.out is None else args.out
        for path, session, body in opened:
            run_dir = out / f"{path.name}_legs"
            record: dict = {}
            run_module.UNTWIST_FEET = feet and not args.feet_twisted
            try:
                with recorded_poses(record):
                    run_mirror(session, session.metadata["edits"], None, side_by_side=False, progress=False,
                               run_dir=run_dir, ramp_frames=0, refine_pose=True)
            finally:
                run_module.UNTWIST_FEET = feet
            report = leg_report(path, run_dir, record, args.stride)
            report["warp_iou (evaluate_mirror)"] = evaluate_mirror(session, run_dir, source=body)["warp_iou"]
            print(json.dumps(report), flush=True)


if __name__ == "__main__":
    main()
