"""rec15g's depth data term of the pose refinement, case by case (issue 17, mutation round mutR):
``pose_depth.depth_data_term`` with the projective association stubbed by known pairs, ``bone_vertices`` on a
stand-in body, ``combined_data_term`` with scalar and per-row weights. ``test_pose_depth_neck.py`` checks the effect
on the 2.5K template (seconds); these pin the residual, its gradient, the Huber weight and the arguments handed on.
"""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.reconstruct import pose_depth as pd
from bodystudio.reconstruct.solver import DepthConstraints

V = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.2, 0.0, 1.0], [0.3, 0.0, 1.0]])
N = np.tile([0.0, 0.0, -1.0], (4, 1))
F = [[0, 1, 2], [1, 2, 3]]


def _stubbed(monkeypatch, k=(1.0, 0.5, 0.25)):
    """``depth_constraints`` returns pairs of vertices 0, 2, 3 with points 1 mm, 2 cm and 6 cm in front (-z) and
    normals -z; the calls it got."""
    calls = []

    def stub(Vq, Nq, obs, sigma_m, max_distance_m, F=None, reach_m=0.0, reach_sigma_m=0.05):
        calls.append(dict(V=Vq, N=Nq, obs=obs, sigma_m=sigma_m, max_distance_m=max_distance_m, F=F, reach_m=reach_m,
                          reach_sigma_m=reach_sigma_m))
        vertex = np.array([0, 2, 3])
        point = Vq[vertex] - np.array([[0.0, 0.0, 0.001], [0.0, 0.0, 0.02], [0.0, 0.0, 0.06]])
        return DepthConstraints(vertex, point, np.tile([0.0, 0.0, -1.0], (3, 1)), np.array(k))

    monkeypatch.setattr(pd, "depth_constraints", stub)
    return calls


def test_the_residual_is_point_to_plane_with_the_huber_weight_and_the_normal_as_gradient(monkeypatch):
    calls = _stubbed(monkeypatch)
    term = pd.depth_data_term("obs", F, weight=2.0, robust_m=0.03, sigma_m=0.01, max_distance_m=0.04, reach_m=0.2,
                              reach_sigma_m=0.07)
    rows, r, w, G = term(V, N)
    np.testing.assert_array_equal(rows, [0, 2, 3])
    np.testing.assert_allclose(r, [-0.001, -0.02, -0.06], atol=1e-15)  # n . (v - q), n = -z, q 'in front'
    np.testing.assert_allclose(w, 2.0 * np.array([1.0, 0.5, 0.25]) * [1.0, 1.0, 0.03 / 0.06], rtol=1e-12)
    np.testing.assert_array_equal(G, np.tile([0.0, 0.0, -1.0], (3, 1)))
    (c,) = calls
    assert c["V"] is V and c["N"] is N and c["obs"] == "obs" and (c["sigma_m"], c["max_distance_m"]) == (0.01, 0.04)
    assert (c["reach_m"], c["reach_sigma_m"]) == (0.2, 0.07)
    assert c["F"].dtype == np.int64 and c["F"].flags.c_contiguous and c["F"].tolist() == F
    pd.depth_data_term("obs", np.asfortranarray(np.array(F, np.int32)))(V, N)  # int32, Fortran order: converted
    assert calls[-1]["F"].dtype == np.int64 and calls[-1]["F"].flags.c_contiguous and calls[-1]["F"].tolist() == F


def test_the_defaults_and_the_huber_threshold_at_equality(monkeypatch):
    calls = _stubbed(monkeypatch)
    rows, r, w, G = pd.depth_data_term("obs", F)(V, N)
    c = calls[0]
    assert (c["sigma_m"], c["max_distance_m"], c["reach_m"], c["reach_sigma_m"]) == (0.02, 0.05, 0.10, 0.05)
    np.testing.assert_allclose(w, [1.0, 0.5, 0.25 * 0.03 / 0.06], rtol=1e-12)  # weight 1, Huber 3 cm
    _, _, w2, _ = pd.depth_data_term("obs", F, robust_m=0.02)(V, N)  # |r| = 2 cm exactly: still quadratic
    np.testing.assert_allclose(w2, [1.0, 0.5, 0.25 * 0.02 / 0.06], rtol=1e-12)
    _, _, w0, _ = pd.depth_data_term("obs", F, robust_m=0.0)(V, N)  # zero threshold: r / max(|r|, 1e-12)
    np.testing.assert_allclose(w0, [0.0, 0.0, 0.0], atol=1e-12)


def test_a_vertex_mask_keeps_only_its_rows(monkeypatch):
    _stubbed(monkeypatch, k=(1.0, 0.5, 0.25))
    keep = np.array([False, False, True, True])
    rows, r, w, G = pd.depth_data_term("obs", F, vertices=keep)(V, N)
    np.testing.assert_array_equal(rows, [2, 3])
    np.testing.assert_allclose(r, [-0.02, -0.06], atol=1e-15)
    np.testing.assert_allclose(w, [0.5, 0.25 * 0.5], rtol=1e-12)
    assert G.shape == (2, 3)
    rows, *_ = pd.depth_data_term("obs", F, vertices=np.zeros(4, bool))(V, N)
    assert len(rows) == 0


def test_bone_vertices_are_those_whose_largest_weight_is_on_the_bones():
    body = SimpleNamespace(skeleton=SimpleNamespace(bone_names=["pelvis", "neck_01", "head", "hand_l"]),
                           weights=np.array([[0.6, 0.4, 0, 0], [0.2, 0.5, 0.3, 0], [0, 0.1, 0.9, 0],
                                             [0, 0.3, 0.3, 0.4], [0.1, 0, 0, 0.9]]))
    np.testing.assert_array_equal(pd.bone_vertices(body), [False, True, True, False, False])
    np.testing.assert_array_equal(pd.bone_vertices(body, ("hand_l", "pelvis")), [True, False, False, True, True])
    assert pd.DEPTH_BONES == ("neck_01", "head")
    with pytest.raises(ValueError):
        pd.bone_vertices(body, ("spine_03",))


def test_combined_terms_stack_their_rows_and_broadcast_a_scalar_weight():
    def a(Vq, Nq):
        return np.array([0, 1]), np.array([0.1, 0.2]), 3.0, np.ones((2, 3))

    def b(Vq, Nq):
        assert Vq is V and Nq is N
        return [2], [0.3], np.array([0.5]), np.full((1, 3), 2.0)

    rows, r, w, G = pd.combined_data_term(a, b)(V, N)
    np.testing.assert_array_equal(rows, [0, 1, 2])
    np.testing.assert_allclose(r, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(w, [3.0, 3.0, 0.5])
    np.testing.assert_allclose(G, [[1, 1, 1], [1, 1, 1], [2, 2, 2]])
    rows, r, w, G = pd.combined_data_term(a)(V, N)
    assert w.shape == (2,) and G.shape == (2, 3)
