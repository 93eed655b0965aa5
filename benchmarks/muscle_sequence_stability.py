"""Arm-muscle capture (issue 11): does the sequence fit converge? Its result's sensitivity to a 1e-12 m input change.

The capture's sequence stage (``refine.fit_arm_sequence_skeleton``, trf under a Huber loss) stopped at its
evaluation limit (``CaptureOptions.sequence_max_nfev``) on every call: its result was wherever the optimiser
happened to be, so a rounding-sized change of its input (another CPU's BLAS kernels, a numpy upgrade) moved the
capture by 1-2 mm. This runs the whole capture twice per candidate, the second time with every sequence-fit
call's rest mesh and depth points moved by ``--eps`` (random, seeded), and reports the largest change of the
captured vertices (mm), the solver's statuses and evaluation counts of the sequence fit's calls, and the CPU time:

    python -m benchmarks.muscle_sequence_stability --session /work/thr/s0 --model /work/thr/tiny.npz

``--candidate NAME:KEY=VALUE,...``: ``CaptureOptions`` fields, plus ``ftol`` / ``xtol`` / ``gtol`` handed to the
sequence fit's ``least_squares`` (none: the call's own). Without it: :data:`CANDIDATES`. scipy's statuses:
0 the evaluation limit, 1 gtol, 2 ftol, 3 xtol, 4 ftol and xtol. docs/muscle.md "Capture, the thread count".
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import time

import numpy as np

#: the candidates compared (``CaptureOptions`` fields; ftol / xtol / gtol go to the sequence fit's least_squares)
CANDIDATES = {
    "default": {},
    "old_default": {"sequence_depth_huber_only": False},  # scipy's Huber loss on every residual, 15 evaluations
    "irls_huber": {"sequence_depth_huber_only": True},
    "tight_tol": {"sequence_depth_huber_only": False, "sequence_max_nfev": 200, "ftol": 1e-12, "xtol": 1e-12,
                  "gtol": 1e-12},
    "irls_tight_tol": {"sequence_depth_huber_only": True, "sequence_max_nfev": 200, "ftol": 1e-12, "xtol": 1e-12,
                       "gtol": 1e-12},
}
TOLERANCES = ("ftol", "xtol", "gtol")


def perturbed(values: np.ndarray, eps: float, rng: np.random.Generator) -> np.ndarray:
    """``values`` moved by ``eps`` times a uniform number in [-1, 1] each."""
    return np.asarray(values, np.float64) + eps * rng.uniform(-1.0, 1.0, np.shape(values))


def capture_once(session: str, model: str, candidate: dict, eps: float, seed: int = 0) -> dict:
    """One capture under ``candidate``; each sequence-fit call's rest mesh and depth points moved by ``eps``.
    Returns the vertices, the sequence fit's solver statuses and evaluation counts, and the CPU seconds."""
    import bodystudio.muscle.capture as cap
    import bodystudio.muscle.refine as ref

    fields = {k: v for k, v in candidate.items() if k not in TOLERANCES}
    tolerances = {k: v for k, v in candidate.items() if k in TOLERANCES}
    rng = np.random.default_rng(seed)
    solves, inside = [], []
    orig_options, orig_fit, orig_ls = cap.CaptureOptions, cap.fit_arm_sequence_skeleton, ref.least_squares

    def fit(model_, shape, poses, frames, *args, **kwargs):
        if eps:
            kwargs["rest"] = perturbed(kwargs["rest"], eps, rng)
            frames = [dataclasses.replace(fr, points=perturbed(fr.points, eps, rng)) for fr in frames]
        inside.append(True)
        try:
            return orig_fit(model_, shape, poses, frames, *args, **kwargs)
        finally:
            inside.pop()

    def least_squares(*args, **kwargs):
        if not inside:
            return orig_ls(*args, **kwargs)
        res = orig_ls(*args, **{**kwargs, **tolerances})
        solves.append((int(res.status), int(res.nfev)))
        return res

    cap.CaptureOptions = functools.partial(orig_options, **fields)
    cap.fit_arm_sequence_skeleton, ref.least_squares = fit, least_squares
    try:
        t0 = time.process_time()
        vertices = cap.capture_session_arm(session, model, "full").vertices
        cpu = time.process_time() - t0
    finally:
        cap.CaptureOptions, cap.fit_arm_sequence_skeleton, ref.least_squares = orig_options, orig_fit, orig_ls
    return {"vertices": np.asarray(vertices), "solves": solves, "cpu_s": cpu}


def parse_candidate(text: str) -> tuple[str, dict]:
    """A named candidate of :data:`CANDIDATES`, or NAME:KEY=VALUE,... (values as Python literals)."""
    import ast

    name, _, items = text.partition(":")
    if not items:
        if name not in CANDIDATES:
            raise ValueError(f"unknown candidate {name!r} (known: {', '.join(CANDIDATES)}; or NAME:KEY=VALUE,...)")
        return name, dict(CANDIDATES[name])
    out = {}
    for item in items.split(","):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--candidate {text!r}: {item!r} needs KEY=VALUE")
        out[key.strip()] = ast.literal_eval(value.strip())
    return name, out


def main(argv: list[str] | None = None) -> None:
    from benchmarks.timing import markdown_table

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--session", required=True, help="a capture session folder (e.g. a 4-frame synthetic one)")
    parser.add_argument("--model", required=True, help="the arm model (.npz)")
    parser.add_argument("--eps", type=float, default=1e-12, help="the input change, metres (default 1e-12)")
    parser.add_argument("--candidate", action="append", default=[], help="NAME or NAME:KEY=VALUE,... (repeatable)")
    args = parser.parse_args(argv)
    try:
        candidates = [parse_candidate(c) for c in (args.candidate or list(CANDIDATES))]
    except (ValueError, SyntaxError) as exc:
        parser.error(str(exc))
    rows = []
    for name, candidate in candidates:
        a = capture_once(args.session, args.model, candidate, 0.0)
        b = capture_once(args.session, args.model, candidate, args.eps)
        change_mm = float(np.abs(a["vertices"] - b["vertices"]).max()) * 1e3
        statuses = " ".join(f"{s}/{n}" for s, n in a["solves"])
        rows.append([name, f"{change_mm:.2e}", statuses, f"{a['cpu_s']:.1f}"])
        print(f"{name}: max vertex change {change_mm:.3e} mm; sequence fit status/nfev per call: {statuses}; "
              f"cpu {a['cpu_s']:.1f} s", flush=True)
    print(markdown_table(["candidate", "max vertex change (mm)", "sequence fit status/nfev per call", "cpu (s)"],
                         rows))


if __name__ == "__main__":
    main()
