"""Mirror image steps, another tree's modules against this one's, called alternately in one process (MIRFAST3).

``PYTHONPATH=. python benchmarks/mirror_image_steps_ab.py /work/main [rounds]``: the warp, foreground and compose
modules of the other tree (loaded from its files; what they import comes from this tree) and this tree's are
called one after the other, ``rounds`` times (default 21), on the bench's rendered frames (one and two actors),
numba / OpenCV / BLAS on one thread; prints the median process CPU ms per step, (other, this). On a loaded shared
machine this alternation, call by call, separates a few milliseconds where whole bench runs overlap.

numba's cache goes to a temporary folder for this process: the other tree's compiled kernels, loaded under other
module names, must not land in either tree's ``__pycache__`` (the other tree would then fail to load them).
"""

from __future__ import annotations

import os
import tempfile

os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="mirror_ab_numba_")  # before numba is imported

import importlib.util  # noqa: E402
import inspect  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _cpu_ms(fn) -> float:
    c = time.process_time()
    fn()
    return (time.process_time() - c) * 1e3


def alternate_cpu_ms(steps: dict, rounds: int, digits: int = 2) -> dict:
    """``{name: (other ms, this ms)}``: each step's two calls ``(other, this)`` run once to warm up, then called
    alternately ``rounds`` times; the median process CPU ms of each, rounded to ``digits``."""
    out = {}
    for name, (a, b) in steps.items():
        a()
        b()
        ta, tb = [], []
        for _ in range(rounds):
            ta.append(_cpu_ms(a))
            tb.append(_cpu_ms(b))
        out[name] = (round(float(np.median(ta)), digits), round(float(np.median(tb)), digits))
    return out


def actor_labels(case) -> np.ndarray | None:
    """The player of each pixel of a bench frame's player mask (each actor's side of the frame), as the run passes
    the graph cut when it reshapes several players; None for one actor."""
    if case.actors == 1:
        return None
    centres = sorted(case.camera.project(V.mean(0, keepdims=True))[0, 0]
                     for V in np.split(case.source_vertices, case.actors))
    side = 1 + np.searchsorted(np.add(centres[1:], centres[:-1]) / 2, np.arange(case.player_mask.shape[1]))
    return np.where(case.player_mask, side[None], 0).astype(np.uint8)


def _steps(case, ow, of, oc, rounds: int) -> dict:
    """(other, this) median CPU ms of each image step on one bench frame."""
    from bodystudio.mirror import compose as C
    from bodystudio.mirror import foreground as F
    from bodystudio.mirror import warp as W
    from bodystudio.mirror.run import MLS_ALPHA, MLS_RADIUS_PX, N_HANDLES, RIM_COS, frame_pairs

    actors = case.actors
    bg = C.update_background(None, case.background, np.zeros(case.true_mask.shape, bool))
    S, T = np.split(case.source_vertices, actors), np.split(case.target_vertices, actors)
    F1 = case.faces[: len(case.faces) // actors]
    labels = actor_labels(case)

    # the other tree's pairs as its run.frame_pairs makes them: front faces only where its warp_pairs has them
    # (``closed``, MIRFAST3); without it the pairs step compared a tree's full renders with this one's front faces
    closed = {"closed": True} if "closed" in inspect.signature(ow.warp_pairs).parameters else {}

    def other_pairs():
        if actors == 1:
            return ow.warp_pairs(S[0], T[0], F1, case.camera, N_HANDLES, rim_cos=RIM_COS, dense=True, **closed)
        return ow.actors_warp_pairs(S, T, F1, case.camera, N_HANDLES, rim_cos=RIM_COS, dense=True, **closed)

    def this_pairs():
        return frame_pairs(S, T, F1, case.camera)

    po, pt = other_pairs(), this_pairs()
    fg_o = of.refine_foreground(case.rgb, case.player_mask, background=bg)
    fg_t = F.refine_foreground(case.rgb, case.player_mask, background=bg, labels=labels)

    def field(mod, p, fg):
        # the run's call: with its refined foreground where the tree's field takes it (MIR12l: the extras carried)
        extra = {"foreground": fg} if "foreground" in inspect.signature(mod.mls_warp_field).parameters else {}
        return lambda: mod.mls_warp_field(p.src_uv, p.dst_uv, kind="similarity", alpha=MLS_ALPHA, groups=p.groups,
                                          radius_px=MLS_RADIUS_PX, dense=p.dense, **extra)

    f_o, f_t = field(ow, po, fg_o)(), field(W, pt, fg_t)()
    wo, ao = ow.warp_foreground(case.rgb, fg_o, f_o)
    wt, at = W.warp_foreground(case.rgb, fg_t, f_t)
    steps = {
        "pairs": (other_pairs, this_pairs),
        "graph cut": (lambda: of.refine_foreground(case.rgb, case.player_mask, background=bg),
                      lambda: F.refine_foreground(case.rgb, case.player_mask, background=bg, labels=labels)),
        "warp field": (field(ow, po, fg_o), field(W, pt, fg_t)),
        "warp (remap)": (lambda: ow.warp_foreground(case.rgb, fg_o, f_o),
                         lambda: W.warp_foreground(case.rgb, fg_t, f_t)),
        "compose": (lambda: oc.compose(wo, ao, bg, case.rgb, fg_o), lambda: C.compose(wt, at, bg, case.rgb, fg_t)),
    }
    out = alternate_cpu_ms(steps, rounds)
    out["sum"] = (round(sum(v[0] for v in out.values()), 2), round(sum(v[1] for v in out.values()), 2))
    return out


def compare(other_tree: str | Path, rounds: int = 21) -> dict:
    """{"1 actor": {step: (other ms, this ms)}, "2 actors": ...} (see the module docstring)."""
    from benchmarks.bench_mirror import one_core
    from bodystudio.mirror.image_case import cached_image_case

    root = Path(other_tree) / "bodystudio" / "mirror"
    ow, of, oc = (_load(f"other_{n}", root / f"{n}.py") for n in ("warp", "foreground", "compose"))
    with one_core():
        return {f"{a} actor{'s' if a > 1 else ''}": _steps(cached_image_case(None, 0, a), ow, of, oc, rounds)
                for a in (1, 2)}


if __name__ == "__main__":
    import shutil

    try:
        print(json.dumps(compare(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 21)))
    finally:
        shutil.rmtree(os.environ["NUMBA_CACHE_DIR"], ignore_errors=True)
