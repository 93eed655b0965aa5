"""Tests of the arm-capture scores (bodystudio.muscle.evaluate) against known perturbations of the truth."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle.arm import ArmPose, part_transforms, pose_arm
from bodystudio.muscle.evaluate import biceps_peak_height, biceps_region, score_arm_sequence


@pytest.fixture(scope="module")
def truth(arm_template_2k):
    """Three frames of the 2k arm flexing at the elbow, visibility from the front, joints."""
    t = arm_template_2k
    s, e, _ = t.joints
    axis = np.cross(e - s, [0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    frames, joints = [], []
    for deg in (10.0, 20.0, 30.0):
        pose = ArmPose(np.eye(4), np.stack([np.zeros(3), np.radians(deg) * axis, np.zeros(3)]))
        frames.append(pose_arm(t.vertices, t.part_weights, t.joints, pose))
        T = part_transforms(t.joints, pose)
        joints.append(np.stack([T[k, :3, :3] @ t.joints[k] + T[k, :3, 3] for k in range(3)]))
    G = np.stack(frames)
    vis = np.stack([vertex_normals(V, t.faces)[:, 2] > 0 for V in G])
    return G, vis, np.stack(joints)


def test_truth_scores_zero(arm_template_2k, truth):
    G, vis, J = truth
    r = score_arm_sequence(G, G, arm_template_2k, vis, J)
    for k in ("median_mm", "p90_mm", "front_median_mm", "back_median_mm", "bulge_err_mm", "jitter_mm"):
        assert abs(r[k]) < 1e-9, k


def test_offset_and_jitter_are_measured(arm_template_2k, truth):
    G, vis, J = truth
    r = score_arm_sequence(G + [0.002, 0.0, 0.0], G, arm_template_2k, vis, J)
    assert abs(r["median_mm"] - 2.0) < 1e-6 and abs(r["p90_mm"] - 2.0) < 1e-6 and abs(r["jitter_mm"]) < 1e-9
    steady = np.stack([G[0] + [0.001 * k, 0.0, 0.0] for k in range(3)])  # uniform motion: no acceleration
    shaky = steady.copy()
    shaky[1] += [0.0, 0.001, 0.0]  # the middle frame 1 mm off: acceleration 2 mm at frame 1
    assert abs(score_arm_sequence(shaky, steady, arm_template_2k, vis, J)["jitter_mm"] - 2.0) < 1e-6
    back_only = G.copy()
    back_only[~vis] += [0.0, 0.0, 0.004]
    r = score_arm_sequence(back_only, G, arm_template_2k, vis, J)
    assert r["front_median_mm"] < 1e-9 and abs(r["back_median_mm"] - 4.0) < 1e-6


def test_bulge_error_is_the_biceps_peak_height(arm_template_2k, truth):
    t = arm_template_2k
    G, vis, J = truth
    region = biceps_region(t)
    assert 5 <= region.sum() < 0.3 * t.arm_mask.sum()
    assert np.all(t.part_weights[region, 1] > 0.5)
    bulged = G.copy()
    for f in range(len(G)):
        N = vertex_normals(G[f], t.faces)
        bulged[f, region] += 0.003 * N[region]
    r = score_arm_sequence(bulged, G, t, vis, J)
    assert 2.0 < r["bulge_err_mm"] < 3.01
    assert biceps_peak_height(bulged[0], region, J[0, 0], J[0, 1]) > biceps_peak_height(G[0], region, J[0, 0], J[0, 1])


def test_mismatched_sequences_raise(arm_template_2k, truth):
    G, vis, J = truth
    with pytest.raises(InputError, match="frames"):
        score_arm_sequence(G[:2], G, arm_template_2k, vis, J)


def test_surface_figures_count_the_skin_not_the_sliding(arm_template_2k, truth):
    """A surface pushed 2 mm along its normals is 2 mm off both ways; vertices that slide within the surface
    (each moved a fraction of the way to a neighbour) are off per vertex but on the surface."""
    G, vis, J = truth
    t = arm_template_2k
    r = score_arm_sequence(G, G, t, vis, J)
    assert r["surface_median_mm"] < 1e-6 and r["surface_p90_mm"] < 1e-6
    pushed = np.stack([V + 0.002 * vertex_normals(V, t.faces) for V in G])
    r = score_arm_sequence(pushed, G, t, vis, J)
    assert abs(r["surface_median_mm"] - 2.0) < 0.1 and r["surface_p90_mm"] < 2.3
    # slide each vertex 30 % of the way towards the next vertex of one of its faces: it stays on that face
    nxt = np.arange(t.n_vertices)  # a vertex first in no face stays
    nxt[t.faces[:, 0]] = t.faces[:, 1]
    slid = np.stack([V + 0.3 * (V[nxt] - V) for V in G])
    moved = np.linalg.norm(slid - G, axis=2)[:, t.arm_mask]
    r = score_arm_sequence(slid, G, t, vis, J)
    assert np.median(moved) * 1000 > 1.5 and r["median_mm"] > 1.5
    assert r["surface_median_mm"] < 0.1 * r["median_mm"], r
