"""Algorithm 1 end to end on a small synthetic capture: 4 cameras, 2K template (issue 5 acceptance)."""

import numpy as np
import pytest

from bodystudio.errors import InputError, SessionError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.reconstruct.evaluate import silhouette_iou, surface_error
from bodystudio.reconstruct.pose_init import initialise_pose
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations


@pytest.fixture(scope="module")
def perturbed_init(body_2k, synthetic_capture):
    """Template posed from noisy joints, then inflated 20 mm along its normals."""
    rng = np.random.default_rng(5)
    joints = synthetic_capture["joints"] + rng.normal(scale=0.01, size=synthetic_capture["joints"].shape)
    V = initialise_pose(body_2k, joints).vertices
    return V + 0.020 * vertex_normals(V, body_2k.faces)


# Measured (2K template, 4 cameras 640x480, seed 5): the inflated start scores median 14.77 mm, p90 30.7 mm,
# min IoU 0.775; the uninflated posed template alone 6.85 mm. After Algorithm 1 (8 outer iterations):
#   gs      median 4.36 mm, p90 15.4 mm, min IoU 0.936
#   jacobi  median 4.78 mm, p90 16.4 mm, min IoU 0.938
#   cholesky (4 outer) 3.81 mm, cg (4 outer) 4.54 mm
# Bounds sit at ~1.25x the measured median: below the uninflated template (6.85 mm), so a solve that only
# undoes the inflation, or does nothing, fails.
@pytest.mark.parametrize("solver, median_mm, p90_mm", [("gs", 5.5, 17.5), ("jacobi", 6.0, 18.5)])
def test_reaches_ground_truth_from_a_perturbed_init(body_2k, synthetic_capture, perturbed_init, solver, median_mm,
                                                   p90_mm):
    cap = synthetic_capture
    before = surface_error(perturbed_init, body_2k.faces, cap["V"], cap["F"])
    result = deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], cap["masks"],
                                    RapidSkinParams(solver=solver))
    after = surface_error(result.vertices, body_2k.faces, cap["V"], cap["F"])
    assert before.median_mm > 14.0
    assert after.median_mm < 0.4 * before.median_mm
    assert after.median_mm < median_mm, after.median_mm
    assert after.p90_mm < p90_mm, after.p90_mm
    iou_before = silhouette_iou(perturbed_init, body_2k.faces, cap["rig"], cap["masks"])
    iou_after = silhouette_iou(result.vertices, body_2k.faces, cap["rig"], cap["masks"])
    assert min(iou_before.values()) < 0.8
    assert min(iou_after.values()) > 0.925, iou_after  # 0.936 / 0.938 measured
    assert min(result.n_silhouette) > 200


def test_baselines_reach_ground_truth_too(body_2k, synthetic_capture, perturbed_init):
    cap = synthetic_capture
    for solver, median_mm in (("cholesky", 4.8), ("cg", 5.7)):  # 3.81 / 4.54 mm measured (4 outer iterations)
        result = deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], cap["masks"],
                                        RapidSkinParams(solver=solver, outer_iterations=4))
        err = surface_error(result.vertices, body_2k.faces, cap["V"], cap["F"]).median_mm
        assert err < median_mm, (solver, err)


def test_algorithm1_runs_every_outer_iteration(body_2k, synthetic_capture, perturbed_init):
    """No outer iterations re-match and solve No times; the second one still gains a lot (measured median
    7.45 mm after one, 5.39 mm after two, 4.86 after three), so a loop one short fails the bound."""
    cap = synthetic_capture
    seen = []
    result = deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], cap["masks"],
                                    RapidSkinParams(outer_iterations=2), callback=lambda o, V: seen.append(V.copy()))
    assert len(seen) == 2 and len(result.n_silhouette) == 2
    assert np.abs(seen[1] - seen[0]).max() > 1e-3  # the second pass moved the mesh
    err = surface_error(result.vertices, body_2k.faces, cap["V"], cap["F"]).median_mm
    assert err < 6.3, err


def test_bad_inputs(body_2k, synthetic_capture, perturbed_init):
    cap = synthetic_capture
    masks = dict(cap["masks"])
    masks["cam_02"] = np.zeros_like(masks["cam_02"])
    with pytest.raises(SessionError, match="cam_02 is empty"):
        deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], masks)
    with pytest.raises(InputError, match="unknown solver"):
        RapidSkinParams(solver="lu")
    with pytest.raises(InputError, match="depth observation"):
        deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], cap["masks"],
                               RapidSkinParams(constraints=("depth",)))
