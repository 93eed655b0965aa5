"""The rig's self-check (bodystudio/rig/plausibility.py) on clean and planted-fault scans: the figures its thresholds
come from (docs/plausibility.md, "rig").

6000-vertex synthetic scans (``synthetic_scan``, 1 mm noise, sole holes and patches) rigged with the 6k template as
``bodystudio rig`` does (``rig_scan``, restarts included): clean subjects 11, 12, 101-103 in the A-pose, 11 in the
T-pose, 101-103 in the random pose, 101 and 12 with 3 mm noise; scan files in millimetres with z up (subject 11);
faults: the feet cut off (nothing below 15 cm: 11, 12, 101), the head cut off (top 20 cm: 11), a pose three times
the random scans' spread (12, 101).

    python -m benchmarks.rig_plausibility [--quick]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = [("clean", 11), ("clean", 12), ("clean", 101), ("clean", 102), ("clean", 103), ("t-pose", 11),
         ("random pose", 101), ("random pose", 102), ("random pose", 103), ("noise 3 mm", 101), ("noise 3 mm", 12),
         ("mm, z up", 11), ("feet cut off", 11), ("feet cut off", 12), ("feet cut off", 101),
         ("head cut off", 11), ("pose 3x spread", 12), ("pose 3x spread", 101)]
QUICK = [("clean", 11), ("mm, z up", 11), ("feet cut off", 11), ("head cut off", 11), ("pose 3x spread", 12)]


def planted_scan(case: str, subject: int, path: Path) -> Path:
    import bodystudio.register.synthetic as synthetic
    from bodystudio.geometry.mesh import Mesh, save_mesh

    pose = {"t-pose": "t", "random pose": "random", "pose 3x spread": "random"}.get(case, "a")
    sigma = synthetic.RANDOM_POSE_SIGMA
    try:
        if case == "pose 3x spread":
            synthetic.RANDOM_POSE_SIGMA = {k: 3.0 * v for k, v in sigma.items()}
        scan, _ = synthetic.synthetic_scan(subject, pose, 6000, 3.0 if case == "noise 3 mm" else 1.0, True)
    finally:
        synthetic.RANDOM_POSE_SIGMA = sigma
    V, F = scan.vertices, scan.faces
    keep = None
    if case == "mm, z up":
        V = 1000.0 * V[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])
    elif case == "feet cut off":
        keep = V[F, 1].min(axis=1) > 0.15
    elif case == "head cut off":
        keep = V[F, 1].max(axis=1) < V[:, 1].max() - 0.2
    if keep is not None:
        F = F[keep]
        used = np.unique(F)
        remap = np.full(len(V), -1)
        remap[used] = np.arange(len(used))
        V, F = V[used], remap[F]
    save_mesh(path, Mesh(V, F, None))
    return path


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help=f"only {len(QUICK)} cases")
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args(argv)
    from benchmarks.timing import markdown_table
    from bodystudio.errors import BodyStudioError
    from bodystudio.register.scan import load_scan
    from bodystudio.rig.pipeline import load_template_model, rig_scan
    from bodystudio.rig.plausibility import rig_plausibility

    work = args.work or Path(tempfile.mkdtemp(prefix="rig_plaus_"))
    work.mkdir(parents=True, exist_ok=True)
    model = load_template_model("6k")
    rows, verdicts = [], {}
    for case, subject in QUICK if args.quick else CASES:
        name = f"{case} {subject}"
        path = planted_scan(case, subject, work / f"{case.replace(' ', '_').replace(',', '')}_{subject}.ply")
        t0 = time.perf_counter()
        try:
            scan, _ = load_scan(path)
            fit = rig_scan(scan, model).fit
        except BodyStudioError as exc:
            rows.append([name, "-", "-", "-", "-", f"refused before the check: {str(exc)[-70:]}"])
            print(" | ".join(rows[-1]), flush=True)
            continue
        v = rig_plausibility(fit, scan.vertices, scan.faces, path.name)
        verdicts[name] = v
        cov = v["coverage"]
        low = sorted(cov, key=lambda r: cov[r])[:2]
        rows.append([name, f"{v['fit_err_mm_median']:.2f}", f"{v['fit_err_mm_p90']:.2f}",
                     ", ".join(f"{r} {cov[r]:.2f}" for r in low), f"{time.perf_counter() - t0:.0f}",
                     "refused: " + v["problems"][0][:70] if v["problems"] else
                     "warning: " + v["warnings"][0][:70] if v["warnings"] else "ok"])
        print(" | ".join(rows[-1]), flush=True)
    (work / "verdicts.json").write_text(json.dumps(verdicts, indent=1))
    print(markdown_table(["scan", "fit median (mm)", "fit p90 (mm)", "lowest region coverage", "s", "verdict"], rows))


if __name__ == "__main__":
    main()
