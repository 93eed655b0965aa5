"""register/scan.py against independent references (issue 17, branch mutDD): every refusal word for word, the
clean-up's counts on an icosphere with planted duplicates, null and non-manifold faces and debris of known size,
units at both ends of each range, the orientation of synthetic scans under all 24 proper axis permutations (the
expected up / facing names read off the permutation), the winding repair piece by piece, area-uniform surface
samples against the triangles' areas and centroids, the head-to-chest ratios of stacked boxes from the percentiles
written out, and ``load_scan``'s overrides, notes and report.
"""

import logging
from functools import cache
from itertools import permutations, product

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, FileFormatError, InputError
from bodystudio.geometry.mesh import Mesh, save_mesh, vertex_areas
from bodystudio.register import scan as sc


@cache
def _person(pose: str = "t"):
    """A synthetic scan (not built by the module under test): subject 12, T / A pose; subject 128's random pose."""
    from bodystudio.register.synthetic import synthetic_scan

    if pose == "random":
        return synthetic_scan(128, "random", 6000, 1.0, True)[0]
    return synthetic_scan(12, pose, 6000 if pose == "t" else 5000, 1.0 if pose == "t" else 0.0, pose == "t")[0]


def _sphere():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)


def _boxes(parts):
    """Axis-aligned boxes ``(x0, x1, y0, y1, z0, z1)`` as one outward-wound triangle mesh."""
    import trimesh

    Vs, Fs, n = [], [], 0
    for x0, x1, y0, y1, z0, z1 in parts:
        b = trimesh.creation.box(bounds=[[x0, y0, z0], [x1, y1, z1]])
        Vs.append(np.asarray(b.vertices))
        Fs.append(np.asarray(b.faces) + n)
        n += len(b.vertices)
    return np.vstack(Vs), np.vstack(Fs)


# ------------------------------------------------------------------------------------------------ read_scan_file

def test_read_scan_file_refusals_word_for_word(tmp_path):
    missing = tmp_path / "none.ply"
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(missing)
    assert str(e.value) == f"{missing}: no such scan file"
    other = tmp_path / "scan.xyz"
    other.write_text("1 2 3\n")
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(str(other))
    assert str(e.value) == f"{other}: unsupported scan format '.xyz'; use one of .ply, .obj, .glb, .gltf, .stl, .off"
    upper = tmp_path / "SCAN.PLY"
    upper.write_bytes(b"")
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(upper)
    assert str(e.value) == f"{upper}: empty file; give a triangle mesh scan"
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF not really")
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(broken)
    assert str(e.value).startswith(f"{broken}: not a readable mesh (") and str(e.value).endswith(")")
    import re

    assert re.match(rf"{re.escape(str(broken))}: not a readable mesh \((\w+Error|\w+Exception): ", str(e.value))
    assert e.value.__cause__ is None and e.value.__suppress_context__
    cloud = tmp_path / "cloud.ply"
    pts = np.random.default_rng(0).normal(size=(7, 3))
    cloud.write_text("ply\nformat ascii 1.0\nelement vertex 7\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n" + "\n".join(" ".join(map(str, p)) for p in pts) + "\n")
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(cloud)
    assert str(e.value) == (f"{cloud}: found a point cloud of 7 points and no triangles; mesh it first (e.g. "
                            "screened Poisson) and give a triangle mesh")


def test_a_scene_of_points_only_is_refused_and_meshes_are_joined(tmp_path):
    import trimesh

    pts = tmp_path / "points.glb"
    trimesh.Scene([trimesh.PointCloud(np.random.default_rng(1).normal(size=(9, 3)))]).export(pts)
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(pts)
    assert str(e.value) == f"{pts}: found no triangles (9 points); give a triangle mesh, not a point cloud"
    V, F = _sphere()
    two = tmp_path / "two.glb"
    trimesh.Scene([trimesh.Trimesh(V, F, process=False), trimesh.Trimesh(V + 3.0, F, process=False)]).export(two)
    mesh = sc.read_scan_file(two)
    assert mesh.n_vertices == 84 and mesh.n_faces == 160 and mesh.metadata == {"source": str(two)}
    assert np.isclose(mesh.vertices[:, 0].max(), V[:, 0].max() + 3.0)


def test_vertex_face_and_texture_colours_become_vertex_colours(tmp_path, caplog):
    import trimesh

    V, F = _sphere()
    col = (np.arange(42)[:, None] * [5, 3, 7] % 256).astype(np.uint8)
    path = tmp_path / "vc.ply"
    save_mesh(path, Mesh(V, F, col))
    got = sc.read_scan_file(path)
    np.testing.assert_array_equal(got.vertex_colors, col)
    assert got.vertex_colors.dtype == np.uint8 and got.vertices.dtype == np.float64
    np.testing.assert_allclose(got.vertices, V, atol=1e-6)
    np.testing.assert_array_equal(got.faces, F)
    # one colour for the whole surface given per face: every vertex gets it
    fc = tmp_path / "fc.ply"
    trimesh.Trimesh(V, F, face_colors=np.tile([10, 200, 30, 255], (80, 1)), process=False).export(fc)
    got = sc.read_scan_file(fc)
    np.testing.assert_array_equal(got.vertex_colors, np.tile([10, 200, 30], (42, 1)))
    # a texture of one colour: sampled to that colour everywhere
    from PIL import Image

    tex = trimesh.visual.TextureVisuals(uv=np.c_[V[:, 0] * 0.4 + 0.5, V[:, 1] * 0.4 + 0.5],
                                        image=Image.new("RGB", (8, 8), (40, 90, 160)))
    tx = tmp_path / "tx.glb"
    trimesh.Trimesh(V, F, visual=tex, process=False).export(tx)
    got = sc.read_scan_file(tx)
    assert got.vertex_colors is not None and np.abs(got.vertex_colors.astype(int) - [40, 90, 160]).max() <= 1
    plain = tmp_path / "plain.stl"
    trimesh.Trimesh(V, F, process=False).export(plain)
    assert sc.read_scan_file(plain).vertex_colors is None


def test_a_mesh_without_faces_one_face_and_nan_vertices(tmp_path, monkeypatch):
    import trimesh

    V, F = _sphere()
    one = tmp_path / "one.ply"
    save_mesh(one, Mesh(V[:3], F[:1] * 0 + [0, 1, 2]))
    assert sc.read_scan_file(one).n_faces == 1
    nan = tmp_path / "nan.ply"
    Vn = V.copy()
    Vn[5] = np.nan
    save_mesh(nan, Mesh(Vn, F))
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(nan)
    assert str(e.value) == f"{nan}: 1 vertices are NaN or infinite"
    monkeypatch.setattr(trimesh, "load", lambda *a, **k: trimesh.Trimesh(V, np.zeros((0, 3), int), process=False))
    with pytest.raises(FileFormatError) as e:
        sc.read_scan_file(one)
    assert str(e.value) == f"{one}: found 42 vertices and no triangles; give a triangle mesh scan"


def test_a_broken_texture_is_skipped_with_a_warning(tmp_path, caplog, monkeypatch):
    import trimesh

    V, F = _sphere()
    path = tmp_path / "s.ply"
    save_mesh(path, Mesh(V, F))

    class Broken:
        @property
        def kind(self):
            raise ValueError("bad image")

    real = trimesh.load

    def load(*a, **k):
        m = real(*a, **k)
        m.visual = Broken()
        return m

    monkeypatch.setattr(trimesh, "load", load)
    with caplog.at_level(logging.WARNING, logger="bodystudio.register.scan"):
        got = sc.read_scan_file(path)
    assert got.vertex_colors is None and got.n_faces == 80
    assert [r.getMessage() for r in caplog.records] == [f"{path}: cannot read colours (bad image); continuing without"]
    assert caplog.records[0].levelno == logging.WARNING


# ------------------------------------------------------------------------------------------------ clean_scan

def test_clean_scan_counts_each_repair():
    V, F = _sphere()
    n = len(V)
    e = F[0, :2]
    # the bounding box: x from -2.5 to 2.5 (the two loose pieces), y and z the sphere's
    diag = np.linalg.norm([5.0, *np.ptp(V[:, 1:], axis=0)])
    a, b = 0.04 * diag / np.sqrt(2), 0.06 * diag / np.sqrt(2)  # pieces 4 % (debris) and 6 % (kept) across
    extra = np.array([V[0],  # a duplicate of vertex 0, used by a face (merged into 0)
                      [0.0, 0.0, 0.01],  # unreferenced
                      V[e].mean(0) * 0.9, V[e].mean(0) * 0.8,  # two fins on edge e: non-manifold
                      [2.5 - a, 0, 0], [2.5, 0, 0], [2.5 - a, a, 0],
                      [-2.5 + b, 0, 0], [-2.5, 0, 0], [-2.5 + b, b, 0]])
    V2 = np.vstack([V, extra])
    dup = [[n, F[5, 1], F[5, 2]]] if F[5, 0] == 0 else [[F[5, 0], F[5, 1], F[5, 2]]]
    F2 = np.vstack([F, [F[3]], [[0, 0, 1]], [[e[0], e[1], n + 2], [e[1], e[0], n + 3]], [[n + 4, n + 5, n + 6]],
                    [[n + 7, n + 8, n + 9]], dup, [[n, F[0, 1], F[0, 2]]] if F[0, 0] == 0 else np.zeros((0, 3), int)])
    col = (np.arange(len(V2))[:, None] * [3, 5, 7] % 256).astype(np.uint8)
    mesh = Mesh(V2, F2, col, {"source": "x.ply"})
    out, removed_v, removed_f = sc.clean_scan(mesh)
    assert np.isclose(np.linalg.norm(np.ptp(V2, axis=0)), diag) and sc.MIN_COMPONENT_FRACTION == 0.05
    # kept: the sphere's 42 vertices and the 6 % piece (3)
    assert out.n_vertices == 45 and removed_v == len(V2) - 45
    assert out.n_faces == 81 and removed_f == len(F2) - 81
    assert out.metadata == {"source": "x.ply"} and out.vertices.dtype == np.float64 and out.faces.dtype == np.int64
    assert out.vertex_colors.dtype == np.uint8
    kept = np.r_[np.arange(n), n + 7, n + 8, n + 9]
    order = [int(np.flatnonzero(np.all(np.isclose(V2[kept], p), axis=1))[0]) for p in out.vertices]
    np.testing.assert_array_equal(out.vertex_colors, col[kept][order])
    plain, rv, rf = sc.clean_scan(Mesh(V, F))
    assert plain.vertex_colors is None and (rv, rf) == (0, 0) and plain.n_faces == 80


# ------------------------------------------------------------------------------------------------ units

@pytest.mark.parametrize("extent,unit,scale", [(0.3, "m", 1.0), (3.0, "m", 1.0), (30.0, "cm", 0.01),
                                               (300.0, "cm", 0.01), (300.5, "mm", 0.001), (3000.0, "mm", 0.001)])
def test_units_at_both_ends_of_each_range(extent, unit, scale):
    assert sc.detect_units(extent, "s.ply") == (unit, scale)


@pytest.mark.parametrize("extent,shown", [(0.2999, "0.2999"), (3.001, "3.001"), (29.99, "29.99"), (3000.5, "3000"),
                                          (12345.678, "1.235e+04")])
def test_no_adult_in_any_unit_is_refused(extent, shown):
    with pytest.raises(InputError) as e:
        sc.detect_units(extent, "s.ply")
    assert str(e.value) == (f"s.ply: the scan is {shown} units tall, which is no standing adult in m, cm or mm; "
                            "rescale it to metres")


# ------------------------------------------------------------------------------------------------ orientation

def test_central_fraction_and_weighted_mean_by_hand():
    x = np.arange(11.0)
    w = np.arange(1.0, 12.0)
    # lo 0, hi 10: strictly between 3.5 and 6.5 are 4, 5, 6
    assert sc._central_fraction(x, w) == pytest.approx((5 + 6 + 7) / 66)
    assert sc._central_fraction(np.array([0.0, 3.5, 5.0, 6.5, 10.0]), np.ones(5)) == pytest.approx(0.2)
    # lo 10, hi 20: strictly between 13.5 and 16.5 are 14, 15, 16
    assert sc._central_fraction(x + 10.0, w) == pytest.approx((5 + 6 + 7) / 66)
    assert sc._weighted_mean(np.array([1.0, 3.0]), np.array([1.0, 3.0])) == pytest.approx(2.5)
    assert sc._weighted_mean(np.array([1.0, 3.0]), np.zeros(2)) == pytest.approx(2.0)


def _proper_permutations():
    for perm, signs in product(permutations(range(3)), product((-1.0, 1.0), repeat=3)):
        P = np.eye(3)[list(perm)] * np.array(signs)[:, None]
        if np.linalg.det(P) > 0:
            yield P


def _axis_name(P, canonical_axis):
    """The file axis (name and sign) that canonical axis ``canonical_axis`` (1 = y up, 2 = z facing) went to."""
    k = int(np.flatnonzero(P[:, canonical_axis])[0])
    return ("+" if P[k, canonical_axis] > 0 else "-") + "xyz"[k]


@pytest.mark.parametrize("pose", ["t", "a", "random"])
def test_orientation_undoes_every_proper_permutation(pose):
    scan = _person(pose)
    area = vertex_areas(scan.vertices, scan.faces)
    ext = np.ptp(scan.vertices, axis=0)
    if pose == "t":
        assert ext[0] > ext[1] / 1.3  # arms spread: the central-surface branch decides the vertical axis
    else:
        assert ext[1] > 1.3 * ext[0]
    for P in _proper_permutations():
        R, up, facing = sc.detect_orientation(scan.vertices @ P.T, area)
        np.testing.assert_allclose(R @ P, np.eye(3), atol=1e-12)
        assert (up, facing) == (_axis_name(P, 1), _axis_name(P, 2))


def _box_person(lift_left_foot=False):
    """A standing person of boxes, 1 m tall, facing +z: legs, feet with the toes 10 cm ahead of the shins, a trunk
    wider than deep, arms down beside it, a head (each box subdivided three times: vertices every 1-2 cm)."""
    import trimesh

    lift = 0.1 if lift_left_foot else 0.0
    parts = [(-0.16, -0.04, 0.05, 0.45, -0.05, 0.05), (0.04, 0.16, 0.05 + lift, 0.45, -0.05, 0.05),
             (-0.16, -0.04, 0.0, 0.05, -0.05, 0.15), (0.04, 0.16, lift, 0.05 + lift, -0.05, 0.15),
             (-0.2, 0.2, 0.45, 0.85, -0.1, 0.1), (-0.27, -0.21, 0.5, 0.82, -0.04, 0.04),
             (0.21, 0.27, 0.5, 0.82, -0.04, 0.04), (-0.07, 0.07, 0.86, 1.0, -0.08, 0.08)]
    ms = [trimesh.creation.box(bounds=[[x0, y0, z0], [x1, y1, z1]]).subdivide().subdivide().subdivide()
          for x0, x1, y0, y1, z0, z1 in parts]
    m = trimesh.util.concatenate(ms)
    return np.asarray(m.vertices), np.asarray(m.faces)


@pytest.mark.parametrize("lift,offset", [(False, (0.0, 0.0, 0.0)), (True, (0.0, 0.0, 0.0)), (False, (3.0, -2.0, 5.0))])
def test_orientation_of_a_box_person_every_proper_permutation(lift, offset):
    # each cue decides on its own here: the height (1.0 m against 0.54 m), the skin above mid-height (trunk, arms,
    # head), the trunk 0.4 wide and 0.2 deep, the feet 10 cm ahead of the shins (one foot lifted 10 cm: only the
    # other one is the lowest slice) and the head top no further forward than the neck; also far from the origin
    V, F = _box_person(lift)
    V = V + offset
    area = vertex_areas(V, F)
    for P in _proper_permutations():
        R, up, facing = sc.detect_orientation(V @ P.T, area)
        np.testing.assert_allclose(R @ P, np.eye(3), atol=1e-12)
        assert (up, facing) == (_axis_name(P, 1), _axis_name(P, 2))


# ------------------------------------------------------------------------------------------------ winding

def test_winding_repair_by_signed_volume_per_piece():
    V, F = _sphere()
    out, n = sc.orient_faces_outward(V, F)
    assert n == 0 and out is F
    out, n = sc.orient_faces_outward(V, F[:, ::-1])
    assert n == 80
    np.testing.assert_array_equal(out, F)
    # two spheres far apart, the second wound inwards; the centroid lies between them
    V2, F2 = np.vstack([V - 3.0, V + 3.0]), np.vstack([F, F[:, ::-1] + 42])
    out, n = sc.orient_faces_outward(V2, F2)
    assert n == 80 and out.dtype == np.int64
    np.testing.assert_array_equal(out, np.vstack([F, F + 42]))
    # an open cap (the top half of the sphere) wound inwards is turned as well; pieces joined at one vertex
    # only (a face of the cap sharing a corner with the rest) are one piece
    top = F[V[F].mean(1)[:, 1] > 0.2]
    out, n = sc.orient_faces_outward(V, top[:, ::-1])
    assert n == len(top)
    np.testing.assert_array_equal(out, top)
    empty = np.zeros((0, 3), np.int32)
    out, n = sc.orient_faces_outward(V, empty)
    assert n == 0 and out is empty
    out, n = sc.orient_faces_outward(V, F[:, ::-1].astype(np.int32))
    assert n == 80 and out.dtype == np.int64
    # one face wound inwards (about the centroid of all the vertices) is turned
    out, n = sc.orient_faces_outward(V, F[:1, ::-1])
    assert n == 1
    np.testing.assert_array_equal(out, F[:1])
    # a flat square through the centroid has no volume: neither inwards nor outwards, left as it is
    sq = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]])
    Fs = np.array([[0, 1, 2], [0, 2, 3]])
    out, n = sc.orient_faces_outward(sq, Fs)
    assert n == 0 and out is Fs


def test_a_piece_is_everything_connected_through_any_corner():
    # a large outward triangle and a small inward one sharing only their last corner: one piece, whose signed
    # volume (positive) keeps both; the same two apart (the corner duplicated) are two pieces, the small one turned
    V = np.array([[1.0, 0, 0], [0, 1, 0], [0.3, 0.3, 0.3], [-0.2, 0.0, 0.1], [0.0, -0.2, 0.1], [0.3, 0.3, 0.3]])
    c = V.mean(0)
    joined, apart = np.array([[0, 1, 2], [4, 3, 2]]), np.array([[0, 1, 2], [4, 3, 5]])
    vol = [np.linalg.det(np.stack([V[i] - c for i in f])) for f in joined]
    assert vol[0] > 0 > vol[1] and vol[0] + vol[1] > 0
    out, n = sc.orient_faces_outward(V, joined)
    assert n == 0 and out is joined
    out, n = sc.orient_faces_outward(V, apart)
    assert n == 1
    np.testing.assert_array_equal(out, [[0, 1, 2], [5, 3, 4]])


# ------------------------------------------------------------------------------------------------ shape check

def test_surface_samples_are_uniform_over_the_area():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 2, 0], [5, 0, 0], [8, 0, 0], [5, 2, 0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])  # areas 1 and 3
    P = sc.surface_samples(V, F)
    assert P.shape == (20000, 3)
    np.testing.assert_array_equal(P, sc.surface_samples(V, F, 20000, 0))
    assert not np.array_equal(P, sc.surface_samples(V, F, 20000, 1))
    first = P[:, 0] < 2.5
    assert abs(first.mean() - 0.25) < 0.012
    # inside each triangle and spread over it: the mean is the centroid, the x-spread that of a uniform triangle
    for sel, (a, b, c) in ((first, V[:3]), (~first, V[3:])):
        Q = P[sel]
        lam = np.linalg.solve(np.c_[b - a, c - a][:2], (Q - a)[:, :2].T).T
        assert (lam >= -1e-12).all() and (lam.sum(1) <= 1 + 1e-12).all()
        np.testing.assert_allclose(Q.mean(0), (a + b + c) / 3, atol=0.03)
        assert abs((lam.sum(1) <= 0.5).mean() - 0.25) < 0.03  # the corner a's quarter of the area
    assert len(sc.surface_samples(V, F, 10)) == 10
    small = sc.surface_samples(V * 0.1, F, 50)  # total area 0.04: sampled all the same
    assert small.shape == (50, 3) and not np.isin(small, V * 0.1).all(axis=1).any()
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert sc.surface_samples(flat, np.array([[0, 1, 2]])) is flat


def _ratios_by_hand(V, F):
    P = sc.surface_samples(V, F)
    y = P[:, 1]
    floor, h = y.min(), y.max() - y.min()
    out = []
    for a in (0, 2):
        bands = []
        for lo, hi in ((0.9, 1.0), (0.55, 0.8)):
            s = P[(y >= floor + lo * h) & (y <= floor + hi * h), a]
            bands.append(np.percentile(s, 98) - np.percentile(s, 2))
        out.append(bands[0] / bands[1])
    return out


def test_head_to_chest_ratios_of_stacked_boxes():
    # legs 0-0.5, chest 0.5-0.85 (0.4 wide, 0.24 deep), head 0.85-1.0 (0.12 wide, 0.16 deep)
    V, F = _boxes([(-0.15, 0.15, 0.0, 0.5, -0.1, 0.1), (-0.2, 0.2, 0.5, 0.85, -0.12, 0.12),
                   (-0.06, 0.06, 0.85, 1.0, -0.08, 0.08)])
    got = sc.head_to_chest_ratios(V, F)
    assert isinstance(got, tuple) and len(got) == 2
    np.testing.assert_allclose(got, _ratios_by_hand(V, F), rtol=1e-12)
    assert 0.27 < got[0] < 0.33 and 0.6 < got[1] < 0.7
    person = _person("a")
    np.testing.assert_allclose(sc.head_to_chest_ratios(person.vertices, person.faces),
                               _ratios_by_hand(person.vertices, person.faces), rtol=1e-12)
    # a column whose top band has too few samples (< 20) to measure: NaN
    V2, F2 = _boxes([(-0.2, 0.2, 0.0, 1.0, -0.1, 0.1), (-0.0005, 0.0005, 1.0, 1.2, -0.0005, 0.0005)])
    r = sc.head_to_chest_ratios(V2, F2)
    assert np.isnan(r[0]) and np.isnan(r[1])


def test_check_standing_person_refuses_a_box_word_for_word():
    V, F = _boxes([(-0.2, 0.2, 0.0, 1.7, -0.1, 0.1)])
    r = sc.head_to_chest_ratios(V, F)
    with pytest.raises(InputError) as e:
        sc.check_standing_person(Mesh(V, F), "box.ply")
    assert str(e.value) == (f"box.ply: the shape has no head: its top is {r[0]:.2f}x as wide and {r[1]:.2f}x as deep "
                            "as its middle (a person's head is under half as wide as the shoulders), so it is not a "
                            "person standing upright; give a body scan")
    V, F = _boxes([(-0.2, 0.2, 0.0, 0.85, -0.1, 0.1), (-0.18, 0.18, 0.85, 1.0, -0.08, 0.08)])
    r = sc.head_to_chest_ratios(V, F)
    with pytest.raises(InputError) as e:
        sc.check_standing_person(Mesh(V, F), "col.ply")
    assert f"its top is {r[0]:.2f}x as wide and {r[1]:.2f}x as deep" in str(e.value) and f"{r[0]:.2f}" != f"{r[1]:.2f}"
    # narrow on top in one direction only: not refused; nor a top too thin to measure
    V, F = _boxes([(-0.2, 0.2, 0.0, 0.88, -0.1, 0.1), (-0.2, 0.2, 0.88, 1.0, -0.02, 0.02)])
    assert sc.check_standing_person(Mesh(V, F), "x") is None
    V, F = _boxes([(-0.2, 0.2, 0.0, 0.88, -0.1, 0.1), (-0.02, 0.02, 0.88, 1.0, -0.1, 0.1)])
    assert sc.check_standing_person(Mesh(V, F), "x") is None
    V, F = _boxes([(-0.2, 0.2, 0.0, 1.0, -0.1, 0.1), (-0.0005, 0.0005, 1.0, 1.2, -0.0005, 0.0005)])
    assert sc.check_standing_person(Mesh(V, F), "x") is None
    # just over and under the threshold: a top 0.80 / 0.70 as wide and deep as the middle
    assert sc.MAX_HEAD_TO_CHEST_RATIO == 0.75
    for k, refused in ((0.8, True), (0.7, False)):
        V, F = _boxes([(-0.2, 0.2, 0.0, 0.85, -0.1, 0.1), (-0.2 * k, 0.2 * k, 0.85, 1.0, -0.1 * k, 0.1 * k)])
        if refused:
            with pytest.raises(InputError):
                sc.check_standing_person(Mesh(V, F), "x")
        else:
            sc.check_standing_person(Mesh(V, F), "x")


# ------------------------------------------------------------------------------------------------ load_scan

def _saved(tmp_path, name, V, F, colors=None):
    path = tmp_path / name
    save_mesh(path, Mesh(V, F, colors))
    return path


def test_report_as_dict():
    r = sc.ScanReport("s.ply", "cm", "+z", "-y", np.eye(3) * 0.01, 3, 4, ("a", "b"))
    assert r.as_dict() == {"source": "s.ply", "units": "cm", "up_axis": "+z", "facing_axis": "-y",
                           "to_canonical": (np.eye(3) * 0.01).tolist(), "removed_vertices": 3, "removed_faces": 4,
                           "notes": ["a", "b"]}
    assert sc.ScanReport("s", "m", "+y", "+z", np.eye(3), 0, 0).notes == ()


def test_load_scan_detects_a_rotated_centimetre_scan_and_keeps_the_translation(tmp_path, caplog):
    scan = _person("a")
    to_file = np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])  # canonical y -> file z, z -> file x
    V = 100.0 * scan.vertices @ to_file.T + [50.0, -20.0, 300.0]
    path = _saved(tmp_path, "cm.ply", V, scan.faces, scan.vertex_colors)
    with caplog.at_level(logging.INFO, logger="bodystudio.register.scan"):
        mesh, report = sc.load_scan(str(path))
    np.testing.assert_allclose(report.to_canonical, 0.01 * to_file.T, atol=1e-15)
    np.testing.assert_allclose(mesh.vertices, V @ report.to_canonical.T)
    assert (report.source, report.units, report.up_axis, report.facing_axis) == (str(path), "cm", "+z", "+x")
    assert (report.removed_vertices, report.removed_faces) == (0, 0)
    height = np.ptp(V[:, 2])
    assert report.notes == ("assumed up axis +z, facing +x (detected from the body's shape)",
                            f"assumed units cm (scan is {height:.4g} units tall)")
    assert [r.getMessage() for r in caplog.records] == [f"cm.ply: {n}" for n in report.notes]
    assert mesh.metadata == {"source": str(path)} and mesh.vertex_colors is not None
    np.testing.assert_array_equal(mesh.faces, scan.faces)


@pytest.mark.parametrize("axis", ["+x", "-x", "+y", "-y", "+z", "-z"])
@pytest.mark.parametrize("facing", [1.0, -1.0])
def test_load_scan_with_each_up_axis_given(tmp_path, axis, facing):
    scan = _person("a")
    k, s = "xyz".index(axis[1]), 1.0 if axis[0] == "+" else -1.0
    # the canonical y goes to file axis k with sign s; the facing z to another axis, right-handed
    P = np.zeros((3, 3))
    P[k, 1] = s
    P[(k + 2) % 3, 2] = facing
    P[:, 0] = np.cross(P[:, 1], P[:, 2])
    path = _saved(tmp_path, "s.ply", scan.vertices @ P.T, scan.faces)
    mesh, report = sc.load_scan(path, units="m", up_axis=axis)
    np.testing.assert_allclose(report.to_canonical @ P, np.eye(3), atol=1e-12)
    assert report.up_axis == axis and report.units == "m"
    assert report.facing_axis == _axis_name(P, 2)
    assert report.notes == ()
    np.testing.assert_allclose(mesh.vertices, scan.vertices, atol=1e-9)


def test_the_given_up_axis_wins_over_the_shape(tmp_path):
    # an upright scan (y up, facing +z) said to be +x / -y up is turned so that that axis points up, as asked; the
    # detection alone turned it back upright and only reported the axis it was given. Lying on its side it loads
    # (the user's word); standing on its head it is refused as no standing person
    scan = _person("a")
    path = _saved(tmp_path, "s.ply", scan.vertices, scan.faces)
    _, report = sc.load_scan(path, units="m", up_axis="+x")
    np.testing.assert_allclose(report.to_canonical[1], [1.0, 0.0, 0.0], atol=1e-12)
    assert report.up_axis == "+x" and report.facing_axis == "+z"
    with pytest.raises(InputError) as e:
        sc.load_scan(path, units="m", up_axis="-y")
    assert str(e.value).startswith(f"{path}: the shape has no head")


def test_detect_orientation_with_the_vertical_known():
    scan = _person("random")
    area = vertex_areas(scan.vertices, scan.faces)
    for P in _proper_permutations():
        k = int(np.flatnonzero(P[:, 1])[0])
        if P[k, 1] < 0:
            continue  # up given means that axis points up
        R, up, facing = sc.detect_orientation(scan.vertices @ P.T, area, up=k)
        np.testing.assert_allclose(R @ P, np.eye(3), atol=1e-12)
        assert (up, facing) == (_axis_name(P, 1), _axis_name(P, 2))
    # upside down but said to be up: kept upside down (y stays the vertical, pointing where it was said to)
    R, up, _ = sc.detect_orientation(scan.vertices * [1, -1, -1], area, up=1)
    assert up == "+y" and np.allclose(R[1], [0, 1, 0])


def test_load_scan_units_given_and_refusals(tmp_path, monkeypatch):
    scan = _person("a")
    path = _saved(tmp_path, "s.ply", scan.vertices * 1000.0, scan.faces)
    mesh, report = sc.load_scan(path, units="mm")
    assert report.units == "mm" and report.notes == ("assumed up axis +y, facing +z (detected from the body's shape)",)
    np.testing.assert_allclose(report.to_canonical, np.eye(3) * 0.001)
    mesh, report = sc.load_scan(path, units="cm")  # believed: a 16 m tall body is the user's choice
    assert report.units == "cm" and np.isclose(np.ptp(mesh.vertices[:, 1]), 10.0 * np.ptp(scan.vertices[:, 1]))
    big = _saved(tmp_path, "big.ply", scan.vertices * 5.0, scan.faces)
    with pytest.raises(InputError) as e:
        sc.load_scan(big)
    assert str(e.value).startswith(f"{big}: the scan is ") and str(e.value).endswith("rescale it to metres")
    with pytest.raises(InputError) as e:
        sc.load_scan(path, units="in")
    assert str(e.value) == "unknown units 'in'; valid: m, cm, mm"
    with pytest.raises(InputError) as e:
        sc.load_scan(path, up_axis="y")
    assert str(e.value) == "unknown up axis 'y'; valid: +x, -x, +y, -y, +z, -z"
    n = scan.n_vertices
    monkeypatch.setattr(sc, "MAX_SCAN_VERTICES", n - 1)
    with pytest.raises(InputError) as e:
        sc.load_scan(path)
    assert str(e.value) == (f"{path}: the scan has {n} vertices, more than the {n - 1} supported; decimate it first")
    monkeypatch.setattr(sc, "MAX_SCAN_VERTICES", n)
    assert sc.load_scan(path)[1].units == "mm"
    assert sc.MAX_SCAN_VERTICES == n


def test_load_scan_small_and_empty_meshes(tmp_path):
    g = np.stack(np.meshgrid(np.arange(11.0), np.arange(9.0)), -1).reshape(-1, 2)  # 99 vertices
    V = np.c_[g[:, 0] * 0.1, g[:, 1] * 0.2, np.zeros(99)]
    F = np.array([[i, i + 1, i + 11] for i in range(80) if (i % 11) < 10])
    path = _saved(tmp_path, "few.ply", V, F)
    with pytest.raises(InputError) as e:
        sc.load_scan(path)
    assert str(e.value) == f"{path}: found only 99 vertices; a body scan has thousands"
    V100 = np.vstack([V, [[5.0, 5.0, 5.0]]])  # 100 vertices: past that check, then the flat sheet is no adult
    path = _saved(tmp_path, "hundred.ply", V100, F)
    with pytest.raises(BodyStudioError) as e:
        sc.load_scan(path)
    assert "found only" not in str(e.value)
    null = np.array([[i, i, i + 1] for i in range(99)])  # only null faces: nothing left after the clean-up
    path = _saved(tmp_path, "null.ply", V100, null)
    with pytest.raises(FileFormatError) as e:
        sc.load_scan(path)
    assert str(e.value) == f"{path}: no triangles left after removing duplicates and debris"


def test_load_scan_notes_the_clean_up_and_the_faces_turned(tmp_path, caplog):
    scan = _person("a")
    n = scan.n_vertices
    V = np.vstack([scan.vertices, [[3.0, 0.0, 0.0]]])  # one unreferenced vertex
    path = _saved(tmp_path, "in.ply", V, scan.faces[:, ::-1])
    with caplog.at_level(logging.INFO, logger="bodystudio.register.scan"):
        mesh, report = sc.load_scan(path)
    m = len(scan.faces)
    assert (report.removed_vertices, report.removed_faces) == (1, 0) and mesh.n_vertices == n
    assert report.notes[0] == "clean-up removed 1 vertices and 0 faces"
    assert report.notes[-1] == f"{m} of {m} faces were wound inwards (normals into the body): turned outwards"
    assert caplog.records[-1].getMessage() == f"in.ply: {report.notes[-1]}"
    np.testing.assert_array_equal(mesh.faces, scan.faces)


def test_load_scan_refuses_a_box_after_canonicalising(tmp_path):
    V, F = _boxes([(-0.2, 0.2, 0.0, 1.7, -0.1, 0.1)])
    import trimesh

    box = trimesh.Trimesh(V, F, process=False).subdivide().subdivide().subdivide()
    path = _saved(tmp_path, "box.ply", np.asarray(box.vertices) * 100.0, np.asarray(box.faces))
    with pytest.raises(InputError) as e:
        sc.load_scan(path)
    assert str(e.value).startswith(f"{path}: the shape has no head")
