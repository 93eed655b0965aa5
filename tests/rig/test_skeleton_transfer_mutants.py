"""bodystudio.rig.skeleton_transfer cases left open by the analytic tests (issue 17, mutation testing):
fill orientation whichever corner each face lists first, a face-less mesh, and a batch of points where one
lies on an edge (its own special case must not spoil the other points' coordinates)."""

import numpy as np
import pytest
import trimesh

from bodystudio.rig.skeleton_transfer import close_holes, mean_value_coordinates


def _open_box():
    box = trimesh.creation.box()
    V, F = np.asarray(box.vertices), np.asarray(box.faces, np.int64)
    top = np.all(V[F][:, :, 2] > 0.49, axis=1)
    bottom = np.all(V[F][:, :, 2] < -0.49, axis=1)
    return V, F[~(top | bottom)]  # two square holes


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize("roll", [0, 1, 2])
def test_fill_faces_run_against_the_boundary_whichever_corner_a_face_starts_at(roll, reverse, monkeypatch):
    """Rolling every face's corner list keeps the surface and its orientation; a loop given against the
    faces' edges (libigl's run along them: reversed here) has its edge (loop[1], loop[0]) in the (0, 1),
    (1, 2) or (2, 0) edge set depending on the roll, and each must be searched."""
    import igl

    import bodystudio.rig.skeleton_transfer as st

    real = igl.boundary_loop_all
    monkeypatch.setattr(st.igl, "boundary_loop_all",
                        lambda F: [np.asarray(loop)[::-1] if reverse else loop for loop in real(F)])
    V, F = _open_box()
    F = np.roll(F, roll, axis=1)
    Vc, Fc, P = close_holes(V, F)
    assert len(Fc) == len(F) + 8
    edges = np.r_[Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]]
    directed = {tuple(e) for e in edges}
    assert len(directed) == len(edges)  # no directed edge twice: consistently oriented
    assert all((b, a) in directed for a, b in directed)  # closed
    assert trimesh.Trimesh(Vc, Fc, process=False).volume == pytest.approx(1.0, abs=1e-12)


def test_a_mesh_without_faces_has_nothing_to_close():
    V = np.random.default_rng(0).normal(size=(5, 3))
    F = np.zeros((0, 3), np.int64)
    Vc, Fc, P = close_holes(V, F)
    np.testing.assert_array_equal(Vc, V)
    assert Fc.shape == (0, 3)
    np.testing.assert_array_equal(P.toarray(), np.eye(5))


def test_a_point_on_an_edge_does_not_spoil_the_other_points_of_its_batch():
    """A point on an edge has the edge's coordinates (1/2, 1/2), from the triangle case (h = pi: this needs
    the angles to full precision near pi; with 2 arcsin(l / 2) h came out ~1e-8 short and the point got
    coordinates reproducing (0.076, 0.076, 0) instead of (0.5, 0.5, 0)). Its sines of pi are 0, which must
    only drop that point's triangles, not every point's."""
    V = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    points = np.array([(V[0] + V[2]) / 2, [0.1, -0.2, 0.05], [-0.3, 0.1, 0.2]])
    M = mean_value_coordinates(points, V, F)
    assert np.isfinite(M).all()
    np.testing.assert_allclose(M[0], [0.5, 0, 0.5, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(M.sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(M @ V, points, atol=1e-9)
    np.testing.assert_allclose(M[1:], mean_value_coordinates(points[1:], V, F), atol=1e-12)
