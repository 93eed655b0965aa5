"""The visual-hull gate's dispatch (reconstruct/rapid_skin.py ``hull_consistent_constraints``, 9d2d4f1; issue 17
mutation row): :class:`SilhouetteFields` take the compiled ``hull_gate``, any other hull its ``implicit_hull``
(``hull_gate_reference``); both keep the same constraints on the sphere scene of tests/reconstruct/conftest.py,
and each is called with the vertices, the constraints' vertices, rays and the gate."""

from functools import lru_cache

import numpy as np

from bodystudio.reconstruct import rapid_skin
from bodystudio.reconstruct.rapid_skin import hull_consistent_constraints, hull_gate_reference
from bodystudio.reconstruct.silhouette import area_weighted_normals, silhouette_constraints
from bodystudio.reconstruct.solver import SilhouetteConstraints
from bodystudio.reconstruct.tracking import SilhouetteFields


@lru_cache(maxsize=1)
def _sphere():
    """An icosphere of radius 0.30 m seen by 3 cameras, its silhouettes those of the sphere scaled by 1.05, and
    its silhouette constraints (conftest's ``sphere_scene``), the mesh shrunk by 4 % so some rays pass outside."""
    import trimesh

    from bodystudio.geometry.camera import Camera
    from bodystudio.reconstruct.silhouette import silhouette_mask

    m = trimesh.creation.icosphere(subdivisions=3, radius=0.30)
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.3, 3 * np.cos(a)), (0, 0, 0), fx=400.0, width=200, height=160)
            for i, a in enumerate([0.0, 2.1, 4.2])]
    masks = {c.name: silhouette_mask(1.05 * V, F, c) for c in cams}
    sil = silhouette_constraints(V, F, area_weighted_normals(V, F), cams, masks)
    return V, F, cams, masks, sil


class _Hull:
    """Wraps SilhouetteFields so only ``implicit_hull`` is seen (not an instance: the reference path)."""

    def __init__(self, fields):
        self.fields = fields

    def implicit_hull(self, X):
        return self.fields.implicit_hull(X)


def test_silhouette_fields_take_the_compiled_gate_with_the_constraints_rays_and_the_gate(monkeypatch):
    V, F, cams, masks, sil = _sphere()
    fields = SilhouetteFields(cams, masks)
    want = hull_gate_reference(V, sil, fields, 0.001)
    assert 0 < want.sum() < len(sil)  # some matches are dropped
    got = hull_consistent_constraints(V, sil, fields, 0.001)
    assert sil.camera is not None and sil.pixel_distance is not None
    for name in ("vertex", "origin", "direction", "k", "camera", "pixel_distance"):
        np.testing.assert_array_equal(getattr(got, name), getattr(sil, name)[want])
    bare = SilhouetteConstraints(sil.vertex, sil.origin, sil.direction, sil.k, None, None)
    got = hull_consistent_constraints(V, bare, fields, 0.001)
    assert got.camera is None and got.pixel_distance is None
    np.testing.assert_array_equal(got.direction, sil.direction[want])
    seen = []
    real = SilhouetteFields.hull_gate
    monkeypatch.setattr(SilhouetteFields, "hull_gate", lambda self, *a: seen.append(a) or real(self, *a))
    monkeypatch.setattr(rapid_skin, "hull_gate_reference", lambda *a: (_ for _ in ()).throw(AssertionError("ref")))
    hull_consistent_constraints(V, sil, fields, 0.002)
    (a,) = seen
    assert a[0] is V and a[1] is sil.vertex and a[2] is sil.origin and a[3] is sil.direction and a[4] == 0.002


def test_any_other_hull_takes_the_reference_with_the_same_decisions(monkeypatch):
    V, F, cams, masks, sil = _sphere()
    fields = SilhouetteFields(cams, masks)
    want = hull_gate_reference(V, sil, fields, 0.001)
    got = hull_consistent_constraints(V, sil, _Hull(fields), 0.001)
    np.testing.assert_array_equal(got.vertex, sil.vertex[want])
    np.testing.assert_array_equal(got.k, sil.k[want])
    seen = []
    real = rapid_skin.hull_gate_reference
    monkeypatch.setattr(rapid_skin, "hull_gate_reference", lambda *a: seen.append(a) or real(*a))
    hull = _Hull(fields)
    hull_consistent_constraints(V, sil, hull, 0.003)
    (a,) = seen
    assert a[0] is V and a[1] is sil and a[2] is hull and a[3] == 0.003
