"""Mutation tests of rec15i's compiled ``DeltaOperator.apply`` (issue 17, branch mutT;
docs/mutation/geometry-laplacian.md "rec15i"): (n, 3) float64 positions take the compiled pass, once, and its result
is what comes back; anything else (float32, two columns) takes the sparse product without calling it. The values
themselves are pinned bit for bit by test_laplacian.py's ``test_compiled_apply_equals_the_sparse_product_bit_for_bit``.
"""

import numpy as np

from bodystudio.geometry import laplacian as lap
from bodystudio.geometry.laplacian import cotangent_weights
from tests.geometry.test_laplacian import _F, _V


def test_float64_positions_take_the_compiled_pass_and_others_the_sparse_product(monkeypatch):
    calls = []
    real = lap._delta_rows

    def spy(*args):
        calls.append(real(*args))
        return calls[-1]

    monkeypatch.setattr(lap, "_delta_rows", spy)
    op = cotangent_weights(_V, _F)
    X = np.asarray(_V, np.float64) * 1.3 + 0.1
    out = op.apply(X)
    assert len(calls) == 1 and calls[0][0] and out is calls[0][1]
    np.testing.assert_array_equal(out, op.matrix @ X)
    for other in (X.astype(np.float32), X[:, :2]):
        got = op.apply(other)
        assert len(calls) == 1  # not called
        np.testing.assert_array_equal(got, op.matrix @ other)
