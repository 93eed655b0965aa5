"""Where a mirror run's warp_iou is lost, frame by frame, with pictures of the worst frames (MIR12s).

Usage: PYTHONPATH=. python benchmarks/mirror_worst_frames.py --run DIR [--png OUT] [--worst 4] SESSION

For a synthetic mirror session and a run folder made from it (``mirror run --ramp-frames 0``, or
``benchmarks/mirror_refine_end_to_end.py --out``), every frame ``eval mirror`` scores for the run's player: its
warp_iou, the pixels the warped person misses (true target, not warped) and adds (warped, not true target) by body
part (:mod:`benchmarks.mirror_warp_parts`' groups, each pixel given to the part of the nearest pixel of the true
target body rendered with the source's faces), the true root's yaw against the camera (degrees, 0 facing it) and the
image rows / columns the target reaches. Prints a per-frame table (sorted worst first), the per-part share over the
session and the same split over the worst quarter of the frames; with ``--png`` writes for the ``--worst`` frames a
picture: grey = both, red = missed, blue = extra, green outline = the true source person (what the input showed).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.mirror_warp_parts import group_of, nearest_part_image


def root_yaw_deg(world_root: np.ndarray, camera_R: np.ndarray) -> float:
    """Yaw (degrees) of a body facing +z at rest, turned by its root's world rotation, against the camera's view."""
    facing = np.asarray(world_root) @ [0.0, 0.0, 1.0]
    towards_camera = -np.asarray(camera_R)[2]  # the camera looks along its third row in the world
    f, c = facing[[0, 2]], towards_camera[[0, 2]]
    return float(np.degrees(np.arctan2(f[0] * c[1] - f[1] * c[0], f @ c)))


def frame_losses(session_path, run_dir, player: int | None = None):
    """Per scored frame: warp_iou, missed / extra pixels by part, the root's yaw; plus the masks for pictures."""
    import cv2

    from benchmarks.mirror_pose_oracle import world_rotations
    from bodystudio.body.pose import Pose
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.run import load_source

    session = open_session(session_path)
    run_dir = Path(run_dir)
    run = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
    player = int(run.get("player", 1)) if player is None else player
    body, model = load_source(session)
    weights = np.asarray(model.weights if getattr(body, "weights", None) is None else body.weights)
    bones = list(body.skeleton.bone_names)
    part = np.array([group_of(bones[j]) for j in weights.argmax(1)])
    names = sorted(set(part))
    faces = np.asarray(body.faces)
    root = int(np.flatnonzero(np.asarray(body.skeleton.parents) < 0)[0])
    rows = []
    for i in sorted(int(f["index"]) for f in run["frames"]):
        frame = session.frame(i)
        gt = frame.gt_mirror
        if gt is None or frame.gt_target_person is None or player not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(player)
        if not gt["reported"][k]:
            continue
        target = frame.gt_target_person == player
        source = frame.gt_person == player
        warped = cv2.imread(str(run_dir / "masks" / "warped" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        fg = cv2.imread(str(run_dir / "masks" / "foreground" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        if len(gt["players"]) > 1:  # a scene of two: keep the masks near this player (as eval mirror does)
            near = cv2.dilate((source | target).astype(np.uint8), np.ones((31, 31), np.uint8)) > 0
            near &= (frame.gt_person == 0) | source
            near &= (frame.gt_target_person == 0) | target
            warped, fg = warped & near, fg & near
        _, nearest = nearest_part_image(np.asarray(gt["target_vertices"][k], float), faces, session.kinect.color,
                                        part, names)
        missed, added = target & ~warped, warped & ~target
        ys, xs = np.nonzero(target)
        rows.append({
            "frame": i, "warp_iou": mask_iou(warped, target), "fg_iou": mask_iou(fg, source),
            "unwarped_iou": mask_iou(source, target), "target_px": int(target.sum()),
            "missed": {n: int(np.count_nonzero(missed & (nearest == g))) for g, n in enumerate(names)},
            "extra": {n: int(np.count_nonzero(added & (nearest == g))) for g, n in enumerate(names)},
            "yaw_deg": root_yaw_deg(world_rotations(body.skeleton, Pose(gt["pose_rotations"][k],
                                                                         gt["pose_translations"][k]))[root],
                                    session.kinect.color.R),
            "depth_m": float((session.kinect.color.R @ gt["pose_translations"][k] + session.kinect.color.t)[2]),
            "rows": (int(ys.min()), int(ys.max())) if len(ys) else (0, 0),
            "cols": (int(xs.min()), int(xs.max())) if len(xs) else (0, 0),
            "_masks": (target, warped, source)})
    return rows, names


def picture(target, warped, source) -> np.ndarray:
    """BGR picture: grey both, red missed, blue extra, green outline of the true source person."""
    import cv2

    img = np.full(target.shape + (3,), 255, np.uint8)
    img[target & warped] = (150, 150, 150)
    img[target & ~warped] = (0, 0, 255)
    img[warped & ~target] = (255, 0, 0)
    edge = source & ~(cv2.erode(source.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    img[edge] = (0, 180, 0)
    return img


def main() -> None:
    import cv2

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--run", type=Path, required=True, help="the run folder")
    parser.add_argument("--png", type=Path, default=None, help="folder for the worst frames' pictures")
    parser.add_argument("--worst", type=int, default=4)
    parser.add_argument("--crop", action="store_true", help="crop the pictures to the person")
    args = parser.parse_args()
    rows, names = frame_losses(args.session, args.run)
    ious = np.array([r["warp_iou"] for r in rows])
    print(f"{args.session} {args.run}: {len(rows)} frames, warp_iou {ious.mean():.4f} (min {ious.min():.4f}, "
          f"quartiles {np.percentile(ious, 25):.4f} / {np.median(ious):.4f} / {np.percentile(ious, 75):.4f})")

    def split(sel, title):
        miss = {n: sum(r["missed"][n] for r in sel) for n in names}
        extra = {n: sum(r["extra"][n] for r in sel) for n in names}
        total = sum(miss.values()) + sum(extra.values())
        print(f"{title}: | part | missed px | extra px | share |")
        for n in sorted(names, key=lambda n: -(miss[n] + extra[n])):
            print(f"| {n} | {miss[n]} | {extra[n]} | {(miss[n] + extra[n]) / max(total, 1):.1%} |")

    split(rows, "all frames")
    order = sorted(rows, key=lambda r: r["warp_iou"])
    split(order[: max(1, len(order) // 4)], "worst quarter")
    print("| frame | warp_iou | fg_iou | unwarped | yaw deg | depth m | rows | cols | largest loss (part: miss/extra) "
          "|")
    for r in order:
        top = sorted(names, key=lambda n: -(r["missed"][n] + r["extra"][n]))[:2]
        print(f"| {r['frame']} | {r['warp_iou']:.4f} | {r['fg_iou']:.4f} | {r['unwarped_iou']:.4f} | "
              f"{r['yaw_deg']:+.1f} | {r['depth_m']:.2f} | {r['rows']} | {r['cols']} | "
              + ", ".join(f"{n}: {r['missed'][n]}/{r['extra'][n]}" for n in top) + " |")
    yaw = np.array([r["yaw_deg"] for r in rows])
    if len(rows) > 2:
        print(f"corr(warp_iou, |yaw|) = {np.corrcoef(ious, np.abs(yaw))[0, 1]:+.2f}; yaw range "
              f"{yaw.min():+.1f} .. {yaw.max():+.1f} deg")
    if args.png is not None:
        args.png.mkdir(parents=True, exist_ok=True)
        for r in order[: args.worst]:
            img = picture(*r["_masks"])
            if args.crop:
                (y0, y1), (x0, x1) = r["rows"], r["cols"]
                img = img[max(0, y0 - 20): y1 + 20, max(0, x0 - 20): x1 + 20]
            cv2.imwrite(str(args.png / f"{args.session.name}_{r['frame']:05d}.png"), img)


if __name__ == "__main__":
    main()
