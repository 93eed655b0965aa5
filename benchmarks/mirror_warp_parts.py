"""Where a mirror run's warp_iou is lost, by body part of the true target body (MIR12d).

``PYTHONPATH=. python benchmarks/mirror_warp_parts.py SESSION [SESSION ...] [--from-frame N]``: for a session with
a ``mirror run`` (``SESSION/mirror/run``, run with ``--ramp-frames 0`` against the whole edit) and its ground truth
(``gt/mirror`` target vertices, ``gt/target/person``), every frame ``eval mirror`` scores for player 1: the pixels
the warped person misses (true target, not warped) and adds (warped, not true target), each given to the body part
of the nearest pixel of the true target body rendered with the source body's faces (part: the bone of the largest
skinning weight of the face's first vertex, grouped as :data:`GROUPS`). Prints a table per session: missed and
extra pixels per part, its share of the error, and the pooled IoU if that part were exact.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: Body-part groups by bone name (the statistical model's skeleton).
GROUPS = (("head/neck", ("head", "neck")), ("hands", ("hand", "index", "middle", "pinky", "ring", "thumb")),
          ("forearms", ("lowerarm",)), ("upper arms/shoulders", ("upperarm", "clavicle")),
          ("feet", ("foot", "ball")), ("shins", ("calf",)), ("thighs", ("thigh",)),
          ("torso/pelvis", ("spine", "pelvis", "root")))


def group_of(bone: str) -> str:
    """The :data:`GROUPS` name of a bone (``other:NAME`` for one in none)."""
    name = bone.lower()
    for group, keys in GROUPS:
        if any(k in name for k in keys):
            return group
    return f"other:{bone}"


def nearest_part_image(vertices: np.ndarray, faces: np.ndarray, camera, part: np.ndarray, names) -> tuple:
    """The body rendered in ``camera`` and, for every pixel, the index in ``names`` of the part (``part``: a group
    name per vertex) of the nearest rendered pixel (the first vertex of the triangle there): (render result, (h, w)
    int image)."""
    import cv2

    from bodystudio.capture.render import render

    r = render(vertices, faces, camera)
    part_px = np.full(r.mask.shape, -1, np.int64)
    part_px[r.mask] = np.searchsorted(names, part[faces[r.triangle_id[r.mask], 0]])
    _, label = cv2.distanceTransformWithLabels((~r.mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                               labelType=cv2.DIST_LABEL_PIXEL)
    rows, cols = np.nonzero(r.mask)
    return r, part_px[rows[label - 1], cols[label - 1]]


def parts_of_the_loss(session_path, first_frame: int = 0) -> dict:
    """Missed / extra pixels per body part over the scored frames (see the module docstring)."""
    import cv2

    from bodystudio.capture.session import open_session
    from bodystudio.mirror.evaluate import mask_iou
    from bodystudio.mirror.run import load_source

    session = open_session(session_path)
    body, model = load_source(session)
    weights = np.asarray(model.weights if getattr(body, "weights", None) is None else body.weights)
    bones = list(body.skeleton.bone_names)
    part = np.array([group_of(bones[j]) for j in weights.argmax(1)])
    names = sorted(set(part))
    faces = np.asarray(body.faces)
    run_dir = Path(session.path) / "mirror" / "run"
    run = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
    miss, extra = dict.fromkeys(names, 0), dict.fromkeys(names, 0)
    inter = union = 0
    ious, checks = [], []
    for i in sorted(int(f["index"]) for f in run["frames"]):
        frame = session.frame(i)
        gt = frame.gt_mirror
        if i < first_frame or gt is None or frame.gt_target_person is None or 1 not in list(gt["players"]):
            continue
        k = list(gt["players"]).index(1)
        if not gt["reported"][k]:
            continue
        target = frame.gt_target_person == 1
        warped = cv2.imread(str(run_dir / "masks" / "warped" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        r, nearest = nearest_part_image(np.asarray(gt["target_vertices"][k], float), faces, session.kinect.color,
                                        part, names)
        missed, added = target & ~warped, warped & ~target
        for g, name in enumerate(names):
            miss[name] += int(np.count_nonzero(missed & (nearest == g)))
            extra[name] += int(np.count_nonzero(added & (nearest == g)))
        inter += int(np.count_nonzero(target & warped))
        union += int(np.count_nonzero(target | warped))
        ious.append(mask_iou(warped, target))
        checks.append(mask_iou(r.mask, target))
    return {"frames": len(ious), "warp_iou": float(np.mean(ious)), "pooled_iou": inter / max(union, 1),
            "render_check_min": float(min(checks)), "missed": miss, "extra": extra, "inter": inter, "union": union}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--from-frame", type=int, default=0)
    args = parser.parse_args()
    for path in args.sessions:
        r = parts_of_the_loss(path, args.from_frame)
        total = sum(r["missed"].values()) + sum(r["extra"].values())
        print(f"{path} (frames >= {args.from_frame}): {r['frames']} frames, warp_iou {r['warp_iou']:.4f}, pooled IoU "
              f"{r['pooled_iou']:.4f}; the true target rendered against gt/target/person: IoU >= "
              f"{r['render_check_min']:.3f}")
        print("| part | missed px | extra px | share of the error | pooled IoU were it exact |")
        print("|---|---|---|---|---|")
        for name in sorted(r["missed"], key=lambda n: -(r["missed"][n] + r["extra"][n])):
            err = r["missed"][name] + r["extra"][name]
            print(f"| {name} | {r['missed'][name]} | {r['extra'][name]} | {err / max(total, 1):.1%} | "
                  f"{(r['inter'] + r['missed'][name]) / (r['union'] - r['extra'][name]):.4f} |")


if __name__ == "__main__":
    main()
