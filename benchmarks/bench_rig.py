"""Scan -> rigged avatar (issue 6): accuracy on synthetic scans of held-out subjects and poses, weight
transfer comparison (harmonic vs barycentric vs bounded biharmonic), reshaping, and `bodystudio rig` time.

Subjects 101-103 (never used by tests), poses a / t / random, 100K vertices (20K with --quick), 1 mm noise,
holes; template 6k. The weight table adds subjects 104-109 at 30K vertices (weights only) and, as a bound,
the ground-truth weights on the same transferred skeleton: what no transfer can beat, so the gap between
it and barycentric is all a better transfer can win. Timing: median of 5 runs of the whole
`bodystudio rig` path (load, fit, skeleton, weights, export) on one 100K scan, in this process.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.timing import markdown_table, median_seconds

CASES = ((101, "a"), (102, "t"), (103, "random"))
WEIGHT_CASES = ((104, "a"), (105, "t"), (106, "random"), (107, "a"), (108, "t"), (109, "random"))
WEIGHT_CASE_VERTICES = 30_000


def compare_weights(mesh, gt, result, to_canonical, with_bbw: bool) -> list[tuple[str, dict]]:
    """Held-out-pose errors of each weight transfer on the avatar's own (transferred) skeleton.

    The region column is the scan vertices without a compatible correspondence, where harmonic and
    barycentric differ."""
    from bodystudio.rig.evaluate import evaluate_rig, match_vertices
    from bodystudio.rig.weights import (
        barycentric_weight_transfer,
        bounded_biharmonic_weights,
        compatible_correspondences,
        limit_influences,
    )

    av, fit = result.avatar, result.fit
    compatible, _ = compatible_correspondences(mesh.vertices, mesh.vertex_normals, fit.vertices, fit.faces,
                                               fit.weights)
    region = ~compatible

    def score(W):
        return evaluate_rig(dataclasses.replace(av, weights=W), gt, to_canonical, region=region)

    idx = match_vertices(av.vertices, gt.posed_vertices(gt.pose) @ np.asarray(to_canonical).T)
    truth = limit_influences(np.asarray(gt.weights[idx].todense()))
    rows = [("harmonic (eq. 7)", score(av.weights)),
            ("barycentric", score(barycentric_weight_transfer(mesh.vertices, fit.vertices, fit.faces, fit.weights)))]
    if with_bbw:
        bones = np.array([i for i, b in enumerate(av.bone_names)
                          if not b.startswith(("thumb", "index", "middle", "ring", "pinky")) and b != "Root"])
        tails = av.heads + av.bind_rotations[:, :, 1] * av.bone_lengths[:, None]
        rows.append(("bounded biharmonic (igl.bbw)",
                     score(bounded_biharmonic_weights(mesh.vertices, mesh.faces, av.heads, tails, bones))))
    rows.append(("ground-truth weights (bound)", score(truth)))
    return rows


def run(quick: bool = False) -> str:
    from bodystudio.cli.rig import rig_to_files
    from bodystudio.errors import InputError
    from bodystudio.register.scan import load_scan
    from bodystudio.register.synthetic import save_synthetic_scan, synthetic_scan
    from bodystudio.rig.evaluate import evaluate_rig
    from bodystudio.rig.pipeline import load_template_model, rig_scan
    from bodystudio.rig.reshape import reshape_avatar

    n_vertices = 20_000 if quick else 100_000
    model = load_template_model("6k")
    tmp = Path(tempfile.mkdtemp(prefix="bench_rig_"))
    rows, weight_rows, reshape_rows = [], [], []
    timing_scan = None
    for subject, pose in CASES:
        scan, gt = synthetic_scan(subject, pose, n_vertices, 1.0, True)
        path = tmp / f"s{subject}.ply"
        save_synthetic_scan(path, scan, gt)
        timing_scan = timing_scan or path
        mesh, report = load_scan(path)
        t0 = time.perf_counter()
        result = rig_scan(mesh, model)
        seconds = time.perf_counter() - t0
        av = result.avatar
        harmonic = evaluate_rig(av, gt, report.to_canonical)
        rows.append([subject, pose, mesh.n_vertices, harmonic["joint_err_mm_mean"], harmonic["joint_err_mm_max"],
                     harmonic["pose_vertex_err_mm_mean"], harmonic["weights_l1_mean"], harmonic["fit_err_mm_median"],
                     seconds])
        fit = result.fit
        for name, r in compare_weights(mesh, gt, result, report.to_canonical, with_bbw=True):
            weight_rows.append([subject, pose, mesh.n_vertices, name, r["pose_vertex_err_mm_mean"],
                                r["pose_vertex_err_mm_region"], r["weights_l1_mean"]])
        if pose == "a":
            before = float(np.ptp(av.vertices[:, 1]))
            t1 = time.perf_counter()
            taller, _ = reshape_avatar(av, fit, model, {"stature_m": 0.05})
            t_reshape = time.perf_counter() - t1
            after = float(np.ptp(taller.vertices[:, 1]))
            reshape_rows.append([subject, "stature +0.05 m", 1000 * (after - before), t_reshape])
    for subject, pose in WEIGHT_CASES:
        scan, gt = synthetic_scan(subject, pose, min(n_vertices, WEIGHT_CASE_VERTICES), 1.0, True)
        path = tmp / f"s{subject}.ply"
        save_synthetic_scan(path, scan, gt)
        mesh, report = load_scan(path)
        try:
            result = rig_scan(mesh, model)
        except InputError as exc:  # a failed fit is a finding of this benchmark, not a reason to stop it
            weight_rows.append([subject, pose, mesh.n_vertices, f"rig failed (up axis {report.up_axis}): {exc}",
                                float("nan"), float("nan"), float("nan")])
            continue
        for name, r in compare_weights(mesh, gt, result, report.to_canonical, with_bbw=False):
            weight_rows.append([subject, pose, mesh.n_vertices, name, r["pose_vertex_err_mm_mean"],
                                r["pose_vertex_err_mm_region"], r["weights_l1_mean"]])
    t_rig = median_seconds(lambda: rig_to_files(timing_scan, tmp / "timing.glb"), repeats=5, warmup=0) \
        if not quick else float("nan")
    out = ["## Rig (issue 6): scan -> rigged avatar", "",
           f"Synthetic scans, {n_vertices} vertices (before holes), 1 mm noise, holes; template 6k; "
           "`.venv/bin/python -m benchmarks.run --only rig`.", "",
           markdown_table(["subject", "pose", "vertices", "joint err mean mm", "joint err max mm",
                           "held-out pose vertex err mm", "weights L1", "fit err median mm", "rig s"], rows), "",
           "Skin weight transfer on the same transferred skeleton (held-out poses). Region: the scan vertices "
           "without a compatible correspondence (closest model triangle's normal over 60° off), where harmonic "
           "fills in and barycentric copies; bound: the ground-truth weights (4 influences).", "",
           markdown_table(["subject", "pose", "vertices", "weights", "pose vertex err mm", "region err mm",
                           "weights L1"], weight_rows), "",
           "Reshaping (deformation transfer, §5.1); stature measured as the scan's height:", "",
           markdown_table(["subject", "edit", "measured change mm", "seconds"], reshape_rows), ""]
    if not quick:
        out += [f"`bodystudio rig` end to end on a {n_vertices}-vertex scan (load, fit, skeleton, weights, glb): "
                f"median {t_rig:.2f} s over 5 runs."]
    return "\n".join(out)
