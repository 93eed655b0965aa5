"""The shape prior carried into the tracked frames and restricted to regions (issue 15, rec15p;
``shape_prior="carried"``, ``shape_prior_region`` of :func:`bodystudio.reconstruct.sequence.reconstruct_session`).

The region weights on a strip of triangles (1 inside, a ramp over the fall-off rings, 0 beyond; ``lower_torso``
cut at the rest ``spine_02`` tail), the blended rest shape against a planted body whose region alone has the shape
space's shape, and the per-frame wiring on the tracked path's stand-ins (tests/reconstruct/
test_sequence_tracked_mutants.py): the coefficients fitted to the (re-)initialised frames' one pass only, each
tracked frame started from and regularised towards their mean, no second pass. Under a second in all.
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.reconstruct.sequence as seq
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.shape_prior import fit_shape_coefficients, region_blend_weights, region_shape
from bodystudio.reconstruct.tracking import TrackParams
from tests.reconstruct.test_sequence_tracked_mutants import (
    BODIES,
    EXPECTED_TRACK,
    FRAMES,
    OUTSIDE_PX,
    Writer,
    _session,
    _stand_ins,
)
from tests.reconstruct.test_shape_prior_analytic import _space


def _strip(n=12):
    """``n`` columns of a 2-row strip of triangles along x (vertex 2k at y 0, 2k + 1 at y 1): column k is k rings
    from column 0."""
    V = np.array([[k, r, 0.0] for k in range(n) for r in (0, 1)], dtype=np.float64)
    F = np.array([f for k in range(n - 1) for f in ([2 * k, 2 * k + 2, 2 * k + 1], [2 * k + 1, 2 * k + 2,
                                                                                      2 * k + 3])])
    return V, F


def test_region_weights_are_one_inside_and_ramp_to_zero_over_the_falloff():
    V, F = _strip()
    body = NS(vertices=V, faces=F)
    regions = np.array(["crotch"] * 6 + ["legs"] * 18, dtype=object)  # columns 0-2 the region
    w = region_blend_weights(body, regions, ("crotch",), falloff_rings=4)
    col = w.reshape(-1, 2)
    np.testing.assert_array_equal(col[:3], 1.0)
    assert np.all(col[7:] == 0.0)  # beyond 4 rings (one ring a column here: each step of the mean spreads one)
    outside = col[3:7, 0]  # measured 0.64 0.26 0.067 0.008
    assert np.all(np.diff(outside) < 0) and np.all((outside > 0) & (outside < 1))
    assert np.all(region_blend_weights(body, regions, ("crotch",), falloff_rings=0) == np.repeat([1.0, 0.0],
                                                                                                   [6, 18]))
    assert not region_blend_weights(body, regions, ("head",)).any()
    np.testing.assert_array_equal(region_blend_weights(body, regions, ("crotch", "legs")), 1.0)


def test_lower_torso_is_the_torso_below_the_spine_02_tail():
    V, F = _strip()
    V[:, 1] = np.repeat(np.linspace(0.9, 1.4, 12), 2)  # rest heights rise along the strip
    skel = NS(bone_names=("pelvis", "spine_02"), tails=np.array([[0, 0.95, 0], [0, 1.1, 0]]))
    body = NS(vertices=V, faces=F, skeleton=skel)
    regions = np.array(["torso"] * 24, dtype=object)
    w = region_blend_weights(body, regions, ("lower_torso",), falloff_rings=0)
    np.testing.assert_array_equal(w == 1.0, V[:, 1] < 1.1)
    assert 0 < np.count_nonzero(w) < 24


def test_region_shape_is_the_space_inside_the_template_outside_and_recovers_a_planted_body():
    """Planted: a first pass that is the shape space's ``c_true`` with 1 mm noise, and a wanted body that is that
    shape on a third of the vertices (the region) and the template's elsewhere. The space fitted to the pass and
    blended by the region's weights is within 2 mm of the wanted body everywhere (measured 0.1 mm) and exactly the
    template outside; the space everywhere (no weights), weights inverted or halved are centimetres off."""
    rng = np.random.default_rng(3)
    template = rng.normal(0, 0.3, (300, 3))
    model = _space(template + rng.normal(0, 0.02, (300, 3)))
    body = NS(vertices=template)
    inside = np.arange(300) < 100
    c_true = np.array([0.75, -0.3, 0.16, 0.2])
    wanted = np.where(inside[:, None], model.vertices(c_true), template)
    w = inside.astype(np.float64)
    c = fit_shape_coefficients(model, model.vertices(c_true) + rng.normal(0, 0.001, template.shape), ridge=1e-8)
    got = region_shape(model, body, c, w)
    assert 1000 * np.linalg.norm(got - wanted, axis=1).max() < 2.0
    np.testing.assert_array_equal(got[~inside], template[~inside])  # exactly the template outside
    np.testing.assert_allclose(region_shape(model, body, c, None), model.vertices(c))
    for other in (None, 1.0 - w, 0.5 * w):
        assert 1000 * np.linalg.norm(region_shape(model, body, c, other) - wanted, axis=1).max() > 10.0
    np.testing.assert_allclose(region_shape(model, body, c, np.full(300, 0.5)), 0.5 * (template + model.vertices(c)))


# --- reconstruct_frames' wiring on the tracked path's stand-ins -------------------------------------------------

def _carried_run(monkeypatch, tmp_path, region="all", tracking=True, reach=0.0, prior="carried"):
    rec = _stand_ins(monkeypatch)
    import bodystudio.body.statistical as statistical

    monkeypatch.setattr(statistical, "load_statistical_model", lambda resolution, progress=True: "space")
    fits, poses = [], []

    def coefficients(model, body, V, T):
        assert model == "space" and body is BODIES["6k"]
        fits.append((np.array(V), np.array(T)))
        return np.array([float(len(fits)), 10.0 * len(fits)])

    def posed(model, body, coeffs, T, scale=1.0, **kw):
        out = body.vertices * scale + T + [0.0, float(coeffs[0]), 0.0]  # the mean coefficient shows as a lift
        poses.append((np.array(coeffs), np.array(T), scale, kw, out))
        return out

    monkeypatch.setattr(seq, "deformed_shape_coefficients", coefficients)
    monkeypatch.setattr(seq, "posed_shape", posed)
    monkeypatch.setattr(seq, "shape_prior_mesh", lambda *a, **k: pytest.fail("carried: no second pass"))
    monkeypatch.setattr(seq, "vertex_regions", lambda body: np.array(["crotch", "legs", "torso", "head"],
                                                                      dtype=object))
    monkeypatch.setattr(seq, "region_blend_weights", lambda body, regions, names: np.array([1.0, 0.5, 0.0, 0.0]))
    writer = Writer(tmp_path)
    seq.reconstruct_frames(_session(), writer, list(FRAMES), [NS(name="c0")], NS(depth="depth-camera"),
                           RapidSkinParams(outer_iterations=5), "gs", "6k", "tracker", None, False, False, False,
                           False, tracking=tracking, track_params=TrackParams(outside_px=OUTSIDE_PX),
                           bone_lengths="frame", shape_prior=prior, shape_prior_region=region,
                           shape_prior_reach=reach)
    return rec, fits, poses, writer


@pytest.mark.parametrize("region", ["all", "crotch+legs"])
def test_carried_fits_the_initialised_frames_and_starts_the_tracked_ones_from_their_mean(monkeypatch, tmp_path,
                                                                                          region):
    rec, fits, poses, writer = _carried_run(monkeypatch, tmp_path, region)
    deform = rec.calls["deform"]
    assert len(deform) == len(FRAMES)  # one pass a frame
    initialised = [k for k, t in enumerate(EXPECTED_TRACK) if t != "tracked"]
    assert len(fits) == len(initialised) == 5
    for (V, _T), k in zip(fits, initialised, strict=True):  # fitted to that frame's one pass
        np.testing.assert_allclose(V, deform[k]["V"] + [0, 0, 0.001 * (k + 1)])
    tracked = [k for k, t in enumerate(EXPECTED_TRACK) if t == "tracked"]
    assert len(poses) == len(tracked)
    for (coeffs, _T, _s, kw, out), k in zip(poses, tracked, strict=True):
        n_before = sum(1 for j in initialised if j < k)  # the mean of the fits so far
        np.testing.assert_allclose(coeffs, np.mean([[i, 10.0 * i] for i in range(1, n_before + 1)], axis=0))
        np.testing.assert_array_equal(deform[k]["V"], out)  # the start ...
        np.testing.assert_array_equal(deform[k]["reference"], out)  # ... and the smoothness reference
        if region == "all":
            assert kw == {}
        else:
            np.testing.assert_array_equal(kw["region_weights"], [1.0, 0.5, 0.0, 0.0])
    # the initialised frames start from the posed template (no shape), as without the prior
    for k in initialised:
        np.testing.assert_allclose(deform[k]["reference"], deform[k]["V"])
    assert writer.meta["shape_prior"] == "carried" and writer.meta["shape_prior_region"] == region


def test_carried_lifts_each_tracked_frame_by_the_mean_so_far(monkeypatch, tmp_path):
    """The stand-in shape lifts the posed template by the mean coefficient: tracked frame 11 follows 1 fit (1.0),
    frames 16 and 17 the 5 of frames 10, 12, 13, 14, 15 (mean 3.0; a tracked frame adds none)."""
    rec, _fits, poses, _w = _carried_run(monkeypatch, tmp_path)
    lifts = [float(p[0][0]) for p in poses]
    assert lifts == [1.0, 3.0, 3.0]

