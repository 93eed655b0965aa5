"""Cotangent weights (Eq. 8 of Rapid Skin) where mutation testing found no test: the clamp-and-floor of
obtuse (negative) cotangents against a hand computation, and float32 input."""

import numpy as np

from bodystudio.geometry.laplacian import _WEIGHT_FLOOR, cotangent_delta_coordinates, cotangent_weights

# The irregular octahedron of test_laplacian.py, flattened so that the two apexes sit close to the
# equator plane: the equator's corner angles become obtuse and edges (0, 1) and (1, 2) get negative
# cotangent weights (-0.117 and -0.002), which the operator clamps to zero and then floors.
_F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]])
_V_FLAT = np.array([[1.0, 0.1, 0.05], [-0.1, 0.9, -0.1], [-1.2, -0.1, 0.1],
                    [0.05, -0.8, 0.0], [0.1, 0.05, 0.08], [-0.05, 0.1, -0.06]])


def _raw_cotangents(V, F):
    """``(cot a_ij + cot b_ij) / 2`` per edge, unclamped, dense."""
    n = len(V)
    W = np.zeros((n, n))
    for f in F:
        for c in range(3):
            o, i, j = f[c], f[(c + 1) % 3], f[(c + 2) % 3]
            e1, e2 = V[i] - V[o], V[j] - V[o]
            cot = np.dot(e1, e2) / np.linalg.norm(np.cross(e1, e2))
            W[i, j] += 0.5 * cot
            W[j, i] += 0.5 * cot
    return W


def _dense(op):
    n = op.n_vertices
    W = np.zeros((n, n))
    rows = np.repeat(np.arange(n), np.diff(op.indptr))
    W[rows, op.indices] = op.weights
    return W


def test_negative_cotangents_are_clamped_then_floored_at_a_share_of_the_row_mean():
    raw = _raw_cotangents(_V_FLAT, _F)
    ring = np.zeros_like(raw, dtype=bool)
    for f in _F:
        for a, b in ((0, 1), (1, 2), (2, 0)):
            ring[f[a], f[b]] = ring[f[b], f[a]] = True
    assert raw[0, 1] < -0.1 and raw[1, 2] < 0  # the case this test is about
    clamped = np.where(ring, np.maximum(raw, 0.0), 0.0)
    # floor = 1e-3 x the row's mean clamped weight (not an absolute 1e-3, not divided by the mean)
    floor = _WEIGHT_FLOOR * clamped.sum(1) / ring.sum(1)
    # rows 0-2 hold the floored edges; their mean weight is far from 1, so an absolute floor differs clearly
    assert np.all(np.abs(clamped.sum(1) / ring.sum(1) - 1.0)[:3] > 0.3)
    w = np.where(ring, np.maximum(clamped, floor[:, None]), 0.0)
    ref = w / w.sum(1, keepdims=True)
    W = _dense(cotangent_weights(_V_FLAT, _F))
    np.testing.assert_allclose(W, ref, rtol=1e-9, atol=1e-15)
    # the floored edge keeps a small positive weight (the 1-ring stays connected)
    assert 0 < W[0, 1] < 2 * _WEIGHT_FLOOR and 0 < W[1, 2] < 2 * _WEIGHT_FLOOR


def test_float32_vertices_give_the_weights_of_their_float64_values():
    # float32 vertices give exactly the weights of their float64 values (libigl widens them too) and the
    # delta coordinates come out in float64.
    V32 = _V_FLAT.astype(np.float32)
    ref = _dense(cotangent_weights(V32.astype(np.float64), _F))
    np.testing.assert_allclose(_dense(cotangent_weights(V32, _F)), ref, rtol=0, atol=1e-14)
    op, delta = cotangent_delta_coordinates(V32, _F)
    assert delta.dtype == np.float64
    np.testing.assert_allclose(_dense(op), ref, rtol=0, atol=1e-14)
