"""Garment §6-7: render on the fitted actor, refine in image space (flow §7.1, RBF silhouette warp §7.2-7.3),
composite by depth, then the hem matte onto the worn garment's edges (gar13e); garment_iou / PSNR / SSIM against the
true render, with each refinement step ablated in the same run, on hidden subjects, with a perturbed oracle fit and the
real §4 fit (with and without its final shape refinement, step 4b, and with 4b but without the poses refined on the
refined shape, step 4c)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import markdown_table

#: Subjects the tests do not use (tests: 3, 4), each with its motion.
SUBJECTS = ((21, "walk"), (37, "arm_flex"))
CONFIGS = (("full refinement", {}), ("no flow (§7.1 off)", {"flow": False}), ("no RBF warp (§7.2 off)", {"rbf": False}),
           ("no depth compositing", {"depth": False}), ("no hem matte", {"hem": False}),
           ("unrefined (3D render only)", {"flow": False, "rbf": False, "depth": True, "hem": False}))
REAL_FIT = "real fit (§4)"
#: The real fit without the final shape refinement of step 4b (gar13c), scored with the full §7 refinement only.
REAL_FIT_NO_4B = "real fit, no shape refinement (4b)"
#: The real fit with step 4b but without the poses' refinement on the refined shape (step 4c, gar13d), full §7 only.
REAL_FIT_NO_4C = "real fit, no pose refinement (4c)"


def _real_fits(session_path: Path, stature_m: float, root: Path) -> dict:
    """The §4 fit with its defaults (``garment fit``) and, from the same pose fit, without the final shape
    refinement (step 4b) and with 4b but without the poses' refinement (step 4c): ``refine_garment_fit`` of the fit
    made with ``shape_refinement=False`` is what ``fit_garment_video`` gives with them on. ``{name: (fit folder,
    fit)}``."""
    from bodystudio.garment.fit import fit_garment_video, refine_garment_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.person import person_frames

    base = fit_garment_video(str(session_path), stature_m, root / "real_fit_no_4b", shape_refinement=False)
    images = person_frames(str(session_path)).images
    refined = refine_garment_fit(base, images, stature_m)
    save_garment_fit(root / "real_fit", refined, "benchmark")
    no_4c = refine_garment_fit(base, images, stature_m, pose_refinement=False)
    save_garment_fit(root / "real_fit_no_4c", no_4c, "benchmark")
    return {REAL_FIT: (root / "real_fit", refined), REAL_FIT_NO_4B: (root / "real_fit_no_4b", base),
            REAL_FIT_NO_4C: (root / "real_fit_no_4c", no_4c)}


def _score(fit_dir: Path, session, target: dict, texture_size: int, fit=None, min_frame_iou: float | None = None,
           configs=CONFIGS) -> dict:
    from bodystudio.garment.composite import composite_errors, render_garment_video

    rows = {}
    for name, options in configs:
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
            oracle = perturbed_fit(ground_truth_fit(session), seed=subject)
            save_garment_fit(root / "perturbed", oracle, "benchmark")
            fits = {"perturbed oracle": (root / "perturbed", oracle)}
            try:
                fits.update(_real_fits(root / "session", session.gt_subject["stature_m"], root))
            except Exception as exc:  # the benchmark reports a failing fit, it does not hide the others
                notes.append(f"subject {subject}: the real fit failed ({type(exc).__name__}: {exc})")
            for fit_name, (fit_dir, fit) in fits.items():
                rows = _score(fit_dir, session, g["target"], g["texture_size"],
                              min_frame_iou=0.0 if fit_name == "perturbed oracle" else None,
                              configs=CONFIGS[:1] if fit_name in (REAL_FIT_NO_4B, REAL_FIT_NO_4C) else CONFIGS)
                for name, r in rows.items():
                    table.append([subject, motion, fit_name, name, round(r["garment_iou"], 4),
                                  round(r["psnr_person"], 2), round(r["ssim_person"], 3)])
                    summary.setdefault(fit_name, {}).setdefault(name, []).append(r["garment_iou"])
                if fit_name != "perturbed oracle":
                    off_mm = 1e3 * abs(fit.stature_m - session.gt_subject["stature_m"])
                    notes.append(f"subject {subject}, {fit_name}: stature {off_mm:.2f} mm off, fit ms per frame "
                                 f"{fit.timings_ms}")
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
    if REAL_FIT not in summary:
        notes.append("`bodystudio.garment.fit` is not installed in this checkout: no real-fit rows.")
    if notes:
        out += [""] + [f"* {n}" for n in notes]
    return "\n".join(out)
