"""The cameras of one frame matched in one compiled call (``prange`` over the views, issue 15's second core)
and the visual-hull gate's points in ``prange``: the same constraints and keep masks as the per-view loop,
on one thread and on two."""

import numba
import numpy as np
import pytest

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.rapid_skin import hull_gate_reference
from bodystudio.reconstruct.silhouette import (
    SilhouetteViews,
    area_weighted_normals,
    silhouette_constraints,
    silhouette_mask,
)
from bodystudio.reconstruct.tracking import SilhouetteFields

FIELDS = ("vertex", "origin", "direction", "k", "camera", "pixel_distance")


@pytest.fixture(scope="module")
def scene():
    """A template sphere inside a 'body' of two merged spheres seen by six ring cameras, half of them with
    lens distortion."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=0.12)
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    arm = 0.6 * V + np.array([0.2, 0.0, 0.0])
    scene_V, scene_F = np.vstack([1.05 * V, arm]), np.vstack([F, F + len(V)])
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240,
                           dist=(-0.2, 0.05, 0.001, -0.001, 0.0) if i % 2 else None)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 6, endpoint=False) + 0.3)]
    masks = {c.name: silhouette_mask(scene_V, scene_F, c) for c in cams}
    return V, F, cams, masks


def _with_threads(n, f, *args):
    before = numba.get_num_threads()
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        return f(*args)
    finally:
        numba.set_num_threads(before)


def test_all_cameras_in_one_call_equal_the_per_view_loop(scene):
    V, F, cams, masks = scene
    rng = np.random.default_rng(5)
    Vs = V + rng.normal(0.0, 0.003, V.shape)
    N = area_weighted_normals(Vs, F)
    views = SilhouetteViews(cams, masks, F)
    assert views.packed is not None
    loop = SilhouetteViews(cams, masks, F)
    loop.packed = None  # the per-view path (_match_view camera by camera, as before)
    ref = silhouette_constraints(Vs, F, N, cams, None, 20.0, 5.0, 0.2, views=loop)
    assert len(ref) > 200 and len(set(ref.camera.tolist())) == 6
    for threads in (1, 2):
        got = _with_threads(threads, silhouette_constraints, Vs, F, N, cams, None, 20.0, 5.0, 0.2, views)
        for name in FIELDS:
            np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=f"{name}, {threads} threads")


def test_views_of_different_sizes_keep_the_per_view_loop(scene):
    V, F, cams, masks = scene
    small = Camera.look_at("s", cams[0].center, (0, 0, 0), fx=250.0, width=160, height=120)
    masks = dict(masks, s=silhouette_mask(1.05 * V, F, small))
    views = SilhouetteViews([*cams, small], masks, F)
    assert views.packed is None
    sil = silhouette_constraints(V, F, area_weighted_normals(V, F), [*cams, small], None, views=views)
    assert 6 in set(sil.camera.tolist())


def test_parallel_gate_decides_as_the_reference_on_one_and_two_threads(scene):
    V, F, cams, masks = scene
    fields = SilhouetteFields(cams, masks)
    rng = np.random.default_rng(7)
    # the gate's three cases: target at or below the gate (kept whatever hull(v) is), above it with the vertex
    # inside the hull (dropped), above it with the vertex outside (its own limit: kept or dropped)
    cases = np.zeros(4, np.int64)
    for scale in (0.9, 1.15):
        Vs = scale * V + rng.normal(0.0, 0.003, V.shape)
        sil = silhouette_constraints(Vs, F, area_weighted_normals(Vs, F), cams, masks)
        ref = hull_gate_reference(Vs, sil, fields, 0.001)
        for threads in (1, 2):
            got = _with_threads(threads, fields.hull_gate, Vs, sil.vertex, sil.origin, sil.direction, 0.001)
            np.testing.assert_array_equal(got, ref)
        q = sil.origin + np.sum((Vs[sil.vertex] - sil.origin) * sil.direction, axis=1, keepdims=True) * sil.direction
        h_q, h_v = fields.implicit_hull(q)[0], fields.implicit_hull(Vs[sil.vertex])[0]
        above = h_q > 0.001
        cases += [np.sum(~above), np.sum(above & (h_v <= 0)), np.sum(above & (h_v > 0) & ref),
                  np.sum(above & (h_v > 0) & ~ref)]
    assert np.all(cases >= 5), cases


def test_implicit_hull_in_prange_equals_the_serial_pass_on_one_and_two_threads(scene):
    """The fit's implicit hull and its gradient (``max_c d_c z_c / f_c``) with the vertices in ``prange``
    chunks: bit for bit the one-thread values (and an odd count, so the chunks are uneven), and the same as
    a plain per-camera evaluation of the fields (the numpy reference, to rounding)."""
    V, F, cams, masks = scene
    fields = SilhouetteFields(cams, masks)
    rng = np.random.default_rng(3)
    P = np.vstack([rng.uniform(-0.3, 0.3, (1001, 3)), 1.02 * V])
    one = _with_threads(1, fields.implicit_hull, P)
    two = _with_threads(2, fields.implicit_hull, P)
    np.testing.assert_array_equal(one[0], two[0])
    np.testing.assert_array_equal(one[1], two[1])
    ref = np.full(len(P), -np.inf)
    for cam in cams:
        uv, z = cam.project_with_depth(P)
        d, _, ok = fields.sample(cam, uv)
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        ref = np.where(ok & (z > 1e-6), np.maximum(ref, d * z / f), ref)
    seen = np.isfinite(ref)
    assert seen.sum() > 1000 and (ref[seen] > 0).sum() > 200 and (ref[seen] < 0).sum() > 200
    np.testing.assert_allclose(one[0][seen], ref[seen], atol=1e-9)
    assert np.all(np.isinf(one[0][~seen]))
    assert np.abs(one[1]).max() > 0


def test_gate_reads_the_matchings_projections_and_decides_the_same(scene, monkeypatch):
    """rec15c: the gate's hull(v) from the pixels and depths the matching already computed
    (``SilhouetteViews.projection``) instead of projecting again: the same keep masks as the projecting gate
    and the numpy reference, on one and two threads (half the cameras distorted); the projection is offered
    only for the array just matched; the deformation's vertices bit for bit with the sharing on and off."""
    from bodystudio.reconstruct import rapid_skin
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations

    V, F, cams, masks = scene
    fields = SilhouetteFields(cams, masks)
    views = SilhouetteViews(cams, masks, F)
    rng = np.random.default_rng(11)
    for scale in (0.9, 1.15):
        Vs = scale * V + rng.normal(0.0, 0.003, V.shape)
        sil = silhouette_constraints(Vs, F, area_weighted_normals(Vs, F), cams, masks, views=views)
        projected = views.projection(Vs)
        assert projected is not None and projected[0].shape == (len(cams), len(V), 2)
        assert views.projection(Vs.copy()) is None and views.projection(Vs[::-1]) is None
        uv_ref = np.array([c.project(Vs) for c in cams])
        np.testing.assert_allclose(projected[0], uv_ref, atol=1e-6)
        ref = hull_gate_reference(Vs, sil, fields, 0.001)
        assert 0 < ref.sum() < len(ref)
        for threads in (1, 2):
            got = _with_threads(threads, fields.hull_gate, Vs, sil.vertex, sil.origin, sil.direction, 0.001,
                                projected)
            np.testing.assert_array_equal(got, ref)
    unpacked = SilhouetteViews(cams[:1], masks, F)
    silhouette_constraints(V, F, area_weighted_normals(V, F), cams[:1], masks, views=unpacked)
    assert unpacked.packed is None and unpacked.projection(V) is None
    shared = deform_to_observations(0.95 * V, F, cams, masks, RapidSkinParams(outer_iterations=3))
    monkeypatch.setattr(rapid_skin, "_same_cameras", lambda fields, views: False)
    alone = deform_to_observations(0.95 * V, F, cams, masks, RapidSkinParams(outer_iterations=3))
    np.testing.assert_array_equal(shared.vertices, alone.vertices)
    assert np.abs(shared.vertices - 0.95 * V).max() > 1e-3
