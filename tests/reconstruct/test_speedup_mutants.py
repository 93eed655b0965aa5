"""Mutation tests (issue 17) of rec15's plain-Python speed-ups around the compiled kernels: the cached sparse
skin weights (``geometry.skinning.sparse_skin_weights``, ``articulated_fit._sparse_weights``), the one-thread
BLAS context made once (``_one_blas_thread``), the fit's ``min_decrease`` stop (off at 0, even when the data
energy rises) and ``TrackParams``' new settings. Small random inputs and a synthetic data term: seconds."""

import numpy as np
import pytest

from bodystudio.errors import InputError


def _weights(rng, n=12, B=9, zero_from=4):
    W = rng.uniform(0.05, 1.0, (n, B))
    W[: n // 2, zero_from:] = 0.0  # half the vertices have `zero_from` influences, the rest all nine
    return W / W.sum(axis=1, keepdims=True)


def test_sparse_skin_weights_k6_keeps_the_six_largest_renormalised():
    """Eq. 12 of Rapid Skin on the six largest weights: the mirror's truncation (k=6) of nine influences."""
    from bodystudio.geometry.skinning import sparse_skin_weights

    W = _weights(np.random.default_rng(11))
    idx, w = sparse_skin_weights(W, k=6)
    assert idx.shape == (12, 6) and w.shape == (12, 6) and idx.flags.c_contiguous
    order = np.argsort(-W, axis=1)[:, :6]
    np.testing.assert_array_equal(np.sort(idx, axis=1), np.sort(order, axis=1))
    top = np.take_along_axis(W, order, 1)
    np.testing.assert_allclose(w, top / top.sum(1, keepdims=True), atol=1e-15)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-15)
    assert np.all(np.diff(w, axis=1) <= 0)  # the largest first
    # the six largest of the full rows do not sum to one before renormalising: the division is exercised
    assert np.abs(top[6:].sum(1) - 1.0).min() > 1e-3


def test_sparse_skin_weights_k_none_has_as_many_columns_as_the_fullest_vertex():
    from bodystudio.geometry.skinning import sparse_skin_weights

    W = _weights(np.random.default_rng(12), zero_from=3)
    W = W[:6]  # only the vertices with three influences
    idx, w = sparse_skin_weights(W, k=None)
    assert idx.shape == (6, 3)
    np.testing.assert_allclose(w, np.take_along_axis(W, idx, 1), atol=1e-15)  # rows already sum to one
    one = np.zeros((4, 5))
    one[np.arange(4), [0, 2, 4, 1]] = 1.0  # a single influence each: one column, never zero
    idx1, w1 = sparse_skin_weights(one, k=None)
    assert idx1.shape == (4, 1)
    np.testing.assert_array_equal(idx1[:, 0], [0, 2, 4, 1])
    np.testing.assert_array_equal(w1[:, 0], 1.0)
    idx0, w0 = sparse_skin_weights(np.zeros((0, 5)), k=None)  # no vertices: one (empty) column
    assert idx0.shape == (0, 1) and w0.shape == (0, 1)


def test_sparse_skin_weights_cache_is_keyed_by_array_and_k_and_bounded():
    from bodystudio.geometry import skinning

    skinning._SPARSE_CACHE.clear()  # an earlier test's entries could evict this one's mid-test
    W = _weights(np.random.default_rng(13))
    a = skinning.sparse_skin_weights(W, k=6)
    b = skinning.sparse_skin_weights(W, k=None)
    assert a[0].shape == (12, 6) and b[0].shape == (12, 9)  # k is part of the key
    again = skinning.sparse_skin_weights(W, k=6)
    assert again[0] is a[0] and again[1] is a[1]  # a hit returns the cached arrays
    assert skinning._SPARSE_CACHE[(id(W), 6)][0] is W  # the array is held, so its id is not reused
    W2 = W.copy()
    W2[:, [0, 1]] = W2[:, [1, 0]]  # same values, other bones: its own entry
    c = skinning.sparse_skin_weights(W2, k=6)
    assert not np.array_equal(c[0], a[0])
    sizes = []
    for _ in range(20):
        skinning.sparse_skin_weights(_weights(np.random.default_rng(14)), k=6)
        sizes.append(len(skinning._SPARSE_CACHE))
    assert min(sizes) >= 1 and max(sizes) == 8  # at most eight arrays held
    assert skinning.sparse_skin_weights(W)[0].shape == (12, 6)  # the default is the mirror's six


def test_fit_sparse_weights_every_non_zero_unnormalised_and_cached():
    from bodystudio.reconstruct import articulated_fit as af

    af._SPARSE_CACHE.clear()
    W = _weights(np.random.default_rng(15), zero_from=4)
    W[0] *= 2.0  # not renormalised: the fit's weights are taken as they are
    idx, w = af._sparse_weights(W)
    assert idx.shape == (12, 9)
    np.testing.assert_allclose(w, np.take_along_axis(W, idx, 1), atol=0)
    np.testing.assert_array_equal(w[:6, 4:], 0.0)
    assert np.all(np.diff(w, axis=1) <= 0)
    again = af._sparse_weights(W)
    assert again[0] is idx and again[1] is w
    assert af._SPARSE_CACHE[id(W)][0] is W
    one = np.eye(5)
    assert af._sparse_weights(one)[0].shape == (5, 1)
    sizes = []
    for _ in range(20):
        af._sparse_weights(_weights(np.random.default_rng(16)))
        sizes.append(len(af._SPARSE_CACHE))
    assert min(sizes) >= 1 and max(sizes) == 8


def test_one_blas_thread_limits_blas_and_is_made_once(monkeypatch):
    from threadpoolctl import threadpool_info

    from bodystudio.reconstruct import articulated_fit as af

    monkeypatch.setattr(af, "_BLAS", None)  # the first call makes the controller
    with af._one_blas_thread():
        blas = [p for p in threadpool_info() if p["user_api"] == "blas"]
        assert blas and all(p["num_threads"] == 1 for p in blas)
    first = af._BLAS
    assert first is not None
    with af._one_blas_thread():
        pass
    assert af._BLAS is first


def _rising_term(calls):
    """A data term whose energy sum w r^2 grows at every call (r = 0.01 * call number on 40 vertices)."""
    def term(V, N):
        calls.append(1)
        ids = np.arange(0, 400, 10)
        G = np.asarray(N[ids], dtype=np.float64)
        G[~np.isfinite(G).all(1)] = (0.0, 1.0, 0.0)
        return ids, np.full(len(ids), 0.01 * len(calls)), np.ones(len(ids)), G
    return term


def test_min_decrease_zero_runs_every_iteration_even_when_the_energy_rises(body_2k):
    """``min_decrease`` 0 (the default) is off: a rising data energy does not stop the fit; a positive one does
    at the first evaluation that did not fall."""
    from bodystudio.reconstruct.articulated_fit import PoseRefineParams, refine_bone_transforms

    T0 = np.tile(np.eye(4), (body_2k.skeleton.n_bones, 1, 1))
    calls = []
    refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=4), data_term=_rising_term(calls))
    assert len(calls) == 4
    calls.clear()
    refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=4, min_decrease=0.5),
                           data_term=_rising_term(calls))
    assert len(calls) == 2


@pytest.mark.parametrize("name,value", [("min_decrease", -0.01), ("min_decrease", 1.5),
                                        ("outer_iterations", -1), ("outer_iterations", 101),
                                        ("iterations", 0), ("iterations", 101)])
def test_track_params_new_settings_out_of_range(name, value):
    from bodystudio.reconstruct.tracking import TrackParams

    with pytest.raises(InputError, match=f"tracking {name}"):
        TrackParams(**{name: value})


def test_track_params_new_settings_bounds_accepted():
    from bodystudio.reconstruct.tracking import TrackParams

    for name, value in (("min_decrease", 0.0), ("min_decrease", 1.0), ("outer_iterations", 0),
                        ("outer_iterations", 100), ("iterations", 1), ("iterations", 100)):
        assert getattr(TrackParams(**{name: value}), name) == value
    p = TrackParams()
    assert (p.min_decrease, p.outer_iterations, p.warm_mesh) == (0.01, 2, False)  # No 3 -> 2 (rec15n)


def test_track_bone_transforms_passes_min_decrease_to_the_fit(monkeypatch):
    from bodystudio.reconstruct import tracking

    seen = {}

    def fake_refine(body, previous, hull, refine, data_term=None, anchors=None):
        seen["refine"] = refine
        return previous

    monkeypatch.setattr(tracking, "refine_bone_transforms", fake_refine)
    monkeypatch.setattr(tracking, "silhouette_data_term", lambda fields, params: None)
    params = tracking.TrackParams(min_decrease=0.07, iterations=5, robust_m=0.0123, prior_weight=0.321)
    tracking.track_bone_transforms(None, np.eye(4)[None], None, params)
    r = seen["refine"]
    assert (r.min_decrease, r.iterations, r.prior_weight, r.robust_m) == (0.07, 5, params.prior_weight,
                                                                          params.robust_m)


def test_fields_of_an_empty_mask_are_the_whole_image_all_outside():
    """A view with no silhouette: its field is the whole image, all outside (no inside transform to take)."""
    from bodystudio.geometry.camera import Camera
    from bodystudio.reconstruct.tracking import SilhouetteFields

    H, W = 40, 50
    cams = [Camera.look_at(f"c{i}", (0, 0, 3), (0, 0, 0), fx=100.0, width=W, height=H) for i in range(2)]
    yy, xx = np.mgrid[:H, :W]
    masks = {"c0": np.zeros((H, W), bool), "c1": (yy - 20) ** 2 + (xx - 25) ** 2 < 64}
    fields = SilhouetteFields(cams, masks, margin_px=5)
    assert fields.offset["c0"] == (0, 0) and fields.sdf["c0"].shape == (H, W)
    assert fields.sdf["c0"].dtype == np.float32 and fields.sdf["c0"].min() > 0
    assert fields.sdf["c1"].dtype == np.float32 and fields.sdf["c1"].min() < -5.0
