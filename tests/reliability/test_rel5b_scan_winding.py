"""A scan whose faces are wound inwards (normals into the body; some exporters write clockwise triangles) for
``bodystudio rig`` (reliability round rel5b audit).

The registration pairs scan and model points only where their normals agree, so such a scan had no pairs on the
right side and was refused as "the body model fits this scan only to 48 mm (median) ... is it a human body standing
upright?" (the shared 6000-vertex synthetic scan, faces reversed; exit 2), a misdiagnosis; an avatar from it would
have been drawn inside out. ``register.scan.load_scan`` now turns every inward piece outwards
(``orient_faces_outward``) with a note, as it detects units and the up axis: the reversed scan rigs as the original
does (fit 1.32 / 3.53 mm median / p90 both; docs/rigging.md)."""

from __future__ import annotations

import numpy as np

from bodystudio.geometry.mesh import Mesh, load_mesh, save_mesh
from bodystudio.register.scan import load_scan, orient_faces_outward


def _cube(offset, inward: bool):
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) + offset
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, (F[:, ::-1] if inward else F)


def test_each_piece_is_turned_outwards_on_its_own():
    (Va, Fa), (Vb, Fb) = _cube(0.0, inward=False), _cube(3.0, inward=True)
    V, F = np.vstack([Va, Vb]), np.vstack([Fa, Fb + 8])
    c = Va.mean(axis=0)
    assert np.linalg.det(np.stack([Va[f] - c for f in Fa[0]])) > 0  # the first cube is the outward one
    out, flipped = orient_faces_outward(V, F)
    assert flipped == 12
    np.testing.assert_array_equal(out[:12], Fa)  # left as it was
    np.testing.assert_array_equal(out[12:], Fb[:, ::-1] + 8)  # turned
    same, none = orient_faces_outward(V, out)
    assert none == 0 and same is out  # an outward scan comes back as it is


def test_a_scan_wound_inwards_loads_as_the_outward_one(studio, tmp_path):
    m = load_mesh(studio.scan)
    save_mesh(tmp_path / "inward.ply", Mesh(m.vertices, m.faces[:, ::-1].copy()))
    outward, report = load_scan(studio.scan)
    turned, report_turned = load_scan(tmp_path / "inward.ply")
    np.testing.assert_array_equal(turned.faces, outward.faces)
    np.testing.assert_allclose(turned.vertices, outward.vertices)
    assert not any("wound inwards" in n for n in report.notes)
    assert any(n.startswith(f"{len(m.faces)} of {len(m.faces)} faces were wound inwards") for n in report_turned.notes)
