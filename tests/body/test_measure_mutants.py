"""body/measure.py (stature, mass, girths, limb lengths) against independent references: directed-edge sets by
hand, boxes and prisms whose volume, sections and hull perimeters are known in closed form, a section and
convex-hull girth written from the docstring (edge-by-edge cut points, components by a walk over the cut faces,
the hull by Andrew's monotone chain), and the landmarks of a template as the nearest kept vertex by brute force.
The 2k body is built once per process (functools.cache); the file runs in a few seconds.
"""

from functools import cache

import numpy as np
import pytest

from bodystudio.body import measure as ms
from bodystudio.errors import InputError

BOX = np.array([[x, y, z] for x in (0.0, 0.3) for y in (-0.5, 0.5) for z in (0.0, 0.2)])  # 0.3 x 1 x 0.2
# outward triangles of the box (vertex i = 4 x + 2 y + z)
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def directed_edges(F):
    return {(int(f[i]), int(f[(i + 1) % 3])) for f in F for i in range(3)}


def boundary_by_hand(F):
    E = directed_edges(F)
    return any((b, a) not in E for a, b in E)


def volume_by_hand(V, F):
    return sum(np.dot(V[a], np.cross(V[b], V[c])) for a, b, c in F) / 6.0


def prism(polygon, y0=0.0, y1=1.0, offset=(0.0, 0.0)):
    """The side wall of the polygon (k, 2) in (x, z) extruded from y0 to y1 (no caps; sections do not need them)."""
    P = np.asarray(polygon, float) + offset
    k = len(P)
    V = np.r_[np.c_[P[:, 0], np.full(k, y0), P[:, 1]], np.c_[P[:, 0], np.full(k, y1), P[:, 1]]]
    F = []
    for i in range(k):
        j = (i + 1) % k
        F += [[i, j, k + j], [i, k + j, k + i]]
    return V, np.array(F)


def hull_perimeter(points):
    """Perimeter of the 2-D convex hull (Andrew's monotone chain)."""
    pts = sorted(map(tuple, np.round(points, 12)))

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    hull = half(pts)[:-1] + half(pts[::-1])[:-1]
    return sum(np.linalg.norm(np.subtract(hull[i], hull[i - 1])) for i in range(len(hull)))


def section_by_hand(V, F, h):
    """The cut of y = h: per face the points on its edges with one end >= h and the other below, linked into
    curves by walking from face to face over shared edges."""
    above = V[:, 1] >= h
    point, links = {}, []
    for f in F:
        cut = []
        for i in range(3):
            a, b = int(f[i]), int(f[(i + 1) % 3])
            if above[a] != above[b]:
                lo, hi = min(a, b), max(a, b)
                t = (h - V[lo, 1]) / (V[hi, 1] - V[lo, 1])
                point[(lo, hi)] = V[lo][[0, 2]] + t * (V[hi] - V[lo])[[0, 2]]
                cut.append((lo, hi))
        if cut:
            links.append(cut)
    neighbours = {e: set() for e in point}
    for a, b in links:
        neighbours[a].add(b)
        neighbours[b].add(a)
    curves, seen = [], set()
    for e in point:
        if e in seen:
            continue
        stack, comp = [e], []
        seen.add(e)
        while stack:
            x = stack.pop()
            comp.append(point[x])
            for y in neighbours[x] - seen:
                seen.add(y)
                stack.append(y)
        curves.append(np.array(comp))
    return curves


def girth_by_hand(V, F, h):
    curves = [c for c in section_by_hand(V, F, h) if len(c) >= 3]
    if not curves:
        return float("nan")
    return hull_perimeter(max(curves, key=lambda c: np.prod(c.max(0) - c.min(0))))


def test_has_boundary_is_some_directed_edge_without_its_opposite():
    assert not ms.has_boundary(BOX_FACES) and not boundary_by_hand(BOX_FACES)
    for drop in range(len(BOX_FACES)):
        F = np.delete(BOX_FACES, drop, axis=0)
        assert ms.has_boundary(F) and boundary_by_hand(F)
    # a face of the closed box flipped: each of its edges now runs twice one way
    flipped = BOX_FACES.copy()
    flipped[3] = flipped[3, ::-1]
    assert ms.has_boundary(flipped) and boundary_by_hand(flipped)
    # the largest vertex index alone in one face: the key's base is max + 1
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    assert not ms.has_boundary(tet) and ms.has_boundary(tet[[0, 1, 2]])
    assert not ms.has_boundary(tet[:, [1, 2, 0]]) and not ms.has_boundary(tet[:, ::-1])
    assert ms.has_boundary(np.array([[0, 1, 2]])) and ms.has_boundary(np.array([[2, 0, 1]]))  # one triangle


@pytest.mark.parametrize("hole", [[0, 1], [4, 5, 6, 7], [0, 1, 2, 3]])
def test_closing_the_box_gives_its_exact_volume_either_orientation(hole):
    open_F = np.delete(BOX_FACES, hole, axis=0)
    for F, sign in ((open_F, 1.0), (open_F[:, ::-1].copy(), -1.0)):
        Vc, Fc = ms.close_boundary_loops(BOX, F)
        assert not boundary_by_hand(Fc)
        n_loops = 1 if len(hole) == 2 else 2
        assert len(Vc) == len(BOX) + n_loops and len(Fc) == len(F) + 4 * n_loops
        np.testing.assert_array_equal(Vc[: len(BOX)], BOX)
        np.testing.assert_array_equal(Fc[: len(F)], F)
        fans = Fc[len(F):]
        assert sorted(set(fans[:, 2].tolist())) == list(range(len(BOX), len(BOX) + n_loops))  # around the new centres
        assert (fans[:, 2] >= len(BOX)).all() and (fans[:, :2] < len(BOX)).all()
        assert volume_by_hand(Vc, Fc) == pytest.approx(sign * 0.06, abs=1e-15)
        assert ms.enclosed_volume(Vc, Fc) == pytest.approx(sign * 0.06, abs=1e-15)
        # the fan's centre is the loop's centroid
        for c in Vc[len(BOX):]:
            loop_centres = [BOX[[0, 2, 6, 4]].mean(0), BOX[[1, 3, 7, 5]].mean(0), BOX[[0, 1, 5, 4]].mean(0),
                            BOX[[4, 5, 7, 6]].mean(0), BOX[[0, 1, 3, 2]].mean(0), BOX[[2, 3, 7, 6]].mean(0)]
            assert min(np.linalg.norm(c - m) for m in loop_centres) < 1e-15


def test_a_triangular_hole_is_closed_too():
    tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    T = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    for drop in range(4):
        Vc, Fc = ms.close_boundary_loops(tet, np.delete(T, drop, axis=0))
        assert len(Vc) == 5 and len(Fc) == 6 and not boundary_by_hand(Fc)
        np.testing.assert_allclose(Vc[4], tet[T[drop]].mean(0), atol=1e-15)
        assert volume_by_hand(Vc, Fc) == pytest.approx(1 / 6, abs=1e-15)
        assert ms.body_mass(tet, np.delete(T, drop, axis=0)) == pytest.approx(1010.0 / 6, abs=1e-12)


def test_loops_that_libigl_lists_the_other_way_round_are_turned(monkeypatch):
    """The fan must run each boundary edge against the faces: a loop listed against the faces' direction is
    reversed first (libigl lists them along the faces; the branch is kept for other conventions)."""
    import igl

    listed = igl.boundary_loop_all
    monkeypatch.setattr(igl, "boundary_loop_all", lambda F: [list(loop)[::-1] for loop in listed(F)])
    for hole in ([0, 1], [4, 5, 6, 7]):
        F = np.delete(BOX_FACES, hole, axis=0)
        Vc, Fc = ms.close_boundary_loops(BOX, F)
        assert not boundary_by_hand(Fc)
        assert volume_by_hand(Vc, Fc) == pytest.approx(0.06, abs=1e-15)


def test_a_closed_mesh_is_returned_as_it_is():
    V, F = ms.close_boundary_loops(BOX, BOX_FACES)
    assert V is BOX and np.array_equal(F, BOX_FACES)
    assert F.dtype == np.int64
    V, F = ms.close_boundary_loops(BOX, BOX_FACES.astype(np.int32))
    assert F.dtype == np.int64 and np.array_equal(F, BOX_FACES)
    Vc, Fc = ms.close_boundary_loops(BOX, BOX_FACES[2:].astype(np.int32))
    assert Fc.dtype == np.int64


def test_volume_and_mass_of_boxes_and_a_tetrahedron():
    assert ms.enclosed_volume(BOX, BOX_FACES) == pytest.approx(0.06, abs=1e-15)
    assert ms.enclosed_volume(BOX + [3.0, -2.0, 7.0], BOX_FACES) == pytest.approx(0.06, abs=1e-13)
    assert ms.enclosed_volume(BOX * 2, BOX_FACES) == pytest.approx(0.48, abs=1e-14)
    tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    T = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    assert ms.enclosed_volume(tet, T) == pytest.approx(1 / 6, abs=1e-15)
    assert type(ms.enclosed_volume(tet, T)) is float
    assert ms.body_mass(BOX, BOX_FACES) == pytest.approx(0.06 * 1010.0, abs=1e-12)
    assert ms.BODY_DENSITY_KG_M3 == 1010.0
    assert ms.body_mass(BOX, np.delete(BOX_FACES, [4, 5], axis=0), density_kg_m3=985.0) == \
        pytest.approx(0.06 * 985.0, abs=1e-12)


@pytest.mark.parametrize("h", [-0.2, 0.0, 0.37, 0.49])
def test_section_of_the_box_by_hand(h):
    curves = ms.horizontal_section_curves(BOX, BOX_FACES, h)
    want = section_by_hand(BOX, BOX_FACES, h)
    assert len(curves) == len(want) == 1
    got = np.array(sorted(map(tuple, np.round(curves[0], 12))))
    np.testing.assert_allclose(got, sorted(map(tuple, np.round(want[0], 12))), atol=1e-12)
    assert len(got) == 8  # 4 vertical edges and 4 face diagonals
    assert ms.torso_girth(BOX, BOX_FACES, h) == pytest.approx(1.0, abs=1e-12)


def test_a_vertex_on_the_plane_counts_as_above():
    top = ms.horizontal_section_curves(BOX, BOX_FACES, 0.5)  # the top vertices are on the plane: a cut there
    assert len(top) == 1 and len(top[0]) == 8
    np.testing.assert_allclose(sorted(map(tuple, np.round(top[0], 12)))[0], [0.0, 0.0], atol=1e-12)
    assert ms.torso_girth(BOX, BOX_FACES, 0.5) == pytest.approx(1.0, abs=1e-12)
    assert ms.horizontal_section_curves(BOX, BOX_FACES, -0.5) == []  # all vertices on or above: no cut
    assert ms.horizontal_section_curves(BOX, BOX_FACES, 0.51) == []
    assert np.isnan(ms.torso_girth(BOX, BOX_FACES, 0.7))


def test_sections_of_tubes_sloping_and_apart():
    ell = [[0, 0], [0.4, 0], [0.4, 0.1], [0.1, 0.1], [0.1, 0.3], [0, 0.3]]  # an L: its hull cuts the corner
    Va, Fa = prism(ell, 0.0, 0.7)
    wide = [[0, 0], [1.0, 0], [1.0, 0.08], [0, 0.08]]  # bounding box 0.08 m^2 (< the L's 0.12, > the L's wall)
    Vb, Fb = prism(wide, -0.2, 0.9, offset=(2.0, 0.0))
    Vb[len(wide):, 0] += 0.3  # the wide tube leans: its section moves with the height
    V, F = np.r_[Va, Vb], np.r_[Fa, Fb + len(Va)]
    for h in (0.25, 0.5, 0.65):
        curves = ms.horizontal_section_curves(V, F, h)
        want = section_by_hand(V, F, h)
        assert len(curves) == 2 == len(want)
        key = sorted(want, key=len)
        for c, w in zip(sorted(curves, key=len), key, strict=True):
            np.testing.assert_allclose(sorted(map(tuple, np.round(c, 12))), sorted(map(tuple, np.round(w, 12))),
                                       atol=1e-12)
        # the L's bounding box (0.4 x 0.3) is the larger: its hull, the corner cut off
        assert ms.torso_girth(V, F, h) == pytest.approx(0.4 + 0.1 + np.hypot(0.3, 0.2) + 0.1 + 0.3, abs=1e-12)
        assert ms.torso_girth(V, F, h) == pytest.approx(girth_by_hand(V, F, h), abs=1e-12)
    # above the L only the leaning tube is cut
    assert ms.torso_girth(V, F, 0.8) == pytest.approx(2 * (1.0 + 0.08), abs=1e-12)
    # a tetrahedron cut below its apex: a 3-point curve, the triangle's perimeter
    tet = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.0, 0.3], [0.0, 1.0, 0.0]])
    T = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    assert [len(c) for c in ms.horizontal_section_curves(tet, T, 0.5)] == [3]
    assert ms.torso_girth(tet, T, 0.5) == pytest.approx(0.5 * (0.4 + 0.3 + 0.5), abs=1e-12)
    # a single triangle gives a 2-point curve, dropped
    tri_V = np.array([[5.0, 0.0, 0.0], [5.1, 1.0, 0.0], [5.2, 0.0, 0.1]])
    assert len(ms.horizontal_section_curves(tri_V, np.array([[0, 1, 2]]), 0.5)[0]) == 2
    assert np.isnan(ms.torso_girth(tri_V, np.array([[0, 1, 2]]), 0.5))
    assert ms.torso_girth(np.r_[Va, tri_V], np.r_[Fa, [[12, 13, 14]]], 0.5) == \
        pytest.approx(girth_by_hand(Va, Fa, 0.5), abs=1e-12)


@cache
def body_2k():
    from bodystudio.body import Phenotype, build_body

    return build_body(Phenotype(gender=0.3, weight=0.7, height=0.6), resolution="2k")


def _flat(landmarks):
    return [landmarks.crotch, *landmarks.bust, *landmarks.acromion, *landmarks.elbow, *landmarks.wrist]


def _check_nearest(got, ids):
    """Each landmark is a kept vertex at the smallest distance (by brute force) from the full body's landmark on the
    default body (the crotch on the midline has mirror-image nearest vertices: either is right)."""
    from bodystudio.body.model import shaped_vertices

    V0 = shaped_vertices()
    kept = V0[np.asarray(ids)]
    for full_i, got_i in zip(_flat(ms.landmark_vertices()), _flat(got), strict=True):
        d = np.linalg.norm(kept - V0[full_i], axis=1)
        assert d[got_i] == pytest.approx(d.min(), abs=1e-12)


def test_template_landmarks_are_the_nearest_kept_vertices():
    body = body_2k()
    ms._TEMPLATE_LANDMARKS.clear()  # computed here, not left over from an earlier test in this process
    want = ms.landmark_vertices(body.vertex_ids)
    assert ms.landmark_vertices(body.vertex_ids) is want  # kept per template
    _check_nearest(want, body.vertex_ids)
    assert ms.landmark_vertices(list(body.vertex_ids)) == want  # any sequence of ids, cached by value
    assert ms.landmark_vertices(np.asarray(body.vertex_ids, np.int32)) == want
    assert ms.landmark_vertices(None) == ms.landmark_vertices()
    assert isinstance(want.bust, tuple) and all(type(i) is int for i in (want.crotch, *want.wrist))
    some = np.asarray(body.vertex_ids)[::2]
    _check_nearest(ms.landmark_vertices(some), some)
    assert ms.landmark_vertices(some) != want


def test_measure_attributes_of_the_2k_body_by_hand():
    body = body_2k()
    V, F = body.vertices, body.faces
    L = ms.landmark_vertices(body.vertex_ids)
    _check_nearest(L, body.vertex_ids)
    floor = V[:, 1].min()
    crotch, bust = V[L.crotch, 1], (V[L.bust[0], 1] + V[L.bust[1], 1]) / 2
    span = bust - crotch
    waist = min(girth_by_hand(V, F, crotch + span * (0.45 + 0.4 * i / 8)) for i in range(9))
    hip = max(girth_by_hand(V, F, crotch + span * (0.05 + 0.4 * i / 8)) for i in range(9))
    arm = np.mean([np.linalg.norm(V[L.acromion[s]] - V[L.elbow[s]]) + np.linalg.norm(V[L.elbow[s]] - V[L.wrist[s]])
                   for s in (0, 1)])
    Vc, Fc = ms.close_boundary_loops(V, F)
    assert not boundary_by_hand(Fc)
    want = {"stature_m": V[:, 1].max() - floor, "mass_kg": 1010.0 * volume_by_hand(Vc, Fc),
            "chest_m": girth_by_hand(V, F, bust), "waist_m": waist, "hip_m": hip, "arm_length_m": arm,
            "leg_length_m": crotch - floor}
    for kw in ({"vertex_ids": body.vertex_ids}, {"resolution": "2k"}, {}):
        got = ms.measure_attributes(V, F, **kw)
        assert list(got) == list(ms.ATTRIBUTE_NAMES)
        assert {k: got[k] for k in want} == pytest.approx(want, rel=1e-9), kw
        assert np.isnan(got["muscularity"]) and all(type(v) is float for v in got.values())
    assert waist < min(want["chest_m"], hip) and 40 < want["mass_kg"] < 120
    assert ms.measure_attributes(V.tolist(), F.tolist(), muscularity=0.25)["muscularity"] == 0.25
    # float32 vertices are measured in float64
    V32 = V.astype(np.float32)
    assert ms.measure_attributes(V32, F, muscularity=0.5) == \
        ms.measure_attributes(V32.astype(np.float64), F, muscularity=0.5)
    # the arm length is the mean of both sides: a left wrist moved 2 cm out
    V2 = V.copy()
    V2[L.wrist[0]] += [0.02, 0.0, 0.0]
    arms = [np.linalg.norm(V2[L.acromion[s]] - V2[L.elbow[s]]) + np.linalg.norm(V2[L.elbow[s]] - V2[L.wrist[s]])
            for s in (0, 1)]
    assert abs(arms[0] - arms[1]) > 1e-3
    assert ms.measure_attributes(V2, F)["arm_length_m"] == pytest.approx((arms[0] + arms[1]) / 2, rel=1e-12)
    m = ms.measure_body(body)
    assert {k: m[k] for k in want} == pytest.approx(want, rel=1e-9)
    assert m["muscularity"] == body.phenotype.muscle
    # the body's own vertex ids name the landmarks (a template's ids in another order: other landmark vertices)
    from types import SimpleNamespace

    shuffled = SimpleNamespace(vertices=V, faces=F, vertex_ids=np.asarray(body.vertex_ids)[::-1].copy(),
                               phenotype=body.phenotype)
    np.testing.assert_equal(ms.measure_body(shuffled), ms.measure_attributes(  # NaN girths: the bands are off
        V, F, vertex_ids=shuffled.vertex_ids, muscularity=body.phenotype.muscle))
    assert ms.measure_body(shuffled)["arm_length_m"] != pytest.approx(m["arm_length_m"], rel=1e-3)


def test_band_constants():
    assert ms.WAIST_BAND == (0.45, 0.85) and ms.HIP_BAND == (0.05, 0.45) and ms.N_BAND_LEVELS == 9
    assert ms.MESH_ATTRIBUTE_NAMES == ms.ATTRIBUTE_NAMES[:-1] and ms.ATTRIBUTE_NAMES[-1] == "muscularity"


def test_topology_refusals_word_for_word():
    body = body_2k()
    V, F = body.vertices, body.faces
    n = len(V)
    cases = [
        (lambda: ms.measure_attributes(V[:, :2], F), f"expected (n, 3) vertices and (m, 3) triangles, got ({n}, 2) "
                                                      f"and {F.shape}"),
        (lambda: ms.measure_attributes(V, F[:, :2]), f"expected (n, 3) vertices and (m, 3) triangles, got ({n}, 3) "
                                                      f"and ({len(F)}, 2)"),
        (lambda: ms.measure_attributes(V[None], F), f"expected (n, 3) vertices and (m, 3) triangles, got (1, {n}, 3) "
                                                     f"and {F.shape}"),
        (lambda: ms.measure_attributes(V, F[None]), "expected (n, 3) vertices and (m, 3) triangles"),
        (lambda: ms.measure_attributes(V, F, vertex_ids=body.vertex_ids[:-1]),
         f"mesh has {n} vertices but the template's vertex_ids name {n - 1}"),
        (lambda: ms.measure_attributes(V, F, resolution="6k"), f"mesh has {n} vertices but the 6k template has 6002"),
        (lambda: ms.measure_attributes(V, F, resolution="full"),
         f"mesh has {n} vertices but the full template has 13380"),
        (lambda: ms.measure_attributes(V[:-1], F[F.max(1) < n - 1]),
         f"mesh has {n - 1} vertices; not in bodystudio's body topology, which has 13380 (full), 6002 (6k), {n} (2k)"),
    ]
    for call, message in cases:
        with pytest.raises(InputError) as exc:
            call()
        assert str(exc.value).startswith(message), str(exc.value)
        if message.endswith(")") or message[-1].isdigit():
            assert str(exc.value) == message
