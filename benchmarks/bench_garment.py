"""Garment §6-7: render on the fitted actor, refine in image space (flow §7.1, RBF silhouette warp §7.2-7.3),
composite by depth; garment_iou / PSNR / SSIM against the true render, with each refinement step ablated in
the same run, on hidden subjects, with a perturbed oracle fit (and the real §4 fit once it exists)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import markdown_table

#: Subjects the tests do not use (tests: 3, 4), each with its motion.
SUBJECTS = ((21, "walk"), (37, "arm_flex"))
CONFIGS = (("full refinement", {}), ("no flow (§7.1 off)", {"flow": False}), ("no RBF warp (§7.2 off)", {"rbf": False}),
           ("no depth compositing", {"depth": False}),
           ("unrefined (3D render only)", {"flow": False, "rbf": False, "depth": True}))


def _real_fit(session_path: Path, stature_m: float, out: Path):
    """The §4 fit of the gfit branch when it is installed; None otherwise."""
    try:
        from bodystudio.garment.fit import fit_garment_video
    except ImportError:
        return None
    return fit_garment_video(str(session_path), stature_m, out)


def _score(fit_dir: Path, session, target: dict, texture_size: int, fit=None, min_frame_iou: float | None = None
           ) -> dict:
    from bodystudio.garment.composite import composite_errors, render_garment_video

    rows = {}
    for name, options in CONFIGS:
        # every frame is refined: the perturbed oracle's silhouette IoU (0.6-0.75) is below the fit gate
        doc = render_garment_video(fit_dir, target["name"], target["pattern"], None, seed=target["seed"],
                                   texture_size=texture_size, fit=fit, min_frame_iou=min_frame_iou, **options)
        err = composite_errors(fit_dir, session)
        rows[name] = {**err, "ms": doc["ms_per_frame"]}
    return rows


def run(quick: bool = False) -> str:
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    n_frames = 3 if quick else 10
    table, timing, notes = [], [], []
    summary: dict[str, dict[str, list[float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for subject, motion in SUBJECTS:
            root = Path(tmp) / f"s{subject}"
            session = synth_garment_session(root / "session", subject_seed=subject, n_frames=n_frames, motion=motion,
                                            seed=subject)
            g = session.gt_garment
            fits = {"perturbed oracle": perturbed_fit(ground_truth_fit(session), seed=subject)}
            try:
                real = _real_fit(root / "session", session.gt_subject["stature_m"], root / "real_fit")
            except Exception as exc:  # the benchmark reports a failing fit, it does not hide the others
                notes.append(f"subject {subject}: the real fit failed ({type(exc).__name__}: {exc})")
                real = None
            if real is not None:
                fits["real fit (§4)"] = real
            for fit_name, fit in fits.items():
                fit_dir = root / fit_name.split()[0]
                if fit_name != "real fit (§4)":
                    save_garment_fit(fit_dir, fit, "benchmark")
                else:
                    fit_dir = root / "real_fit"
                rows = _score(fit_dir, session, g["target"], g["texture_size"],
                              min_frame_iou=0.0 if fit_name == "perturbed oracle" else None)
                for name, r in rows.items():
                    table.append([subject, motion, fit_name, name, round(r["garment_iou"], 4),
                                  round(r["psnr_person"], 2), round(r["ssim_person"], 3)])
                    summary.setdefault(fit_name, {}).setdefault(name, []).append(r["garment_iou"])
                full = rows["full refinement"]["ms"]
                timing.append([subject, fit_name] + [round(full.get(k, 0.0)) for k in
                                                     ("render", "flow", "rbf", "composite", "write")])
    means = [[fit_name, name, round(float(np.mean(v)), 4)] for fit_name, d in summary.items() for name, v in d.items()]
    out = ["## garment render, refinement and compositing (§6-7)", "",
           f"{len(SUBJECTS)} hidden subjects (synthetic `synth garment`, 480x640, 6k body, T-shirt in stripes over the "
           f"actor's plain one, shadows), {n_frames} frames each. Perturbed oracle fit: the true fit with every bone "
           "turned 3 deg about a random axis and the root moved 1.5 cm in every frame, lights turned 10 deg. "
           "garment_iou: composited garment pixels vs the true target layer; PSNR / SSIM: composite vs the true render "
           "inside the true person region. Each row is a full `render_garment_video` + `composite_errors` run.", "",
           markdown_table(["subject", "motion", "fit", "refinement", "garment_iou", "psnr_person dB", "ssim_person"],
                          table), "", "Mean garment_iou over the subjects:", "",
           markdown_table(["fit", "refinement", "garment_iou"], means), "",
           "Median ms per frame of the full refinement (one process, shared 2-core machine):", "",
           markdown_table(["subject", "fit", "render", "flow", "rbf", "composite", "write"], timing)]
    if "real fit (§4)" not in summary:
        notes.append("`bodystudio.garment.fit` is not installed in this checkout: no real-fit rows.")
    if notes:
        out += [""] + [f"* {n}" for n in notes]
    return "\n".join(out)
