"""``rig.export.skin_arrays`` on a rig of fewer than four bones (mutY's note): JOINTS_0 / WEIGHTS_0 are declared VEC4
in the glb, so the arrays must have four columns, the missing slots weight 0 on joint 0 (the glTF convention)."""

import numpy as np

from bodystudio.rig.export import skin_arrays


def test_two_bones_give_four_columns():
    weights = np.array([[0.25, 0.75], [1.0, 0.0], [0.5, 0.5]])
    idx, w = skin_arrays(weights)
    assert idx.shape == (3, 4) and w.shape == (3, 4)
    assert idx.dtype == np.uint16 and w.dtype == np.float32
    np.testing.assert_array_equal(w.sum(1, dtype=np.float32), np.ones(3, np.float32))
    dense = np.zeros((3, 4))
    np.add.at(dense, (np.repeat(np.arange(3), 4), idx.ravel()), w.ravel())
    np.testing.assert_allclose(dense[:, :2], weights, atol=1e-7)
    assert np.all(idx[w == 0] == 0)


def test_four_or_more_bones_unchanged():
    rng = np.random.default_rng(3)
    weights = rng.random((20, 6))
    weights /= weights.sum(1, keepdims=True)
    idx, w = skin_arrays(weights)
    np.testing.assert_array_equal(idx, np.argsort(-weights, axis=1)[:, :4])
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
