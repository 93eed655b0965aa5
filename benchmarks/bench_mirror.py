"""Mirror stage (issue 12): per-frame cost of each step at 640x480, one and two actors, on one core.

The image steps (§5.3-§5.5) run on rendered frames with the true source/target vertices
(:mod:`bodystudio.mirror.image_case`), so the figures do not depend on the body fit. Times are the median
process CPU time of repeated calls with every thread pool held to one thread (numba, OpenCV, BLAS): the
figure one idle core would give on this shared machine; wall medians are listed beside them. The
session-side steps (IK, posing) come from MIR-BODY's timing function when it is present.
"""

from __future__ import annotations

import contextlib
import os
import time

import numpy as np

from benchmarks.timing import markdown_table
from bodystudio.mirror.run import MLS_ALPHA


def _median_ms(fn, repeats: int) -> tuple[float, float]:
    """(median CPU ms, median wall ms) of ``fn()`` after one warm-up call."""
    fn()
    cpu, wall = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return float(np.median(cpu)) * 1e3, float(np.median(wall)) * 1e3


@contextlib.contextmanager
def one_core():
    """Hold numba, OpenCV and the BLAS pools to one thread (restored afterwards)."""
    import cv2
    import numba
    from threadpoolctl import threadpool_limits

    cv_threads, nb_threads = cv2.getNumThreads(), numba.get_num_threads()
    cv2.setNumThreads(1)
    numba.set_num_threads(1)
    try:
        with threadpool_limits(1):
            yield
    finally:
        cv2.setNumThreads(cv_threads)
        numba.set_num_threads(nb_threads)


def image_step_times(case, repeats: int = 7) -> tuple[dict, dict]:
    """Per-step (CPU ms, wall ms) of the image steps on one :class:`ImageCase`, and of the alternatives."""
    from bodystudio.mirror.compose import compose, update_background
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.warp import mls_warp_field, visible_vertex_pairs, warp_foreground

    background = update_background(None, case.background, np.zeros(case.true_mask.shape, bool))
    fg = refine_foreground(case.rgb, case.player_mask, background=background)
    field = mls_warp_field(case.src_uv, case.dst_uv, kind="similarity", alpha=MLS_ALPHA, groups=case.pair_groups)
    warped, alpha = warp_foreground(case.rgb, fg, field)
    n_actors = case.actors
    per_actor = len(case.source_vertices) // n_actors
    F1 = case.faces[: len(case.faces) // n_actors]

    def pairs():
        for a in range(n_actors):
            sl = slice(a * per_actor, (a + 1) * per_actor)
            visible_vertex_pairs(case.source_vertices[sl], case.target_vertices[sl], F1, case.camera)

    def field_of(kind):
        return lambda: mls_warp_field(case.src_uv, case.dst_uv, kind=kind, alpha=MLS_ALPHA, groups=case.pair_groups)

    out = {
        "pairs (visibility + projection)": _median_ms(pairs, repeats),
        "foreground: graph cut (PyMaxflow)": _median_ms(
            lambda: refine_foreground(case.rgb, case.player_mask, background=background), repeats),
        "warp field: MLS similarity": _median_ms(field_of("similarity"), repeats),
        "warp (remap)": _median_ms(lambda: warp_foreground(case.rgb, fg, field), repeats),
        "compose": _median_ms(lambda: compose(warped, alpha, background, case.rgb, fg), repeats),
        "background update": _median_ms(lambda: update_background(background, case.rgb, fg), repeats),
    }
    side = {
        "foreground: GrabCut (OpenCV), not used": _median_ms(
            lambda: refine_foreground(case.rgb, case.player_mask, method="grabcut"), max(3, repeats // 2)),
        "warp field: MLS affine, not used": _median_ms(field_of("affine"), repeats),
        "warp field: MLS rigid, not used": _median_ms(field_of("rigid"), repeats),
    }
    return out, side


def _accuracy(case) -> dict[str, float]:
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.image_case import iou
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground

    out = {"player mask IoU (raw)": iou(case.player_mask, case.true_mask),
           "graph cut IoU": iou(refine_foreground(case.rgb, case.player_mask), case.true_mask),
           "GrabCut IoU": iou(refine_foreground(case.rgb, case.player_mask, method="grabcut"), case.true_mask)}
    for kind in ("affine", "similarity", "rigid"):
        field = mls_warp_field(case.src_uv, case.dst_uv, kind=kind, alpha=MLS_ALPHA)
        _, alpha = warp_foreground(case.rgb, case.true_mask, field)
        out[f"warp_iou {kind}"] = iou(alpha > 0.5, case.target_mask)
    return out


def _session_side_ms() -> dict[str, float] | None:
    """IK and posing per frame from MIR-BODY's timing function, when that module has landed."""
    try:
        from bodystudio.mirror import track
    except ImportError:
        return None
    fn = getattr(track, "time_tracking", None)
    if fn is None:
        return None
    try:
        return {str(k): float(v) for k, v in fn().items()}
    except Exception:  # a timing helper of another module must not hide these figures
        return None


def run(quick: bool = False) -> str:
    from bodystudio.mirror.image_case import cached_image_case

    repeats = 5 if quick else 9
    edits = {"+10 % stature, +15 kg": None, "-10 % stature, -15 kg": (("stature_m", -0.16), ("mass_kg", -15.0))}
    lines = ["## mirror", "",
             "Per-frame cost of the mirror's image steps at 640x480 (Kinect v1 colour camera), rendered frames with "
             "the true source/target vertices. Median process CPU ms with numba, OpenCV and BLAS held to one thread "
             "(wall ms beside: the machine is shared). `python -m benchmarks.run --only mirror`.", ""]
    with one_core():
        cases = {"1 actor": cached_image_case(None, 0, 1), "2 actors": cached_image_case(None, 0, 2)}
        rows, totals, side_rows = [], {}, []
        results = {name: image_step_times(case, repeats) for name, case in cases.items()}
        steps = list(next(iter(results.values()))[0])
        for step in steps:
            rows.append([step] + [f"{results[n][0][step][0]:.2f} ({results[n][0][step][1]:.1f})" for n in cases])
        for n in cases:
            totals[n] = sum(v[0] for v in results[n][0].values())
        rows.append(["**total (CPU ms)**"] + [f"**{totals[n]:.1f}**" for n in cases])
        rows.append(["**frames per second, one core**"] + [f"**{1e3 / totals[n]:.1f}**" for n in cases])
        for step in next(iter(results.values()))[1]:
            side_rows.append([step] + [f"{results[n][1][step][0]:.2f} ({results[n][1][step][1]:.1f})" for n in cases])
        lines += [markdown_table(["step", *[f"{n}: CPU ms (wall)" for n in cases]], rows), "",
                  "Alternatives measured side by side (not in the total):", "",
                  markdown_table(["step", *[f"{n}: CPU ms (wall)" for n in cases]], side_rows), ""]
        acc_rows = []
        for label, ed in edits.items():
            acc = _accuracy(cached_image_case(ed, 0, 1))
            acc_rows.append([label, *[round(v, 4) for v in acc.values()]])
        lines += ["Accuracy on the same frame (1 actor, seed 0):", "",
                  markdown_table(["edit", *acc], acc_rows), ""]
    session = _session_side_ms()
    if session:
        lines += ["Session side (MIR-BODY's timing function): " +
                  ", ".join(f"{k} {v:.1f} ms" for k, v in session.items()), ""]
    else:
        lines += ["Session side (IK, posing, depth registration) is not in these totals: their timing functions "
                  "had not landed when this was measured.", ""]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines.append(f"Load average at the end: {load:.1f}.")
    return "\n".join(lines)


if __name__ == "__main__":
    print(run(quick=os.environ.get("BENCH_QUICK") == "1"))
