"""The planted bugs of issue 17, replayed: each one put by hand into a scratch copy of the tree, the fast tests
of its module run against it (``pytest -m "not slow" -x``), the result recorded; writes
docs/mutation/planted-bugs.md.

The issue's reviewer planted 34 bugs of four kinds (drop a term, flip a sign, skip an iteration, return the
input) and named the ones that survived or were caught by a single test; they are the first rows of ``BUGS``
below, the rest are of the same kinds in the stages that landed after (muscle, mirror, garment) and in the
numba kernels mutmut never mutates. A bug is *caught* when at least one selected test fails; the fast tests
of a module are a subset of ``make test-fast``, so caught here means caught by the fast tier.

Usage: python scripts/planted_bugs.py [--only ID ...] [--timeout 900] [--out docs/mutation/planted-bugs.md]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
from mutate import git_commit, scratch_copy, tests_for  # noqa: E402

OUT = ROOT / "docs" / "mutation" / "planted-bugs.md"


@dataclass(frozen=True)
class Bug:
    id: str
    module: str
    what: str
    old: str
    new: str
    tests: tuple[str, ...] = ()  # run first (then the module's own fast tests); globs relative to the root
    module_tests: bool = True  # False: only ``tests`` (a claim about one test file)
    marker: str = "not slow"  # pytest -m expression ("" runs the slow tests too)

    def test_files(self, root: Path) -> list[str]:
        first = sorted({p for pat in self.tests for p in _glob(root, pat)})
        rest = tests_for(self.module, root) if self.module_tests else []
        return first + [t for t in rest if t not in first]


def _glob(root: Path, pattern: str) -> list[str]:
    return [str(p.relative_to(root)) for p in root.glob(pattern)]


SIL, LAP, SKIN = ("bodystudio/reconstruct/silhouette.py", "bodystudio/geometry/laplacian.py",
                  "bodystudio/body/skinning.py")
WEIGHTS, CALIB, KINECT = "bodystudio/rig/weights.py", "bodystudio/calib/calibrate.py", "bodystudio/capture/kinect.py"
BGSUB, RAPID, SOLVER = ("bodystudio/capture/silhouettes.py", "bodystudio/reconstruct/rapid_skin.py",
                        "bodystudio/reconstruct/solver.py")

BUGS = (
    # --- named in issue 17 ---------------------------------------------------------------------------------
    Bug("sil-k-one", SIL, "silhouette weights: every k set to 1 where Eq. 10 is applied",
        "silhouette_weight(off, alpha_px),", "np.ones_like(off),"),
    Bug("sil-alpha-tau", SIL, "silhouette weights: alpha replaced by tau where Eq. 10 is applied",
        "silhouette_weight(off, alpha_px),", "silhouette_weight(off, tau_px),"),
    Bug("cot-squared", LAP, "cotangent weights squared before normalising",
        "w = C.data.astype(np.float64)\n", "w = C.data.astype(np.float64) ** 2\n"),
    Bug("cot-uniform", LAP, "uniform weights instead of cotangent ones",
        "w = C.data.astype(np.float64)\n", "w = np.ones(len(C.data))\n"),
    Bug("dqs-no-normalise", SKIN, "dual-quaternion skinning without normalising the blend",
        "    b_real /= norm\n    b_dual /= norm\n", ""),
    Bug("dqs-no-antipodal", SKIN, "dual-quaternion skinning without the antipodal sign fix",
        "ws = weights * sign\n", "ws = weights\n"),
    Bug("lbs-dominant-translation", SKIN, "LBS with the dominant bone's translation only",
        "t = weights @ transforms[:, :3, 3]\n    return np.einsum",
        "t = transforms[np.argmax(weights, axis=1), :3, 3]\n    return np.einsum"),
    Bug("harmonic-no-fill", WEIGHTS, "harmonic weights: no harmonic fill (closest-point weights returned)",
        "if len(free) == 0:", "if True:"),
    Bug("harmonic-compat-flipped", WEIGHTS, "harmonic weights: the compatibility threshold flipped",
        "model_N[tri]) > COMPATIBLE_COS", "model_N[tri]) < COMPATIBLE_COS"),
    Bug("harmonic-graph-laplacian", WEIGHTS, "harmonic weights: a graph Laplacian instead of the cotangent one",
        "return igl.cotmatrix(V, F).tocsc()",
        "A = igl.adjacency_matrix(F).astype(np.float64)\n"
        "        return (A - sp.diags(np.asarray(A.sum(1)).ravel())).tocsc()"),
    Bug("ba-no-robust-loss", CALIB, "bundle adjustment with the robust loss ignored",
        "levenberg_marquardt(residuals, jacobian, x0, loss, loss_scale_px, max_iterations)",
        "levenberg_marquardt(residuals, jacobian, x0, 'linear', loss_scale_px, max_iterations)"),
    Bug("kinect-no-grazing", KINECT, "Kinect model without grazing-angle dropout",
        "missing = grazing_mask(V, F, result, sensor, model.grazing_angle_deg)",
        "missing = np.zeros(depth.shape, bool)"),
    Bug("kinect-no-holes", KINECT, "Kinect model without holes",
        "depth[random_holes(depth.shape, rng, model)] = 0.0", "pass"),
    Bug("bgsub-no-dark-rule", BGSUB, "background subtraction without the 'darker than a shadow' rule",
        " | (alpha < params.shadow_floor)", ""),
    Bug("bgsub-no-hole-fill", BGSUB, "background subtraction without hole filling",
        "return fill_small_holes(m, params.max_hole_fraction * m.size)", "return m"),
    Bug("bgsub-all-components", BGSUB, "background subtraction keeping every connected component",
        "m = largest_components(m > 0, params.min_component_fraction, params.min_component_px)", "m = m > 0"),
    Bug("alg1-one-outer-fewer", RAPID, "Algorithm 1 with one outer iteration fewer",
        "for outer in range(params.outer_iterations):", "for outer in range(params.outer_iterations - 1):"),
    Bug("alg1-no-solve", RAPID, "the deformation solver never called",
        "V = solve_constraints(V, cs, params.solver, inner, lme)", "pass"),
    Bug("alg1-no-solve-cli", RAPID, "the same, against the reconstruct CLI tests alone, slow ones included (the "
        "issue: they passed)", "V = solve_constraints(V, cs, params.solver, inner, lme)", "pass",
        ("tests/reconstruct/test_sequence_cli.py",), module_tests=False, marker=""),
    # --- the same kinds in the numba kernels' callers and in the later stages --------------------------------
    Bug("gs-one-sweep-fewer", SOLVER, "Gauss-Seidel: one sweep fewer than asked for",
        "return _gauss_seidel_sweeps(V, *args, int(inner_iterations))",
        "return _gauss_seidel_sweeps(V, *args, int(inner_iterations) - 1)"),
    Bug("gs-no-depth", SOLVER, "Gauss-Seidel: the depth constraints' term dropped",
        "k_dep = projection_weight(dep.k, inner_iterations)",
        "k_dep = 0.0 * projection_weight(dep.k, inner_iterations)"),
    Bug("mirror-graphcut-identity", "bodystudio/mirror/foreground.py", "mirror: the graph cut replaced by the identity "
        "(the player mask returned)", "out[crop] = inner | cut", "out[crop] = sub_mask > 0"),
    Bug("mirror-mls-identity", "bodystudio/mirror/warp.py", "mirror: the MLS warp replaced by the identity",
        "_, mapped[mine] = mls_transforms(nodes[mine], t[pairs], s[pairs], kind, alpha, radius_px)",
        "mapped[mine] = nodes[mine]"),
    Bug("muscle-no-refinement", "bodystudio/muscle/capture.py", "muscle: the Sec. 7 refinement skipped (model "
        "meshes returned)",
        "out_t = _refinement(", "out_t = model_meshes or _refinement("),  # a non-empty list: never called
    Bug("muscle-no-detail-smoothing", "bodystudio/muscle/capture.py", "muscle: the refinement's Eq. 13-14 detail "
        "averaging skipped", "if o.detail_sigma_frames > 0 and n >= 3:", "if False:"),
    Bug("garment-no-visibility", "bodystudio/garment/lighting.py", "garment lighting: the light visibility term "
        "dropped from Eq. 7", "G = G * visibility", "G = G"),
    Bug("garment-no-clamp", "bodystudio/garment/lighting.py", "garment lighting: max(0, n.d) not clamped",
        "G = np.clip(normals @ directions.T, 0.0, None)", "G = normals @ directions.T"),
)


def plant(path: Path, old: str, new: str) -> str:
    """Replace the one occurrence of ``old`` in ``path``; returns the original text."""
    text = path.read_text()
    count = text.count(old)
    if count != 1:
        raise SystemExit(f"{path}: the planted bug's anchor occurs {count} times (expected once): {old!r}")
    path.write_text(text.replace(old, new))
    return text


def run_bug(bug: Bug, work: Path, timeout_s: int) -> dict:
    target = work / bug.module
    original = plant(target, bug.old, bug.new)
    tests = bug.test_files(work)
    env = dict(os.environ, PYTHONPATH=str(work), PYTHONDONTWRITEBYTECODE="1")
    t0 = time.monotonic()
    try:
        marker = ["-m", bug.marker] if bug.marker else []
        proc = subprocess.run(["nice", "-n", "10", sys.executable, "-m", "pytest", "-q", "-x", *marker,
                               "-p", "no:cacheprovider", *tests], cwd=work, env=env, capture_output=True,
                              text=True, timeout=timeout_s)
        rc, out = proc.returncode, proc.stdout + proc.stderr
    except subprocess.TimeoutExpired:
        rc, out = None, ""
    finally:
        target.write_text(original)
    failed = re.findall(r"^(?:FAILED|ERROR) (\S+)", out, re.M)
    result = {None: "timeout", 0: "**survived**", 1: "caught"}.get(rc, f"error (pytest exit {rc})")
    return {"id": bug.id, "module": bug.module, "what": bug.what, "result": result,
            "first_failure": failed[0] if failed else "", "seconds": round(time.monotonic() - t0),
            "tests": tests}


def render(rows: list[dict], commit: str) -> str:
    caught = sum(r["result"] == "caught" for r in rows)
    lines = [
        "# Planted bugs (issue 17), replayed",
        "",
        "Generated by `python scripts/planted_bugs.py` (each bug planted in a scratch copy of the tree, the",
        "module's fast tests run with `pytest -m \"not slow\" -x` unless the row says otherwise, the first failing",
        "test recorded). "
        f"Commit {commit}, {dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC: **{caught} of {len(rows)} caught**.",
        "",
        "| id | module | planted bug | result | first failing test | s |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['id']} | `{r['module']}` | {r['what']} | {r['result']} | "
                     f"{('`' + r['first_failure'] + '`') if r['first_failure'] else ''} | {r['seconds']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", default=None, help="bug ids (default: all)")
    parser.add_argument("--timeout", type=int, default=900, help="seconds per bug")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    known = {b.id for b in BUGS}
    unknown = sorted(set(args.only or ()) - known)
    if unknown:
        parser.error(f"unknown bug id(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    bugs = [b for b in BUGS if args.only is None or b.id in args.only]
    rows = []
    with tempfile.TemporaryDirectory(prefix="planted_") as tmp:
        work = Path(tmp)
        commit = git_commit()  # the tree copied now is the one replayed (commits landing meanwhile are not)
        scratch_copy(ROOT, work)
        for bug in bugs:  # check every anchor before spending minutes on the first bug
            plant(work / bug.module, bug.old, bug.old)
        for bug in bugs:
            row = run_bug(bug, work, args.timeout)
            print(f"{row['id']:28s} {row['result']:14s} {row['seconds']:5d} s  {row['first_failure']}", flush=True)
            rows.append(row)
    args.out.write_text(render(rows, commit))
    print(f"wrote {args.out}")
    return 0 if all(r["result"] == "caught" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
