"""Cotangent weights (Eq. 8 of Rapid Skin) against cotangents computed by hand on a small irregular mesh."""

import numpy as np

from bodystudio.geometry.laplacian import cotangent_delta_coordinates, cotangent_weights

# A closed, irregular octahedron: every angle is acute (no clamping), valences 4, edge lengths all differ,
# so cotangent, squared-cotangent and uniform weights all disagree.
_V = np.array([[1.0, 0.1, 0.05], [-0.1, 0.9, -0.1], [-1.2, -0.1, 0.1],
               [0.05, -0.8, 0.0], [0.1, 0.05, 1.1], [-0.05, 0.1, -0.7]])
_F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]])


def _hand_cotangent_weights(V, F):
    """``w_ij = (cot a_ij + cot b_ij) / 2`` from each face's corner angles, then rows normalised to 1."""
    n = len(V)
    W = np.zeros((n, n))
    for f in F:
        for c in range(3):
            o, i, j = f[c], f[(c + 1) % 3], f[(c + 2) % 3]  # the angle at o faces the edge (i, j)
            e1, e2 = V[i] - V[o], V[j] - V[o]
            cot = np.dot(e1, e2) / np.linalg.norm(np.cross(e1, e2))
            W[i, j] += 0.5 * cot
            W[j, i] += 0.5 * cot
    return W / W.sum(axis=1, keepdims=True)


def _dense(op):
    n = op.n_vertices
    W = np.zeros((n, n))
    rows = np.repeat(np.arange(n), np.diff(op.indptr))
    W[rows, op.indices] = op.weights
    return W


def test_cotangent_weights_equal_hand_computed_cotangents():
    ref = _hand_cotangent_weights(_V, _F)
    assert np.all(ref[ref != 0] > 0.05)  # all angles acute: no clamping or floor involved
    # The mesh is irregular enough that wrong weightings differ clearly from the cotangent ones:
    uniform = (ref > 0) / (ref > 0).sum(1, keepdims=True)
    squared = ref**2 / (ref**2).sum(1, keepdims=True)
    assert np.abs(uniform - ref).max() > 0.05 and np.abs(squared - ref).max() > 0.05
    W = _dense(cotangent_weights(_V, _F))
    np.testing.assert_allclose(W, ref, atol=1e-12)


def test_delta_coordinates_are_v_minus_the_weighted_ring():
    op, delta = cotangent_delta_coordinates(_V, _F)
    ref = _hand_cotangent_weights(_V, _F)
    np.testing.assert_allclose(delta, _V - ref @ _V, atol=1e-12)
    # Linear precision: on a planar irregular fan the cotangent Laplacian of the centre vertex vanishes
    # (its mean-curvature normal, Meyer et al. 2003); uniform or squared weights leave an in-plane offset.
    ang = np.array([0.0, 0.9, 2.1, 2.9, 4.0, 5.2])
    rad = np.array([1.0, 0.7, 1.2, 0.8, 1.1, 0.9])
    ring = np.c_[rad * np.cos(ang), rad * np.sin(ang), np.zeros(6)]
    V = np.vstack([[0.05, -0.03, 0.0], ring])
    F = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    _, d = cotangent_delta_coordinates(V, F)
    assert np.linalg.norm(d[0]) < 1e-12


def test_compiled_apply_equals_the_sparse_product_bit_for_bit():
    """:meth:`DeltaOperator.apply` (one compiled pass, issue 15's frame time) sums each row in the sparse product's
    order: the same delta coordinates bit for bit, with the diagonal first, in the middle and last of a row; rows
    out of order or an (n, 2) array take the sparse product itself."""
    from bodystudio.geometry.laplacian import DeltaOperator

    rng = np.random.default_rng(4)
    V = np.vstack([_V, _V * 1.3 + 0.2])
    F = np.vstack([_F, _F + 6])
    op = cotangent_weights(V, F)
    X = V + rng.normal(scale=0.3, size=V.shape) * 10.0 ** rng.integers(-6, 3, size=V.shape)
    got = op.apply(X)
    assert got.dtype == np.float64 and np.array_equal(got, op.apply_reference(X))
    assert np.array_equal(got, op.matrix @ X)
    # a planted summation order (the diagonal's v_i added first) differs somewhere on these magnitudes
    rows = np.repeat(np.arange(len(X)), np.diff(op.indptr))
    first = X.copy()
    for i in range(len(X)):
        acc = X[i].copy()
        for e in range(op.indptr[i], op.indptr[i + 1]):
            acc = acc + (-op.weights[e]) * X[op.indices[e]]
        first[i] = acc
    assert not np.array_equal(first, got) and len(rows) == len(op.indices)
    # unsorted columns: the sparse product (scipy sorts them), the same values as the sorted operator's
    perm = op.indptr[1] - 1
    idx, w = op.indices.copy(), op.weights.copy()
    idx[[0, perm]], w[[0, perm]] = idx[[perm, 0]], w[[perm, 0]]
    shuffled = DeltaOperator(op.indptr, idx, w, op.reverse)
    np.testing.assert_allclose(shuffled.apply(X), got, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(op.apply(X[:, :2]), op.matrix @ X[:, :2])
