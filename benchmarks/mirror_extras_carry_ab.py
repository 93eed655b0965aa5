"""The field with extras (a bag and hair) against the field without, MIR12l's carry against MIR12m's, in one process.

``PYTHONPATH=. python benchmarks/mirror_extras_carry_ab.py [rounds]``: the bench's rendered frames, one person and
two (true bodies, +10 % stature +15 kg), each person with a bag held out beside the hip and hair on the head, painted
into the foreground as tests/mirror/test_warp_extras_frame.py does; ``mls_warp_field(..., dense=, foreground=fg,
extra_reach_px=8)`` timed with the reference extras functions (MIR12l's, ``_foreground_extras_reference`` /
``_carry_extras_reference``) and with this tree's, alternately, ``rounds`` times (default 15), and the same call on
the frame without the bag and hair; numba / OpenCV on one thread; prints the median process CPU ms of each and
whether the fields are equal.
"""

from __future__ import annotations

import sys
import time

import cv2
import numpy as np

from bodystudio.mirror import warp
from bodystudio.mirror.image_case import cached_image_case
from bodystudio.mirror.run import N_HANDLES, RIM_COS
from bodystudio.mirror.warp import EXTRA_REACH_PX, mls_warp_field, warp_pairs

BAG_OUT_PX = int(EXTRA_REACH_PX) + 14
HAIR_UP_PX = int(EXTRA_REACH_PX) + 6


def frame_with_extras(actors: int = 1):
    """(pairs: src_uv, dst_uv, groups, dense; foreground without extras; with a bag and hair on each actor) on the
    bench's rendered frame (one or two actors)."""
    case = cached_image_case(None, actors=actors)
    fg = case.true_mask.copy()
    n, actor = cv2.connectedComponents(fg.astype(np.uint8))
    extras = fg.copy()
    for k in range(1, n):
        own = actor == k
        rows = np.flatnonzero(own.any(1))
        if len(rows) < 100:
            continue
        mid = (rows[0] + rows[-1]) // 2 + 10  # about the hip
        for r in range(mid, mid + 24):  # a bag attached to the body's right side
            right = np.flatnonzero(own[r])[-1]
            extras[r, right - 2:right + BAG_OUT_PX] = True
        top = rows[0]
        cols = np.flatnonzero(own[top + 4])
        extras[top - HAIR_UP_PX:top + 4, cols[0] - 2:cols[-1] + 3] = True  # hair on the head
    if actors == 1:
        pairs = warp_pairs(case.source_vertices, case.target_vertices, case.faces, case.camera, N_HANDLES,
                           rim_cos=RIM_COS, dense=True, closed=True)
        pairs = (pairs.src_uv, pairs.dst_uv, None, pairs.dense)
    else:
        pairs = (case.src_uv, case.dst_uv, case.pair_groups, case.dense)
    return pairs, fg, extras


def _cpu_ms(fn) -> float:
    c = time.process_time()
    fn()
    return (time.process_time() - c) * 1e3


def main(rounds: int = 15, actors: int = 1) -> dict:
    cv2.setNumThreads(1)
    try:
        import numba
        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass
    (src_uv, dst_uv, groups, dense), fg, extras = frame_with_extras(actors)
    shape = fg.shape

    def field(foreground):
        return mls_warp_field(src_uv, dst_uv, shape, groups=groups, dense=dense, foreground=foreground,
                              extra_reach_px=EXTRA_REACH_PX)

    new_fx, new_cx = warp.foreground_extras, warp.carry_extras
    ref_cx = getattr(warp, "_carry_extras_reference", new_cx)
    ref_fx_own = getattr(warp, "_foreground_extras_reference", None)

    def ref_fx(fg_mask, dense, reach_px, distances=None):  # MIR12l's own distance transform
        return (ref_fx_own or new_fx)(fg_mask, dense, reach_px)

    def old():
        warp.foreground_extras, warp.carry_extras = ref_fx, ref_cx
        try:
            return field(extras)
        finally:
            warp.foreground_extras, warp.carry_extras = new_fx, new_cx

    def new():
        return field(extras)

    def without():
        return field(fg)

    a, b = old(), new()
    same = bool(np.array_equal(a, b))
    carried = int(((a[..., 0] != warp.OUTSIDE_PX) & (without()[..., 0] == warp.OUTSIDE_PX)).sum())
    times = {"without extras": [], "extras, MIR12l": [], "extras, this tree": []}
    for _ in range(rounds):
        times["without extras"].append(_cpu_ms(without))
        times["extras, MIR12l"].append(_cpu_ms(old))
        times["extras, this tree"].append(_cpu_ms(new))
    out = {k: round(float(np.median(v)), 2) for k, v in times.items()}
    out["fields equal"] = same
    out["carried pixels"] = carried
    return out


if __name__ == "__main__":
    n_rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 15
    for n_actors in (1, 2):
        print(f"{n_actors} actor(s):", main(n_rounds, n_actors))
