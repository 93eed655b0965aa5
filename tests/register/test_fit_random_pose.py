"""Model fit (eq. 5) on a random pose: every limb's posed rotation, twist about its own axis included."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.skinning import forward_kinematics

LIMBS = ("clavicle_l", "clavicle_r", "upperarm_l", "upperarm_r", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r",
         "thigh_l", "thigh_r", "calf_l", "calf_r")


@pytest.mark.slow
def test_random_pose_limb_rotations():
    from bodystudio.register.fit import fit_model
    from bodystudio.register.synthetic import synthetic_scan
    from bodystudio.rig.pipeline import load_template_model

    scan, gt = synthetic_scan(12, "random", 6000, 1.0, True)
    model = load_template_model("6k")
    fit = fit_model(model, scan)
    names = fit.skeleton.bone_names
    M_fit = forward_kinematics(fit.skeleton, fit.pose)[:, :3, :3]
    M_true = forward_kinematics(gt.skeleton, gt.pose)[:, :3, :3]
    err = {b: np.degrees(np.linalg.norm(Rotation.from_matrix(
        M_true[gt.skeleton.index(b)].T @ M_fit[names.index(b)]).as_rotvec())) for b in LIMBS}
    # Closest-point pairs without the point-to-plane weighting left forearm twists 16-17 deg off, a uniform
    # 0.05 rad pose prior pulled them ~15 deg toward rest, and a straight-arm initial pose let arms settle 40-80
    # deg off (20K-vertex scans of subjects 11-14).
    # Measured at this size (2026-11): mean 0.90 deg, worst 1.99 deg, scan-model p90 2.23 mm, median 0.88 mm
    # (before those fixes: mean 6.4, worst 37 deg). Bounds at ~1.5x.
    detail = " ".join(f"{b}:{e:.1f}" for b, e in err.items())
    assert np.mean(list(err.values())) < 1.4, detail
    assert max(err.values()) < 3.0, detail
    assert fit.fit_err_mm_p90 < 3.4
    assert fit.fit_err_mm_median < 1.35
