"""The visual-hull gate's max over cameras as a select (issue 15's frame time, rec15f): :func:`_hull_max` and
:func:`_hull_max_at` give the implicit hull of :meth:`SilhouetteFields.implicit_hull` bit for bit, and the limited
max decides every point as the full one, on distorted cameras with points inside, outside, beyond the fields' box,
off the image and behind a camera."""

import numpy as np
import pytest

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.silhouette import _project_into, silhouette_mask
from bodystudio.reconstruct.tracking import SilhouetteFields, _hull_max, _hull_max_at


@pytest.fixture(scope="module")
def scene():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=0.25)
    V, F = np.asarray(m.vertices, float) * [1.0, 1.6, 0.8] + [0.0, 1.0, 0.0], np.asarray(m.faces, np.int64)
    cams = [Camera.look_at(f"c{i}", (2.5 * np.sin(a), 1.3, 2.5 * np.cos(a)), (0.0, 1.0, 0.0), fx=300.0, width=200,
                           height=160, dist=(0.08, -0.2, 0.001, -0.001, 0.05) if i % 2 else None)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 5, endpoint=False) + 0.2)]
    fields = SilhouetteFields(cams, {c.name: silhouette_mask(V, F, c) for c in cams}, margin_px=12)
    rng = np.random.default_rng(7)
    X = np.r_[rng.normal([0.0, 1.0, 0.0], [0.3, 0.5, 0.3], (3000, 3)),  # in, near and out of the hull
              rng.normal([0.0, 1.0, 0.0], 2.0, (300, 3)),  # off images, beyond the boxes
              [[2.5 * np.sin(0.2), 1.3, 2.5 * np.cos(0.2) + 0.5]]]  # behind camera 0
    return fields, X


def _args(fields):
    return (fields._R, fields._t, fields._K, fields._dist, fields._has_dist, fields._size, fields._packed_sdf,
            fields._shapes, fields._offsets, fields.margin_px)


def test_the_max_is_the_implicit_hull(scene):
    fields, X = scene
    ref, _ = fields.implicit_hull(X)
    assert np.isfinite(ref).sum() > 2500 and (~np.isfinite(ref)).any()  # seen, and seen by no camera
    assert (ref > 0).sum() > 500 and (ref < 0).sum() > 500
    np.testing.assert_array_equal(_hull_max(X, np.full(len(X), np.inf), *_args(fields), 1), ref)


def test_the_max_from_projections_is_the_same(scene):
    fields, X = scene
    C = len(fields.cameras)
    uv, z = np.empty((C, len(X), 2)), np.empty((C, len(X)))
    for c, cam in enumerate(fields.cameras):
        _project_into(X, cam.R, cam.t, cam.K, np.asarray(cam.dist, float), uv[c], z[c])
    order = np.arange(0, len(X), 3)
    R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin = _args(fields)
    got = _hull_max_at(order, uv, z, K, size, sdf, shapes, offsets, margin, 1)
    np.testing.assert_array_equal(got, fields.implicit_hull(X[order])[0])


def test_the_limited_max_decides_as_the_full_one(scene):
    fields, X = scene
    full, _ = fields.implicit_hull(X)
    rng = np.random.default_rng(1)
    limit = np.where(rng.random(len(X)) < 0.5, 0.001, rng.normal(0.0, 0.02, len(X)))
    limited = _hull_max(X, limit, *_args(fields), 1)
    np.testing.assert_array_equal(limited > limit, full > limit)
    assert 200 < (full > limit).sum() < len(X) - 200
    below = ~(full > limit)
    np.testing.assert_array_equal(limited[below], full[below])  # a kept point read every camera


@pytest.mark.parametrize("chunks", [1, 3])
def test_the_camera_major_hull_and_gradient_are_the_vertex_major_ones(scene, chunks):
    """:func:`_implicit_hull` with the cameras outermost and each camera's points projected in one vectorised pass
    (rec15i), the gradient taken at the maximising camera afterwards: the values and gradients of the vertex-major
    loop it replaced (:func:`_implicit_hull_reference`) bit for bit, in any number of chunks."""
    from bodystudio.reconstruct.tracking import _implicit_hull, _implicit_hull_reference

    fields, X = scene
    best, G = _implicit_hull(X, *_args(fields), chunks)
    ref_best, ref_G = _implicit_hull_reference(X, *_args(fields))
    np.testing.assert_array_equal(best, ref_best)
    np.testing.assert_array_equal(G, ref_G)
    moved = (np.abs(G).sum(axis=1) > 0) & np.isfinite(best)
    assert moved.sum() > 1000 and (np.isfinite(best) & ~moved).any()  # gradients, and points beyond the fields


def test_the_camera_major_outside_share_is_the_reference_one(scene):
    """:func:`outside_fraction` with the cameras outermost (rec15i) decides every point as the per-camera numpy
    path, at thresholds where some and where most points are outside."""
    from bodystudio.reconstruct.tracking import outside_fraction, outside_fraction_reference

    fields, X = scene
    shares = [outside_fraction(X, fields, px) for px in (-3.0, 2.0, 9.0)]
    assert shares == [outside_fraction_reference(X, fields, px) for px in (-3.0, 2.0, 9.0)]
    assert 0.05 < shares[2] < shares[1] < shares[0] < 1.0
