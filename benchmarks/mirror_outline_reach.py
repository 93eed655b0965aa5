"""How far outside the target body the dense warp should show the person (MIR12k): warp variants of the same frames.

Usage: PYTHONPATH=. python benchmarks/mirror_outline_reach.py [--first N] [--iterations K] [--frames A:B]
[--variants NAME ...] SESSION

``run_mirror`` (the session's edits, no ramp, no video) runs once; in every frame its warp field is recomputed for
each variant from the same foreground, pairs and dense correspondence, and each warped mask (``alpha > 0.5``) is
scored against the target's true silhouette (player 1). Variants:

* ``mls6``: the field before MIR12k (the outline band 6 px, MLS beyond it: ``band_px=6, mls_outside=True``);
* ``cutB``: that field with every pixel farther than ``B`` px outside the fitted target body (its rasterised
  silhouette, ``dense.source_uv`` finite) mapped outside the image;
* ``bandB``: ``band_px=B`` (the run's field since MIR12k with another band);
* ``innerB``: ``inner_band_px=B``;
* ``scaleM_B``: the band's pixels ``d`` px outside the target mapped ``M d`` px outside the source's outline,
  nothing beyond ``B`` px;
* ``extraN``: the run's field with the foreground regions reaching more than ``N`` px outside the fitted source body
  carried (``extra_reach_px=N``, MIR12l); ``noextra``: none carried (MIR12k's field).

With ``--reach`` also, per frame, how far the true foreground of player 1 (``gt/person``) and the run's refined
foreground reach outside the fitted source body's silhouette: the largest distance and the pixels beyond 2-16 px
(summed), the misalignment distribution ``EXTRA_REACH_PX`` is chosen on.

``--iterations K``: the pose refinement's Gauss-Newton steps (the run's own otherwise). Prints, over all scored
frames and over those from ``--first`` on (the frames ``eval mirror`` scores after the CLI's 30-frame ramp), the
mean warp_iou of the run ("base") and of each variant, and the base's false positives / negatives split by where
they lie: inside the fitted target body, in the 6 px outside it, beyond (``fp_in``, ``fp_band``, ``fp_out``;
``fn_in``, ``fn_out``), and ``body_iou``: the fitted target body's own silhouette against the truth.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np


def inside_distance(dense, shape) -> tuple[np.ndarray, np.ndarray]:
    """The fitted target body's silhouette (H, W) and each pixel's distance from it."""
    H, W = shape
    x0, y0 = dense.origin
    inside = np.isfinite(dense.source_uv[..., 0])
    full = np.zeros((H, W), np.uint8)
    h, w = inside.shape
    full[y0:y0 + h, x0:x0 + w] = inside
    return full > 0, cv2.distanceTransform(1 - full, cv2.DIST_L2, 3)


def scaled_outline(field, dense, band_px: float, inner_px: float, m: float) -> None:
    """``warp.refine_outline`` with the band's pixels ``d`` px outside the target mapped ``m d`` outside the source."""
    from bodystudio.mirror import warp as W

    x0, y0 = dense.origin
    inside = np.isfinite(dense.source_uv[..., 0])
    for (r0, r1), (c0, c1) in W.people_boxes(inside | dense.source_mask, W._outline_margin_px(band_px * m, inner_px)):
        sub = inside[r0:r1, c0:c1]
        dist, label = cv2.distanceTransformWithLabels((~sub).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5,
                                                      labelType=cv2.DIST_LABEL_PIXEL)
        dist = np.where(sub, dist, 0.5 + m * (dist - 0.5)).astype(np.float32)
        depth_in = cv2.distanceTransform(sub.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        W._outline_band(field[y0 + r0:y0 + r1, x0 + c0:x0 + c1], dense.source_uv[r0:r1, c0:c1], sub, dist, label,
                        W._signed_distance(dense.source_mask[r0:r1, c0:c1]),
                        float(band_px * m + 0.5 * (1 - m) + 1e-3), float(x0 + c0), float(y0 + r0), depth_in,
                        float(inner_px))


def variant_field(name: str, field_fn, src, dst, shape, kw) -> np.ndarray:
    from bodystudio.mirror.warp import OUTSIDE_PX

    dense = kw["dense"]
    if name == "mls6":
        return field_fn(src, dst, shape, **{**kw, "band_px": 6.0, "mls_outside": True})
    if name.startswith("cut"):
        f = field_fn(src, dst, shape, **{**kw, "band_px": 6.0, "mls_outside": True})
        f[inside_distance(dense, shape)[1] > float(name[3:])] = OUTSIDE_PX
        return f
    if name.startswith("band"):
        return field_fn(src, dst, shape, **{**kw, "band_px": float(name[4:])})
    if name.startswith("inner"):
        return field_fn(src, dst, shape, **{**kw, "inner_band_px": float(name[5:])})
    if name.startswith("scale"):
        m, b = (float(x) for x in name[5:].split("_"))
        f = np.full((*shape, 2), OUTSIDE_PX, np.float32)
        scaled_outline(f, dense, b, 8.0, m)
        f[inside_distance(dense, shape)[1] > b] = OUTSIDE_PX
        return f
    if name == "noextra":
        return field_fn(src, dst, shape, **{**kw, "extra_reach_px": None})
    if name.startswith("extra"):
        return field_fn(src, dst, shape, **{**kw, "extra_reach_px": float(name[5:])})
    raise SystemExit(f"unknown variant {name!r}")


REACH_PX = (2, 4, 6, 8, 10, 12, 16)


def outside_reach(mask: np.ndarray, dense) -> dict:
    """How far ``mask`` (H, W) reaches outside the fitted source body (``dense.source_mask``): the largest distance
    and the pixel counts beyond each of :data:`REACH_PX`."""
    H, W = mask.shape
    x0, y0 = dense.origin
    h, w = dense.source_mask.shape
    body = np.zeros((H, W), np.uint8)
    body[y0:y0 + h, x0:x0 + w] = dense.source_mask
    d = cv2.distanceTransform(1 - body, cv2.DIST_L2, cv2.DIST_MASK_5)[mask]
    return {"max": float(d.max()) if d.size else 0.0, **{f"gt{n}": int((d > n).sum()) for n in REACH_PX}}


def main() -> None:
    from bodystudio.capture.session import open_session
    from bodystudio.mirror import run as R
    from bodystudio.mirror.evaluate import mask_iou

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("session", type=Path)
    parser.add_argument("--first", type=int, default=0, help="first frame of the second mean (the CLI's scored frames)")
    parser.add_argument("--frames", default=None, help="a slice A:B[:C] of the session's frame ids")
    parser.add_argument("--iterations", type=int, default=None, help="Gauss-Newton steps of the pose refinement")
    parser.add_argument("--variants", nargs="*", default=["mls6", "cut2", "cut1", "band2", "band0"])
    parser.add_argument("--reach", action="store_true", help="the foreground's reach outside the source body")
    parser.add_argument("--rows", type=Path, default=None, help="write each frame's row to this JSON-lines file")
    args = parser.parse_args()
    if args.iterations is not None:
        R.refine_steps = lambda n, k=args.iterations: k
    field_fn, warp_fn, frame_fn = R.mls_warp_field, R.warp_foreground, R.mirror_frame
    state: dict = {"rows": []}

    def field(src, dst, shape, **kw):
        f = field_fn(src, dst, shape, **kw)
        state["fields"] = {"base": f}
        if kw.get("dense") is not None:
            state["inside"] = inside_distance(kw["dense"], shape)
            state["dense"] = kw["dense"]
            for v in args.variants:
                state["fields"][v] = variant_field(v, field_fn, src, dst, shape, kw)
        return f

    def warp(rgb, fg, f):
        out = warp_fn(rgb, fg, f)
        frame = session.frame(state["index"])
        gt = frame.gt_mirror
        if gt is None or frame.gt_person is None or "inside" not in state:
            return out
        players = list(gt["players"])
        if 1 not in players or not bool(gt["reported"][players.index(1)]):
            return out
        target = frame.gt_target_person == 1
        inside, d = state["inside"]
        row = {"i": state["index"], "body_iou": mask_iou(inside, target)}
        if args.reach:
            row["reach_true"] = outside_reach(frame.gt_person == 1, state["dense"])
            row["reach_fg"] = outside_reach(np.asarray(fg, bool), state["dense"])
        for name, vf in state["fields"].items():
            w = warp_fn(rgb, fg, vf)[1] > 0.5
            row[name] = mask_iou(w, target)
            if name == "base":
                fp, fn = w & ~target, target & ~w
                row.update(fp_in=int((fp & inside).sum()), fp_band=int((fp & ~inside & (d <= 6)).sum()),
                           fp_out=int((fp & (d > 6)).sum()), fn_in=int((fn & inside).sum()),
                           fn_out=int((fn & ~inside).sum()))
        state["rows"].append(row)
        return out

    def frame_step(inp, *a, **k):
        state["index"] = inp.index
        state.pop("inside", None)
        return frame_fn(inp, *a, **k)

    R.mls_warp_field, R.warp_foreground, R.mirror_frame = field, warp, frame_step
    session = open_session(args.session)
    ids = list(session.frame_ids)
    if args.frames:
        ids = ids[slice(*[int(x) if x else None for x in args.frames.split(":")])]
    with tempfile.TemporaryDirectory() as tmp:
        R.run_mirror(session, session.metadata["edits"], None, side_by_side=False, progress=False,
                     run_dir=Path(tmp) / "run", ramp_frames=0, refine_pose=True, frames=ids)
    rows = state["rows"]
    if args.rows is not None:
        args.rows.write_text("".join(json.dumps(r) + "\n" for r in rows))
    if args.reach:
        for key in ("reach_true", "reach_fg"):
            mx = np.array([r[key]["max"] for r in rows])
            print(json.dumps({"session": args.session.name, key: {
                "max_px_median": round(float(np.median(mx)), 1), "max_px_p90": round(float(np.percentile(mx, 90)), 1),
                "max_px_max": round(float(mx.max()), 1),
                **{f"px_beyond_{n}": int(sum(r[key][f"gt{n}"] for r in rows)) for n in REACH_PX},
                **{f"frames_beyond_{n}": int(sum(r[key][f"gt{n}"] > 0 for r in rows)) for n in REACH_PX}}}),
                  flush=True)
    names = ["base", *args.variants]
    for label, sel in (("all", rows), (f"from frame {args.first}", [r for r in rows if r["i"] >= args.first])):
        if not sel:
            continue
        print(json.dumps({"session": args.session.name, "frames": label, "n": len(sel),
                          **{k: round(float(np.mean([r[k] for r in sel])), 4) for k in [*names, "body_iou"]},
                          **{k: int(np.sum([r[k] for r in sel])) for k in ("fp_in", "fp_band", "fp_out", "fn_in",
                                                                            "fn_out")}}), flush=True)


if __name__ == "__main__":
    main()
