"""The compiled lost-track energy (:func:`outside_fraction`) against the per-camera numpy path it replaced,
on a small scene (seconds): meshes inside, across and outside the visual hull, half the cameras distorted."""

import numpy as np

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.silhouette import silhouette_mask
from bodystudio.reconstruct.tracking import SilhouetteFields, outside_fraction, outside_fraction_reference


def _sphere(radius):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def test_compiled_outside_fraction_equals_the_numpy_path():
    V, F = _sphere(0.2)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240,
                           dist=(-0.2, 0.05, 0.001, -0.001, 0.0) if i % 2 else None)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 5, endpoint=False) + 0.3)]
    fields = SilhouetteFields(cams, {c.name: silhouette_mask(V, F, c) for c in cams}, margin_px=16)
    rng = np.random.default_rng(5)
    got, ref = [], []
    for scale, shift in ((0.9, 0.0), (1.0, 0.0), (1.05, 0.0), (1.1, 0.05), (1.0, 0.6), (3.0, 0.0)):
        X = scale * V + rng.normal(0.0, 0.003, V.shape) + [shift, 0.0, 0.0]
        for px in (0.5, 2.0, 5.0):
            got.append(outside_fraction(X, fields, px))
            ref.append(outside_fraction_reference(X, fields, px))
    np.testing.assert_array_equal(got, ref)
    assert min(ref) < 0.05 and max(ref) > 0.95 and len(set(ref)) >= 6  # inside, outside and in between
    assert outside_fraction(np.zeros((0, 3)), fields) == 0.0
