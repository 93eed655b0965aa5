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


@pytest.mark.parametrize("solver", ["gs", "jacobi"])
def test_reaches_ground_truth_from_a_perturbed_init(body_2k, synthetic_capture, perturbed_init, solver):
    cap = synthetic_capture
    before = surface_error(perturbed_init, body_2k.faces, cap["V"], cap["F"])
    result = deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], cap["masks"],
                                    RapidSkinParams(solver=solver))
    after = surface_error(result.vertices, body_2k.faces, cap["V"], cap["F"])
    assert before.median_mm > 12.0
    assert after.median_mm < 8.0
    assert after.p90_mm < before.p90_mm
    iou_before = silhouette_iou(perturbed_init, body_2k.faces, cap["rig"], cap["masks"])
    iou_after = silhouette_iou(result.vertices, body_2k.faces, cap["rig"], cap["masks"])
    assert min(iou_after.values()) > 0.93 and min(iou_after.values()) > min(iou_before.values())
    assert min(result.n_silhouette) > 200


def test_baselines_reach_ground_truth_too(body_2k, synthetic_capture, perturbed_init):
    cap = synthetic_capture
    for solver in ("cholesky", "cg"):
        result = deform_to_observations(perturbed_init, body_2k.faces, cap["rig"], cap["masks"],
                                        RapidSkinParams(solver=solver, outer_iterations=4))
        assert surface_error(result.vertices, body_2k.faces, cap["V"], cap["F"]).median_mm < 8.0, solver


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
