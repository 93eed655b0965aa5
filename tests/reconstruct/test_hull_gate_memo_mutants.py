"""Mutation test of rec15i's compiled memo of the visual-hull gate (issue 17, branch mutT;
docs/mutation/reconstruct-tracking.md "rec15i"): ``SilhouetteFields.hull_gate_memo`` hands its kernel the fields' own
margin, which only the pairs seen beyond a field's stored box read: with a 2-pixel margin and the mesh moved off the
silhouettes the compiled memo still decides as the Python one. test_frame_tradeoffs.py's memo test has every pair
inside the 48-pixel boxes."""

import numpy as np

from bodystudio.reconstruct.rapid_skin import hull_consistent_constraints
from bodystudio.reconstruct.silhouette import area_weighted_normals, silhouette_constraints
from bodystudio.reconstruct.tracking import SilhouetteFields
from tests.reconstruct.test_frame_tradeoffs import _equal, scene  # noqa: F401  (six cameras, two spheres)


class _Hull:  # the fields' implicit hull alone: hull_consistent_constraints' Python memo path
    def __init__(self, fields):
        self.implicit_hull = fields.implicit_hull


def test_the_compiled_memo_reads_the_fields_margin_beyond_their_boxes(scene):  # noqa: F811
    V, F, cams, masks = scene
    fields = SilhouetteFields(cams, masks, margin_px=2)
    sil = silhouette_constraints(V, F, area_weighted_normals(V, F), cams, masks, 20.0, 5.0, 0.2)
    n = len(cams) * len(V)
    for shift in (0.05, 0.3):
        a, b = np.zeros(n, np.int8), np.zeros(n, np.int8)
        X = V + np.array([shift, 0.02, 0.0])
        _equal(hull_consistent_constraints(X, sil, fields, 0.001, memo=a, reuse=False),
               hull_consistent_constraints(X, sil, _Hull(fields), 0.001, memo=b, reuse=False))
        np.testing.assert_array_equal(a, b)
    slot = sil.camera * len(V) + sil.vertex
    assert (a[slot] == 2).any() and (a[slot] == 1).any()


def test_the_gate_with_a_memo_runs_compiled_and_hands_on_the_projection(scene, monkeypatch):  # noqa: F811
    """``hull_consistent_constraints`` with fields, a memo and constraints that know their cameras takes the compiled
    memo (rec15i), handing it the caller's projection; the same constraints with a projection as without."""
    V, F, cams, masks = scene
    fields = SilhouetteFields(cams, masks)
    sil = silhouette_constraints(V, F, area_weighted_normals(V, F), cams, masks, 20.0, 5.0, 0.2)
    seen = []
    real = SilhouetteFields.hull_gate_memo

    def spy(self, *args, **kwargs):
        seen.append(args[8] if len(args) > 8 else kwargs.get("projected"))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(SilhouetteFields, "hull_gate_memo", spy)
    n = len(cams) * len(V)
    plain = hull_consistent_constraints(V, sil, fields, 0.001, memo=np.zeros(n, np.int8), reuse=False)
    assert seen == [None]
    uv = np.stack([c.project_with_depth(V)[0] for c in cams])
    z = np.stack([c.project_with_depth(V)[1] for c in cams])
    given = hull_consistent_constraints(V, sil, fields, 0.001, projected=(uv, z), memo=np.zeros(n, np.int8),
                                        reuse=False)
    assert len(seen) == 2 and seen[1] is not None and seen[1][0] is uv and seen[1][1] is z
    _equal(given, plain)
