"""Harmonic skin weights (eq. 7 of Avatar Reshaping) against answers known in closed form.

On a flat, irregularly triangulated sheet a harmonic function with linear Dirichlet values is that linear
function (the cotangent Laplacian has linear precision; the graph Laplacian does not on irregular meshes).
So where the transfer has to fill in (normals 60-120 degrees from the model's, or a component without any
compatible correspondence) the exact answer is known.
"""

import igl
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import Delaunay

from bodystudio.rig import weights as rig_weights
from bodystudio.rig.weights import (
    COMPATIBLE_COS,
    barycentric_weight_transfer,
    compatible_correspondences,
    harmonic_weight_transfer,
    limit_influences,
    scan_laplacian,
)

UP = np.array([0.0, 1.0, 0.0])


def _sheet(n_inner=300, seed=0, size_m=0.2):
    """An irregular triangulation of the square [0, size]^2 in the floor plane (y = 0), normals +y."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 13)[:-1]
    ring = np.r_[np.c_[t, 0 * t], np.c_[1 + 0 * t, t], np.c_[1 - t, 1 + 0 * t], np.c_[0 * t, 1 - t]]
    xz = np.r_[ring, rng.uniform(0.03, 0.97, (n_inner, 2))] * size_m
    F = Delaunay(xz).simplices.astype(np.int64)
    V = np.c_[xz[:, 0], np.zeros(len(xz)), xz[:, 1]]
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    F[n[:, 1] < 0] = F[n[:, 1] < 0][:, ::-1]
    return V, F, len(ring)


def _linear_weights(V, size_m=0.2):
    """Two bones blending linearly along x, a third bone unused: the harmonic answer with linear boundary data."""
    u = V[:, 0] / size_m
    return np.c_[1.0 - u, u, np.zeros(len(V))]


def _graph_laplacian(F, n):
    """Uniform (graph) Laplacian, negative semi-definite like libigl's cotmatrix."""
    A = igl.adjacency_matrix(F).astype(float)
    return (A - sp.diags(np.asarray(A.sum(1)).ravel())).tocsr()


def _tilted_normals(angle_deg, n):
    a = np.radians(angle_deg)
    return np.tile([np.sin(a), np.cos(a), 0.0], (n, 1))


def _model_with_wrong_interior(V, F):
    """The same sheet as the model, its weights right on the border and all bone 2 inside (what a misfit copies)."""
    W = _linear_weights(V)
    inner = np.all((V[:, [0, 2]] > 0.04) & (V[:, [0, 2]] < 0.16), axis=1)
    W[inner] = [0.0, 0.0, 1.0]
    return W, inner


@pytest.mark.parametrize("angle_deg, compatible", [(0, True), (45, True), (55, True), (65, False), (90, False),
                                                     (115, False), (150, False), (180, False)])
def test_compatibility_is_normals_within_60_degrees(angle_deg, compatible):
    V, F, _ = _sheet(60)
    W = _linear_weights(V)
    ok, W_closest = compatible_correspondences(V + [0, 0.003, 0], _tilted_normals(angle_deg, len(V)), V, F, W)
    assert COMPATIBLE_COS == pytest.approx(0.5)
    assert ok.all() if compatible else not ok.any()
    # every vertex's closest model point is itself: the interpolated weights are the model's
    np.testing.assert_allclose(W_closest, W, atol=1e-9)


def test_scan_laplacian_has_linear_precision_and_the_graph_laplacian_does_not():
    V, F, n_ring = _sheet()
    L = scan_laplacian(V, F).tocsr()
    assert abs(L - L.T).max() < 1e-12
    np.testing.assert_allclose(np.asarray(L.sum(1)).ravel(), 0.0, atol=1e-9)
    assert (L.diagonal() < 0).all()  # negative semi-definite, as libigl's cotmatrix
    inner = np.arange(n_ring, len(V))
    for f in (V[:, 0], V[:, 2], 2 * V[:, 0] - 3 * V[:, 2]):
        assert np.abs(L @ f)[inner].max() < 1e-9
    # A graph (uniform) Laplacian of the same sheet moves linear functions by the neighbours' mean offset.
    graph = _graph_laplacian(F, len(V))
    assert np.abs(graph @ V[:, 0])[inner].max() > 1e-2
    # robust-laplacian: a Delaunay sheet is (up to its mollification) its own intrinsic Delaunay mesh
    robust = scan_laplacian(V, F, "robust").tocsr()
    assert (robust.diagonal() < 0).all()
    assert np.median(np.abs(robust @ V[:, 0])[inner]) < 1e-9 < np.median(np.abs(graph @ V[:, 0])[inner])
    with pytest.raises(ValueError, match="cotan, robust"):
        scan_laplacian(V, F, "graph")


@pytest.mark.parametrize("angle_deg", [65, 90, 115])
def test_harmonic_fill_where_normals_are_60_to_120_degrees_apart_is_linear(angle_deg):
    """Inside, the scan normal is 65-115 degrees from the model's: the transfer must not copy the model's
    (wrong) weights there but fill them in harmonically from the compatible border, i.e. linearly."""
    V, F, _ = _sheet()
    model_W, inner = _model_with_wrong_interior(V, F)
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[inner] = _tilted_normals(angle_deg, inner.sum())
    truth = _linear_weights(V)
    harm = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    bary = barycentric_weight_transfer(V, V, F, model_W)
    assert np.abs(bary - truth).sum(1)[inner].min() > 1.9  # what barycentric transfer copies
    assert np.abs(harm - truth).sum(1).max() < 1e-8, np.abs(harm - truth).sum(1).max()


def test_a_single_free_vertex_takes_the_harmonic_mean_of_its_neighbours():
    V, F, _ = _sheet()
    model_W, inner = _model_with_wrong_interior(V, F)
    one = np.flatnonzero(inner)[0]
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[one] = -UP
    harm = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    L = scan_laplacian(V, F).tocsr()
    row = L[one].toarray().ravel()
    expected = -(np.delete(row, one) @ np.delete(model_W, one, axis=0)) / row[one]
    np.testing.assert_allclose(harm[one], limit_influences(expected[None])[0], atol=1e-12)
    np.testing.assert_allclose(np.delete(harm, one, axis=0), np.delete(model_W, one, axis=0), atol=1e-12)


def test_harmonic_transfer_keeps_compatible_weights_when_normals_agree_within_60_degrees():
    V, F, _ = _sheet()
    model_W, inner = _model_with_wrong_interior(V, F)
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[inner] = _tilted_normals(55, inner.sum())
    harm = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    np.testing.assert_allclose(harm, model_W, atol=1e-12)  # compatible: the model's weights, right or wrong


def test_graph_laplacian_fill_is_not_linear():
    """The test above would pass with any Laplacian if the fill were trivial: the graph Laplacian misses by far."""
    V, F, _ = _sheet()
    model_W, inner = _model_with_wrong_interior(V, F)
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[inner] = _tilted_normals(90, inner.sum())
    graph = _graph_laplacian(F, len(V)).toarray()
    free, known = np.flatnonzero(inner), np.flatnonzero(~inner)
    u = np.linalg.solve(-graph[np.ix_(free, free)], graph[np.ix_(free, known)] @ V[known, 0])
    assert np.abs(u - V[free, 0]).max() > 1e-3  # > 1 % of the sheet: a cotangent fill is exact


def test_component_without_compatible_correspondences_keeps_barycentric_weights():
    V, F, _ = _sheet(120)
    V2, F2 = V + [0.5, 0.0, 0.0], F + len(V)  # a second, separate sheet seen from the wrong side
    scan_V, scan_F = np.r_[V, V2], np.r_[F, F2]
    model_W = np.r_[_linear_weights(V), np.tile([0.2, 0.3, 0.5], (len(V2), 1))]
    scan_N = np.r_[np.tile(UP, (len(V), 1)), np.tile(-UP, (len(V2), 1))]
    harm = harmonic_weight_transfer(scan_V, scan_F, scan_V, scan_F, model_W, scan_N=scan_N)
    assert np.isfinite(harm).all()
    np.testing.assert_allclose(harm, model_W, atol=1e-9)


def test_large_fills_use_conjugate_gradients_with_the_same_answer(monkeypatch):
    V, F, _ = _sheet()
    model_W, inner = _model_with_wrong_interior(V, F)
    scan_N = np.tile(UP, (len(V), 1))
    scan_N[inner] = -UP
    direct = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    monkeypatch.setattr(rig_weights, "DIRECT_SOLVE_MAX", 10)
    cg = harmonic_weight_transfer(V, F, V, F, model_W, scan_N=scan_N)
    truth = _linear_weights(V)
    assert np.abs(direct - truth).max() < 1e-8
    assert np.abs(cg - truth).max() < 5e-3, np.abs(cg - truth).max()  # float32 CG to rtol 1e-3
    assert np.abs(cg - truth)[~inner].max() == 0.0


def test_limit_influences_drops_the_smallest_clips_negatives_and_keeps_zero_rows():
    W = np.array([[0.5, -0.1, 0.2, 0.1, 0.05, 0.15], [0.0] * 6, [0.3, 0.7, 0.0, 0.0, 0.0, 0.0]])
    out = limit_influences(W)
    np.testing.assert_allclose(out[0], np.array([0.5, 0.0, 0.2, 0.1, 0.0, 0.15]) / 0.95)
    np.testing.assert_array_equal(out[1], 0.0)
    np.testing.assert_allclose(out[2], W[2])
    np.testing.assert_allclose(limit_influences(W, k=2)[0], np.array([0.5, 0, 0.2, 0, 0, 0]) / 0.7)
    narrow = np.array([[0.2, 0.6], [0.6, -0.1]])
    np.testing.assert_allclose(limit_influences(narrow), [[0.25, 0.75], [1.0, 0.0]])  # negatives clip to 0
    four = np.array([[0.1, 0.2, 0.3, 0.4]])
    np.testing.assert_allclose(limit_influences(four), four)  # exactly k columns: nothing to drop
    assert W[0, 1] == -0.1  # the input is not modified


def test_segment_distance_and_bone_tails():
    from bodystudio.rig.weights import _segment_distance, bone_segments

    o = np.array([0.3, -0.2, 0.1])  # segment from o to o + 2y
    a, b = o, o + [0.0, 2.0, 0.0]
    P = o + np.array([[1.0, 1.0, 0.0], [0.0, -3.0, 0.0], [0.0, 5.0, 4.0], [0.0, 0.5, 0.0]])
    np.testing.assert_allclose(_segment_distance(P, a, b), [1.0, 3.0, 5.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(_segment_distance(P, a, a), np.linalg.norm(P - o, axis=1))  # a point-sized bone
    R = np.stack([np.eye(3), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])])  # column 1: +y, then -x
    np.testing.assert_allclose(bone_segments(np.array([[1.0, 2, 3], [0, 0, 0]]), R, np.array([0.5, 2.0])),
                               [[1.0, 2.5, 3], [-2.0, 0, 0]])


def test_bounded_biharmonic_weights_of_a_two_bone_rod():
    """A rod along y with a bone in each half (and a third bone left out): each end follows its own bone
    only, the weights form a partition of unity and blend around the joint."""
    import trimesh

    from bodystudio.rig.weights import bounded_biharmonic_weights

    rod = trimesh.creation.cylinder(radius=0.05, height=1.0, sections=16)
    rod = rod.subdivide().subdivide()
    V = np.asarray(rod.vertices)[:, [0, 2, 1]]  # axis along y
    F = np.asarray(rod.faces)
    heads = np.array([[0.0, -0.5, 0.0], [0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    tails = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.6, 0.0, 0.0]])
    W = bounded_biharmonic_weights(V, F, heads, tails, np.array([0, 1]), n_work=len(V) // 2)
    assert W.shape == (len(V), 3)
    np.testing.assert_allclose(W.sum(1), 1.0, atol=1e-9)
    assert (W >= 0).all() and W[:, 2].max() == 0.0
    low, high = V[:, 1] < -0.35, V[:, 1] > 0.35
    assert W[low, 0].min() > 0.95 and W[high, 1].min() > 0.95, (W[low, 0].min(), W[high, 1].min())
    mid = np.abs(V[:, 1]) < 0.02
    assert 0.2 < W[mid, 0].mean() < 0.8
    # weight of the lower bone decreases along the rod
    order = np.argsort(V[:, 1])
    bins = np.array_split(W[order, 0], 10)
    means = [b.mean() for b in bins]
    assert all(x >= y - 0.01 for x, y in zip(means[:-1], means[1:], strict=True)), means


def test_block_conjugate_gradient_is_jacobi_preconditioned_and_starts_from_the_guess():
    """A badly scaled SPD system (diagonal 1e-3..1e3, weak coupling): Jacobi-preconditioned CG reaches
    rtol in a few iterations from any start; the float32 path returns float64 at the requested rtol."""
    from bodystudio.rig.weights import block_conjugate_gradient

    rng = np.random.default_rng(3)
    n = 200
    d = 10.0 ** rng.uniform(-3, 3, n)
    off = sp.random(n, n, density=0.02, random_state=4)
    off = 0.01 * (off + off.T)
    A = (sp.diags(d) + sp.diags(np.sqrt(d)) @ off @ sp.diags(np.sqrt(d))).tocsr()
    B = rng.normal(size=(n, 2)) * [1.0, 1e3]
    exact = np.linalg.solve(A.toarray(), B)
    X0 = exact + rng.normal(size=exact.shape)  # a guess that is off: the residual is B - A X0
    for dtype, rtol in ((np.float64, 1e-10), (np.float32, 1e-3)):
        X = block_conjugate_gradient(A, B, X0, rtol=rtol, max_iterations=12, dtype=dtype)
        assert X.dtype == np.float64
        res = np.linalg.norm(A @ X - B, axis=0) / np.linalg.norm(B, axis=0)
        assert (res < 10 * rtol).all(), (dtype, res)
    # an exact guess needs no iteration at all
    np.testing.assert_allclose(block_conjugate_gradient(A, B, exact, max_iterations=0), exact)


def test_barycentric_transfer_without_the_influence_limit_keeps_every_bone():
    V, F, _ = _sheet(40)
    W = np.random.default_rng(7).dirichlet(np.ones(6), len(V))  # six influences everywhere
    raw = barycentric_weight_transfer(V + [0, 0.001, 0], V, F, W, limit=False)
    np.testing.assert_allclose(raw, W, atol=1e-9)
    limited = barycentric_weight_transfer(V + [0, 0.001, 0], V, F, W)
    assert ((limited > 0).sum(1) == 4).all()
