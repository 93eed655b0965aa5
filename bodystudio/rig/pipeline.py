"""Scan -> rigged avatar, the whole of Avatar Reshaping §4-5: fit (eq. 5), skeleton transfer (eq. 4, 6),
skin weights (eq. 7), optional reshaping (§5.1), ready for export.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from bodystudio.body.skinning import posed_joints
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.register.fit import ModelFit, fit_model
from bodystudio.rig.avatar import Avatar
from bodystudio.rig.skeleton_transfer import joint_mean_value_coordinates, transfer_joint_coordinates
from bodystudio.rig.weights import barycentric_weight_transfer, harmonic_weight_transfer

log = logging.getLogger(__name__)

# A human scan fits the model to a few millimetres (median); a chair, a box or a dog does not.
NON_HUMAN_FIT_MM = 15.0
GOOD_FIT_MM = 1.5  # synthetic scans fit to 0.9-1.2 mm median (surface pairs) when the fit found the right basin
# ... and to 2.2-2.7 mm at the 90th percentile; a limb in a wrong basin can leave the median good (1.2 mm) while
# the 90th percentile is tens of millimetres (a hand 10 cm off).
GOOD_FIT_P90_MM = 6.0
THOROUGH_FIT = {"max_iterations": 40, "scan_sample_factor": 4, "lm_iterations": 8}  # restarts: slower, surer
RESTART_SURFACE_FROM = 20  # restarts: vertex pairs for 20 iterations (they found the basin where surface pairs did not)
FIT_ATTEMPTS = 3
TEMPLATES = {"6k": "6k", "13k": "full", "2k": "2k"}
WEIGHT_METHODS = ("harmonic", "barycentric")


@dataclass(frozen=True, eq=False)
class RigResult:
    """The avatar plus what produced it (the fit, per-stage seconds)."""

    avatar: Avatar
    fit: ModelFit
    seconds: dict = field(default_factory=dict)


def load_template_model(template: str = "6k", n_components: int = 20):
    """The statistical body model on a template resolution (``6k``, ``13k`` = full, ``2k``)."""
    from bodystudio.body.statistical import load_statistical_model

    if template not in TEMPLATES:
        raise InputError(f"unknown template {template!r}; valid: {', '.join(TEMPLATES)}")
    return load_statistical_model(resolution=TEMPLATES[template], n_components=n_components, progress=False)


def single_thread_blas():
    """BLAS on one thread inside the rig (as the calibration does): its products are at most a few hundred
    wide, and OpenBLAS' spinning thread pool made one of them 400x slower on a loaded 2-core machine."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it BLAS keeps its default threads
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def rig_scan(scan: Mesh, model, weights: str = "harmonic", stage: Callable[[str], None] | None = None,
             seed: int = 0) -> RigResult:
    """Rig a canonical scan (metres, y up, facing +z) with the statistical ``model``."""
    with single_thread_blas():
        return _rig_scan(scan, model, weights, stage, seed)


def _rig_scan(scan: Mesh, model, weights: str, stage: Callable[[str], None] | None, seed: int) -> RigResult:
    if weights not in WEIGHT_METHODS:
        raise InputError(f"unknown weight transfer {weights!r}; valid: {', '.join(WEIGHT_METHODS)}")
    seconds = {}
    tick = time.perf_counter()

    def done(name: str) -> None:
        nonlocal tick
        now = time.perf_counter()
        seconds[name] = now - tick
        tick = now
        if stage is not None:
            stage(name)

    # The fit can stop in a local minimum (a limb settled on the wrong side, a twisted spine); refit while
    # the fit is clearly worse than a good one, with other pair-sampling seeds and the first iterations on
    # vertex pairs (coarser, sticky, but on the random-pose scan they found the basin where surface pairs
    # did not), surface pairs after that.
    fit = fit_model(model, scan, seed=seed)
    for attempt in range(1, FIT_ATTEMPTS):
        if fit.fit_err_mm_median <= GOOD_FIT_MM and fit.fit_err_mm_p90 <= GOOD_FIT_P90_MM:
            break
        log.info("fit error %.1f mm median, %.1f mm p90: restarting with another sample seed", fit.fit_err_mm_median,
                 fit.fit_err_mm_p90)
        again = fit_model(model, scan, seed=seed + attempt, surface_from=RESTART_SURFACE_FROM, **THOROUGH_FIT)
        worse = again.fit_err_mm_median + again.fit_err_mm_p90 >= fit.fit_err_mm_median + fit.fit_err_mm_p90
        fit = fit if worse else again
    done("fit")
    if fit.fit_err_mm_median > NON_HUMAN_FIT_MM:
        raise InputError(f"the body model fits this scan only to {fit.fit_err_mm_median:.0f} mm (median), far above a "
                         f"human scan's few mm; is it a human body standing upright?")
    posed_heads = posed_joints(fit.skeleton, fit.pose)[0]
    mvc = joint_mean_value_coordinates(posed_heads, fit.vertices, fit.faces)
    coords = transfer_joint_coordinates(mvc, fit.vertices, fit.faces, scan.vertices, scan.faces)
    done("skeleton")
    if weights == "harmonic":
        W = harmonic_weight_transfer(scan.vertices, scan.faces, fit.vertices, fit.faces, fit.weights,
                                      scan_N=scan.vertex_normals)
    else:
        W = barycentric_weight_transfer(scan.vertices, fit.vertices, fit.faces, fit.weights)
    done("weights")
    from bodystudio.body.skinning import forward_kinematics

    M = forward_kinematics(fit.skeleton, fit.pose)
    avatar = Avatar(scan.vertices, scan.faces, scan.vertex_colors, fit.skeleton.bone_names,
                    np.asarray(fit.skeleton.parents), coords, M[:, :3, :3].copy(),
                    fit.skeleton.rest_rotations.copy(), fit.skeleton.lengths.copy(), W, fit.pose.translation.copy(),
                    {"fit_err_mm_median": fit.fit_err_mm_median, "fit_err_mm_p90": fit.fit_err_mm_p90,
                     "fit_iterations": fit.iterations, "shape_coeffs": fit.coeffs.tolist(),
                     "fit_pose_rotations": fit.pose.rotations.tolist(), "weights": weights})
    return RigResult(avatar, fit, seconds)
