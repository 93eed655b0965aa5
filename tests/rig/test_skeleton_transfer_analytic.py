"""Skeleton transfer (eqs. 4 and 6 of Avatar Reshaping) on small meshes with closed-form answers."""

import numpy as np
import pytest
import trimesh

from bodystudio.rig.skeleton_transfer import (
    close_holes,
    closest_points,
    joint_mean_value_coordinates,
    mean_value_coordinates,
    transfer_joint_coordinates,
)


@pytest.fixture(scope="module")
def blob():
    """A closed, non-convex, irregular surface: an icosphere squashed and dented."""
    s = trimesh.creation.icosphere(subdivisions=2)
    V = s.vertices * [0.3, 0.5, 0.2]
    V[:, 0] *= 1.0 + 0.3 * np.sin(3 * V[:, 1])
    return V, s.faces.astype(np.int64)


def test_mean_value_coordinates_have_linear_precision_inside(blob):
    V, F = blob
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.08, 0.08, (12, 3))
    M = mean_value_coordinates(points, V, F)
    np.testing.assert_allclose(M.sum(1), 1.0, atol=1e-12)
    assert np.abs(M @ V - points).max() < 1e-12
    # and outside the surface, where they are still defined (signed)
    far = np.array([[0.0, 0.0, 0.5], [0.6, 0.1, 0.0]])
    assert np.abs(mean_value_coordinates(far, V, F) @ V - far).max() < 1e-10


def test_mean_value_coordinates_on_the_surface_are_the_vertex_or_barycentric(blob):
    V, F = blob
    M = mean_value_coordinates(V[[5]], V, F)
    expected = np.zeros(len(V))
    expected[5] = 1.0
    np.testing.assert_allclose(M[0], expected, atol=1e-12)
    lam = np.array([0.2, 0.3, 0.5])
    p = lam @ V[F[7]]
    M = mean_value_coordinates(p, V, F)
    np.testing.assert_allclose(M[0, F[7]], lam, atol=1e-9)
    assert np.abs(np.delete(M[0], F[7])).max() < 1e-9


def test_mean_value_coordinates_of_an_octahedron():
    V = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    M = mean_value_coordinates(np.array([[0.0, 0, 0], [0.0, 0, 0.5]]), V, F)
    np.testing.assert_allclose(M[0], 1.0 / 6.0, atol=1e-12)  # by symmetry
    # on the axis: the equator's four vertices share by symmetry, linear precision fixes the rest
    assert M[1, 4] > M[1, 0] > M[1, 5] > 0
    np.testing.assert_allclose(M[1, :4], M[1, 0], atol=1e-12)
    np.testing.assert_allclose(M[1] @ V, [0, 0, 0.5], atol=1e-12)


def _open_box():
    box = trimesh.creation.box()
    V, F = box.vertices, box.faces.astype(np.int64)
    top = np.all(V[F][:, :, 2] > 0.49, axis=1)
    return V, F[~top], F


def test_close_holes_fan_fills_each_loop_with_its_centroid():
    V, F_open, F_closed = _open_box()
    Vc, Fc, P = close_holes(V, F_open)
    assert len(Vc) == len(V) + 1 and len(Fc) == len(F_open) + 4
    np.testing.assert_allclose(Vc[-1], [0.0, 0.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(P.toarray()[:len(V)], np.eye(len(V)))
    np.testing.assert_allclose(P @ V, Vc)
    # the fill keeps the orientation: every directed edge once, the enclosed volume that of the box
    edges = np.r_[Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]]
    assert len({tuple(e) for e in edges}) == len(edges)
    assert trimesh.Trimesh(Vc, Fc, process=False).volume == pytest.approx(1.0, abs=1e-12)
    Vs, Fs, Ps = close_holes(V, F_closed)  # nothing to fill
    assert len(Vs) == len(V) and np.array_equal(Fs, F_closed) and Ps.shape == (len(V), len(V))


def test_two_holes_and_joint_coordinates_of_an_open_mesh():
    V, F_open, _ = _open_box()
    bottom = np.all(V[F_open][:, :, 2] < -0.49, axis=1)
    F2 = F_open[~bottom]
    Vc, Fc, _ = close_holes(V, F2)
    assert len(Vc) == len(V) + 2
    np.testing.assert_allclose(np.sort(Vc[len(V):, 2]), [-0.5, 0.5], atol=1e-12)
    joints = np.array([[0.1, -0.2, 0.3], [0.0, 0.0, -0.45], [-0.3, 0.2, 0.0]])
    M = joint_mean_value_coordinates(joints, V, F2)
    assert M.shape == (3, len(V))
    np.testing.assert_allclose(M.sum(1), 1.0, atol=1e-12)
    assert np.abs(M @ V - joints).max() < 1e-12


def test_closest_points_on_and_off_the_surface(blob):
    V, F = blob
    lam = np.array([[0.1, 0.6, 0.3], [1.0, 0.0, 0.0]])
    P = np.stack([lam[0] @ V[F[3]], lam[1] @ V[F[9]]])
    tri, got, dist = closest_points(P, V, F)
    np.testing.assert_allclose(dist, 0.0, atol=1e-12)
    np.testing.assert_allclose(got[0], lam[0], atol=1e-9) if tri[0] == 3 else None
    np.testing.assert_allclose(got.sum(1), 1.0)
    np.testing.assert_allclose(np.einsum("ij,ijk->ik", got, V[F[tri]]), P, atol=1e-12)
    n = np.cross(V[F[3, 1]] - V[F[3, 0]], V[F[3, 2]] - V[F[3, 0]])
    out = P[0] + 0.01 * n / np.linalg.norm(n)
    tri, got, dist = closest_points(out[None], V, F)
    assert dist[0] == pytest.approx(0.01, abs=1e-9) and (got >= 0).all()


def test_transfer_to_a_copy_is_the_identity_and_follows_a_translation(blob):
    V, F = blob
    joints = np.array([[0.0, 0.1, 0.0], [0.05, -0.2, 0.02]])
    M = joint_mean_value_coordinates(joints, V, F)
    Mz = transfer_joint_coordinates(M, V, F, V, F)
    np.testing.assert_allclose(Mz, M, atol=1e-9)
    # the scan is the model moved by a few mm: the scan joint is the model joint moved by the
    # coordinate-weighted mean of the model-to-scan offsets (closest points C of the model vertices)
    scan_V = V + [0.01, -0.02, 0.005]
    Mz = transfer_joint_coordinates(M, V, F, scan_V, F)
    np.testing.assert_allclose(Mz.sum(1), 1.0)
    tri, lam, _ = closest_points(V, scan_V, F)
    C = np.einsum("ij,ijk->ik", lam, scan_V[F[tri]])
    assert np.abs(Mz @ scan_V - (joints + M @ (C - V))).max() < 1e-12
    assert np.abs(Mz @ scan_V - joints - [0.01, -0.02, 0.005]).max() < 0.02
    # a denser scan of the same surface: joints within the model's sagitta
    s = trimesh.Trimesh(V, F, process=False).subdivide()
    Mz = transfer_joint_coordinates(M, V, F, s.vertices, s.faces)
    assert Mz.shape == (2, len(s.vertices))
    assert np.abs(Mz @ s.vertices - joints).max() < 1e-9  # subdivide keeps the old vertices


@pytest.mark.parametrize("reverse", [False, True])
def test_close_holes_orientation_whichever_way_the_loop_runs(monkeypatch, reverse):
    """libigl returns boundary loops along the faces' edges; a loop given the other way round must be
    reversed before the fan is built, or the fill faces point inwards (volume 1 - 2 * cap)."""
    import igl

    import bodystudio.rig.skeleton_transfer as st

    real = igl.boundary_loop_all
    monkeypatch.setattr(st.igl, "boundary_loop_all",
                        lambda F: [np.asarray(loop)[::-1] if reverse else loop for loop in real(F)])
    V, F_open, _ = _open_box()
    bottom = np.all(V[F_open][:, :, 2] < -0.49, axis=1)
    F2 = F_open[~bottom]  # two holes: top and bottom
    Vc, Fc, _ = close_holes(V, F2)
    fill = Fc[len(F2):]
    assert len(fill) == 8 and np.all(np.sort(fill, axis=1)[:, -1] >= len(V))  # every fill face has a centroid
    assert set(np.unique(fill[fill >= len(V)])) == {len(V), len(V) + 1}
    edges = np.r_[Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]]
    assert len({tuple(e) for e in edges}) == len(edges)
    assert trimesh.Trimesh(Vc, Fc, process=False).volume == pytest.approx(1.0, abs=1e-12)


def test_mean_value_coordinates_of_mixed_and_coplanar_points():
    """Several points at once (on a vertex, inside a face, inside the solid) keep their own cases; a point on
    a face's plane outside the face gets no contribution from that face and keeps linear precision."""
    V = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    on_face = V[F[0]].mean(0)
    points = np.array([V[2], [0.1, -0.2, 0.05], on_face, [2.0, -0.5, -0.5]])  # the last on face 0's plane
    M = mean_value_coordinates(points, V, F)
    np.testing.assert_allclose(M[0], np.eye(6)[2], atol=1e-12)
    np.testing.assert_allclose(M[2, F[0]], 1.0 / 3.0, atol=1e-9)
    np.testing.assert_allclose(M.sum(1), 1.0, atol=1e-12)
    np.testing.assert_allclose(M @ V, points, atol=1e-9)
