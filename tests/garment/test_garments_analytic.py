"""Analytic checks of garment/garments.py's mesh, skinning and texture helpers on tiny meshes with exact answers.

Written for mutation testing (issue 17; tests/garment/test_garments.py dresses a 2k body per session, seconds
per mutant). No body model: a roof of two triangles for the welded normals, single triangles for the hem cut,
a unit cube for the clearance push, a two-bone skeleton, a 2 x 2 texture for the bilinear lookup, UVs in
[0, 1] for the baked texture, a chain for the weight diffusion.
"""

import re
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import InputError
from bodystudio.garment import garments as gm


def exact(message):
    return "^" + re.escape(str(message)) + "$"


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ------------------------------------------------------------------------------------------ normals


def test_welded_normals_are_shared_across_a_uv_seam():
    """A roof: two unit right triangles meeting at 90 degrees along the x axis. Split at the ridge (each face its
    own copies), unwelded copies keep their face's normal; welded, the ridge copies share the mean."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1], [0, 0, 0], [1, 0, 0], [0, -1, 1.0]])
    F = np.array([[0, 1, 2], [3, 5, 4]])
    apart = gm.welded_normals(V, F, np.arange(6))
    n1, n2 = unit([0, -1, 1]), unit([0, 1, 1])
    assert np.abs(apart[[0, 1, 2]] - n1).max() < 1e-12 and np.abs(apart[[3, 4, 5]] - n2).max() < 1e-12
    weld = np.array([0, 1, 2, 0, 1, 3])
    joined = gm.welded_normals(V, F, weld)
    assert np.abs(joined[[0, 1, 3, 4]] - [0, 0, 1]).max() < 1e-12  # the ridge: (n1 + n2) / |n1 + n2|
    assert np.abs(joined[2] - n1).max() < 1e-12 and np.abs(joined[5] - n2).max() < 1e-12
    g = gm.Garment("roof", V, F, np.zeros((6, 2)), np.zeros((2, 2, 3), np.uint8), np.ones((6, 1)), weld)
    assert g.n_vertices == 6 and np.array_equal(g.normals(), joined)
    turned = V @ Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix().T
    assert np.abs(g.normals(turned)[0] - [0, 0, 1]).max() < 1e-12
    assert np.abs(g.normals(turned)[2] - unit([1, 0, 1])).max() < 1e-12


# ------------------------------------------------------------------------------------------ the hem cut


def test_cut_keeps_negative_field_and_splits_one_inside_and_two_inside_triangles_exactly():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    field = np.array([-1.0, 1.0, 3.0, 2.0])  # only vertex 0 inside; crossings at 1/2 of 0-1, 1/4 of 0-2
    Vc, Fc, M = gm.cut_mesh_at_isoline(V, F, field)
    assert np.abs(Vc - [[0, 0, 0], [0.5, 0, 0], [0, 0.25, 0]]).max() < 1e-15
    assert Fc.tolist() == [[0, 1, 2]] and M.shape == (3, 4)
    assert np.allclose(M.toarray(), [[1, 0, 0, 0], [0.5, 0.5, 0, 0], [0.75, 0, 0.25, 0]])
    # two inside (0 and 2): the quad (b, c, ca, ab) in two triangles, same winding (+z)
    field = np.array([-1.0, 3.0, -1.0, 5.0])
    Vc, Fc, M = gm.cut_mesh_at_isoline(V, F, field)
    area = 0.5 * np.abs(np.cross(Vc[Fc[:, 1]] - Vc[Fc[:, 0]], Vc[Fc[:, 2]] - Vc[Fc[:, 0]])[:, 2]).sum()
    # face 0 less its corner at vertex 1 (3/4 of both edges), and face 1's corner at vertex 2 (1/4 and 1/6 of its edges)
    assert area == pytest.approx(0.5 - 0.5 * 0.75 * 0.75 + 0.5 * 0.25 / 6, abs=1e-15)
    n_z = np.cross(Vc[Fc[:, 1]] - Vc[Fc[:, 0]], Vc[Fc[:, 2]] - Vc[Fc[:, 0]])[:, 2]
    assert np.all(n_z > 0) and len(Fc) == 3  # face 1 has vertex 2 inside only: one more small triangle
    assert np.allclose(M @ field, np.r_[-1, -1, np.zeros(len(Vc) - 2)])  # new vertices on the zero level
    # the crossing on edge 1-2 is shared by both faces: one vertex, not two
    assert len(Vc) == 2 + 3


def test_cut_treats_zero_as_outside_and_drops_or_keeps_whole_meshes():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    F = np.array([[0, 1, 2]])
    Vc, Fc, M = gm.cut_mesh_at_isoline(V, F, np.array([-1.0, -1.0, -1.0]))
    assert np.array_equal(Vc, V) and np.array_equal(Fc, F) and np.allclose(M.toarray(), np.eye(3))
    Vc, Fc, M = gm.cut_mesh_at_isoline(V, F, np.array([0.0, 1.0, 2.0]))
    assert Vc.shape == (0, 3) and Fc.shape == (0, 3) and M.shape == (0, 3)
    Vc, Fc, _ = gm.cut_mesh_at_isoline(V, F, np.array([-2.0, 0.0, 0.0]))  # zero: on the line, not inside
    assert np.abs(Vc - V).max() < 1e-15 and Fc.tolist() == [[0, 1, 2]]


def test_largest_component_keeps_the_biggest_face_set_reindexed():
    small = np.array([[0, 1, 2]])
    big = np.array([[3, 4, 5], [3, 5, 6], [5, 6, 7]])
    F = np.vstack([small, big])
    ids, Fk = gm.largest_component(F, 9)  # vertex 8 unused
    assert ids.tolist() == [3, 4, 5, 6, 7] and Fk.tolist() == [[0, 1, 2], [0, 2, 3], [2, 3, 4]]
    ids, Fk = gm.largest_component(F[::-1], 9)
    assert ids.tolist() == [3, 4, 5, 6, 7] and len(Fk) == 3
    chain = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7]])  # joined through vertex 2 only
    assert gm.largest_component(chain, 8)[0].tolist() == [0, 1, 2, 3, 4]


# ------------------------------------------------------------------------------------------ skinning


def test_skin_weights_are_the_barycentric_blend_at_the_nearest_skin_point():
    body_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    body_F = np.array([[0, 1, 2]])
    W = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    P = np.array([[0.2, 0.3, 0.05], [0.5, -0.4, -0.1], [2.0, 2.0, 0.0]])
    got = gm.transfer_skin_weights(P, body_V, body_F, W * 2.0)  # unnormalised input rows: normalised output
    # point 0 projects to (0.2, 0.3): barycentrics (0.5, 0.2, 0.3); point 1 to (0.5, 0) on edge 0-1;
    # point 2 to the hypotenuse's midpoint
    assert np.abs(got - [[0.5, 0.2, 0.3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5]]).max() < 1e-12
    assert np.allclose(got.sum(1), 1.0)


def test_points_inside_or_near_the_skin_are_pushed_out_by_the_clearance():
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    P = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, 0.502], [0.0, 0.0, 0.6], [0.4, 0.0, 0.0]])
    out = gm.push_outside_body(P, V, F)
    assert np.abs(out[0] - [0, 0, 0.504]).max() < 1e-12  # inside: to the nearest face + 4 mm
    assert np.abs(out[1] - [0, 0, 0.504]).max() < 1e-12  # 2 mm outside, within the clearance
    assert np.array_equal(out[2], P[2])  # far enough outside: untouched
    assert np.abs(out[3] - [0.504, 0, 0]).max() < 1e-12
    assert gm.MIN_CLEARANCE_M == 0.004
    wide = gm.push_outside_body(P, V, F, clearance_m=0.05)
    assert np.abs(wide[:2] - [0, 0, 0.55]).max() < 1e-12 and np.array_equal(wide[2], P[2])
    assert np.array_equal(P[0], [0.0, 0.0, 0.3])  # the input is not moved in place


def two_bones():
    return Skeleton(("root", "arm"), np.array([-1, 0]), np.array([[0, 0, 0], [0, 1, 0.0]]),
                    np.array([[0, 1, 0], [1, 1, 0.0]]), np.zeros(2))


def test_pose_garment_is_lbs_with_the_garment_weights():
    sk = two_bones()
    body = SimpleNamespace(skeleton=sk)
    V = np.array([[0, 0.5, 0], [0.5, 1, 0], [1.0, 1, 0]])
    W = np.array([[1.0, 0], [0.5, 0.5], [0, 1.0]])
    g = gm.Garment("g", V, np.array([[0, 1, 2]]), np.zeros((3, 2)), np.zeros((2, 2, 3), np.uint8), W, np.arange(3))
    assert np.abs(gm.pose_garment(g, body, Pose(np.zeros((2, 3)), np.zeros(3))) - V).max() < 1e-12
    moved = gm.pose_garment(g, body, Pose(np.zeros((2, 3)), np.array([0.1, 0.2, 0.3])))
    assert np.abs(moved - V - [0.1, 0.2, 0.3]).max() < 1e-12
    from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms

    pose = Pose(np.array([[0, 0, 0], [0, 0, np.pi / 2]]), np.zeros(3))  # the arm bent up about its head
    got = gm.pose_garment(g, body, pose)
    assert np.abs(got - linear_blend_skinning(V, W, skinning_transforms(sk, pose))).max() < 1e-12
    # the arm's tip turns a quarter circle about the arm's head; the root's vertex stays
    assert np.linalg.norm(got[2] - [0, 1, 0]) == pytest.approx(1.0, abs=1e-12)
    assert (got[2] - [0, 1, 0]) @ [1, 0, 0] == pytest.approx(0.0, abs=1e-12)
    assert np.abs(got[0] - V[0]).max() < 1e-12
    bad = gm.Garment("shirt", V, g.faces, g.uv, g.texture, np.ones((3, 3)) / 3, g.weld)
    with pytest.raises(InputError, match=exact("garment 'shirt' is skinned to 3 bones but the body has 2; dress this "
                                               "body again")):
        gm.pose_garment(bad, body, pose)


def test_smooth_skin_weights_is_half_a_uniform_laplacian_step_per_iteration_on_the_welded_mesh():
    """A strip of two triangles 0-1-2, 1-3-2; vertex 4 a seam copy of vertex 3."""
    F = np.array([[0, 1, 2], [1, 4, 2]])
    weld = np.array([0, 1, 2, 3, 3])
    W = np.array([[1.0, 0], [1.0, 0], [0, 1.0], [0, 2.0], [0, 2.0]])
    assert np.abs(gm.smooth_skin_weights(W, F, weld, 0) - W / W.sum(1, keepdims=True)).max() < 1e-15
    one = gm.smooth_skin_weights(W, F, weld, 1)
    Ww = np.array([[1.0, 0], [1.0, 0], [0, 1.0], [0, 2.0]])
    nbrs = {0: [1, 2], 1: [0, 2, 3], 2: [0, 1, 3], 3: [1, 2]}
    step = np.array([0.5 * Ww[i] + 0.5 * Ww[nbrs[i]].mean(0) for i in range(4)])
    want = step[weld] / step[weld].sum(1, keepdims=True)
    assert np.abs(one - want).max() < 1e-15 and np.array_equal(one[3], one[4])
    two = gm.smooth_skin_weights(W, F, weld, 2)
    step2 = np.array([0.5 * step[i] + 0.5 * step[nbrs[i]].mean(0) for i in range(4)])
    assert np.abs(two - step2[weld] / step2[weld].sum(1, keepdims=True)).max() < 1e-15
    assert np.abs(gm.smooth_skin_weights(W, F, weld, 2.0) - two).max() == 0  # a float count is truncated


def test_weld_positions_join_vertices_equal_to_seven_decimals():
    V = np.array([[0, 0, 0], [1, 0, 0], [1e-9, 0, 0], [1, 2e-8, 0], [0, 0, 1e-6]])
    weld = gm._weld_positions(V)
    assert weld.dtype == np.int64 and weld.shape == (5,)
    assert weld[0] == weld[2] and weld[1] == weld[3] and len(set(weld)) == 3


# ------------------------------------------------------------------------------------------ UVs


def test_split_uv_seams_makes_one_vertex_per_position_and_uv_pair():
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv_faces = np.array([[0, 1, 2], [4, 2, 3]])  # vertex 0 has uv 0 in face 0 and uv 4 in face 1
    tex = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]])
    vid, F2, uv = gm.split_uv_seams(faces, uv_faces, tex)
    assert vid.tolist() == [0, 0, 1, 2, 3]  # (0, 0), (0, 4), (1, 1), (2, 2), (3, 3) sorted
    assert F2.tolist() == [[0, 2, 3], [1, 3, 4]]
    assert np.array_equal(uv, tex[[0, 4, 1, 2, 3]])


def test_normalized_uv_fills_0_01_to_0_99_keeping_the_aspect():
    uv = np.array([[2.0, 1.0], [6.0, 1.0], [2.0, 3.0]])
    got = gm.normalized_uv(uv)
    assert np.abs(got - [[0.01, 0.01], [0.99, 0.01], [0.01, 0.5]]).max() < 1e-15
    assert np.array_equal(gm.normalized_uv(np.ones((3, 2))), np.full((3, 2), 0.01))  # degenerate: no NaN


def square_uv(lo, hi):
    return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


def test_uv_overlap_fraction_of_separate_stacked_and_half_covered_charts():
    F = np.array([[0, 1, 2], [0, 2, 3]])
    two = np.vstack([square_uv((0.0, 0.0), (0.5, 0.5)), square_uv((0.5, 0.5), (1.0, 1.0))])
    F2 = np.vstack([F, F + 4])
    assert gm.uv_overlap_fraction(two, F2, size=64) < 0.01
    stacked = np.vstack([square_uv((0.25, 0.25), (0.75, 0.75))] * 2)
    assert gm.uv_overlap_fraction(stacked, F2, size=64) == pytest.approx(0.5, abs=0.01)
    shifted = np.vstack([square_uv((0.0, 0.0), (0.5, 0.5)), square_uv((0.25, 0.0), (0.75, 0.5))])
    assert gm.uv_overlap_fraction(shifted, F2, size=64) == pytest.approx(0.25, abs=0.01)


def test_uv_texel_positions_put_each_texel_centre_on_the_surface():
    V = np.array([[0, 0, 0], [2.0, 0, 0], [2.0, 1.0, 0], [0, 1.0, 0]])  # uv (0, 0) -> (0, 0, 0), (1, 1) -> (2, 1)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    mask, P = gm.uv_texel_positions(V, F, square_uv((0, 0), (1, 1)), 8)
    assert mask.all() and P.shape == (8, 8, 3)
    rows, cols = np.mgrid[0:8, 0:8]
    assert np.abs(P[..., 0] - 2.0 * (cols + 0.5) / 8).max() < 1e-5  # u = (col + 1/2) / S
    assert np.abs(P[..., 1] - (1.0 - (rows + 0.5) / 8)).max() < 1e-5  # v = 1 - (row + 1/2) / S: row 0 on top
    half, _ = gm.uv_texel_positions(V, F, square_uv((0, 0), (0.5, 1.0)), 8)
    assert half[:, :4].all() and not half[:, 4:].any()


# ------------------------------------------------------------------------------------------ cloth


def test_cloth_patterns_on_known_points():
    colors = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    y = np.array([0.01, 0.04, 0.07, -0.01])  # stripes of 3 cm: bands 0, 1, 0 (0.06-0.09), -1 -> odd
    P = np.column_stack([np.zeros(4), y, np.ones(4)])  # arc 0
    assert np.array_equal(gm.cloth_pattern(P, "stripes", colors), colors[[0, 1, 0, 1]])
    assert np.array_equal(gm.cloth_pattern(P, "plain", colors), colors[[0, 0, 0, 0]])
    # checks: squares of 6 cm over height and arc 0.15 atan2(x, z)
    a = np.array([0.01, 0.07, 0.01, 0.07]) / 0.15
    Q = np.column_stack([np.sin(a), [0.01, 0.01, 0.07, 0.07], np.cos(a)])
    assert np.array_equal(gm.cloth_pattern(Q, "checks", colors), colors[[0, 1, 1, 0]])
    # print: dots of radius 0.25 cells (9 cm cells) at cell centres, rows offset by half a cell
    cell = 0.09
    R = np.column_stack([np.zeros(3), [0.5 * cell, 0.5 * cell + 0.2 * cell, 0.5 * cell + 0.3 * cell], np.ones(3)])
    # arc 0: dx = (0 + 0.5 * row) % 1 - 0.5 = -0.5 in row 0: far from the dot centre
    assert np.array_equal(gm.cloth_pattern(R, "print", colors), colors[[0, 0, 0]])
    S = np.column_stack([np.sin([0.5 * cell / 0.15] * 3), R[:, 1], np.cos([0.5 * cell / 0.15] * 3)])
    assert np.array_equal(gm.cloth_pattern(S, "print", colors), colors[[1, 1, 0]])  # 0, 0.2 inside; 0.3 not
    wide = gm.cloth_pattern(P, "stripes", colors, period_m=0.2)  # bands of 10 cm: all in band 0 but -0.01
    assert np.array_equal(wide, colors[[0, 0, 0, 1]])
    with pytest.raises(InputError, match=exact("unknown cloth pattern 'dots'; valid: stripes, checks, print, plain")):
        gm.cloth_pattern(P, "dots", colors)


def test_cloth_colors_are_three_hsv_colours_0_37_apart_in_hue():
    import colorsys

    c = gm.cloth_colors(3)
    hue = np.random.default_rng(3).uniform(0, 1)
    for k, (s, v) in enumerate(((0.7, 0.75), (0.15, 0.95), (0.8, 0.35))):
        assert np.abs(c[k] - colorsys.hsv_to_rgb((hue + 0.37 * k) % 1.0, s, v)).max() < 1e-15
    assert c.shape == (3, 3) and not np.array_equal(c, gm.cloth_colors(4))
    assert np.array_equal(gm._hsv_to_rgb(0.0, 1.0, 1.0), [1.0, 0.0, 0.0])


def test_sample_texture_is_bilinear_with_v_up_and_replicated_borders():
    tex = np.array([[[0, 0, 0], [100, 0, 0]], [[0, 200, 0], [100, 200, 50]]], np.uint8)  # row 0 is v = 1
    uv = np.array([[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.75, 0.25], [0.5, 0.5], [0.0, 1.0], [1.0, 0.0],
                   [0.5, 0.75]])
    got = gm.sample_texture(tex, uv)
    want = np.array([[0, 0, 0], [100, 0, 0], [0, 200, 0], [100, 200, 50], [50, 100, 12.5], [0, 0, 0],
                     [100, 200, 50], [50, 0, 0]]) / 255.0
    assert np.abs(got - want).max() < 1.0 / 255  # OpenCV's bilinear weights are fixed point (1/32 steps)
    assert np.abs(got[:4] - want[:4]).max() == 0


def test_bake_plain_texture_is_one_colour_even_off_the_charts():
    V = np.array([[0, 0, 0], [1.0, 0, 0], [1.0, 1.0, 0], [0, 1.0, 0]])
    F = np.array([[0, 1, 2]])  # half the UV square: the other half is filled from the nearest chart texel
    tex = gm.bake_procedural_texture(V, F, square_uv((0, 0), (1, 1)), "plain", size=16, seed=2)
    want = np.round(gm.cloth_colors(2)[0] * 255)
    assert tex.shape == (16, 16, 3) and tex.dtype == np.uint8 and np.all(tex == want)


def test_bake_stripes_follow_the_surface_height_and_fill_from_the_nearest_texel():
    V = np.array([[0, 0, 0], [0.12, 0, 0], [0.12, 0.12, 0], [0, 0.12, 0.0]])  # 12 cm: four 3 cm stripes
    F = np.array([[0, 1, 2], [0, 2, 3]])
    tex = gm.bake_procedural_texture(V, F, square_uv((0, 0), (1, 1)), "stripes", size=16, seed=0)
    base, second = (np.round(c * 255) for c in gm.cloth_colors(0)[:2])
    for row in range(16):
        y = 0.12 * (1 - (row + 0.5) / 16)
        want = second if int(np.floor(y / 0.03)) % 2 else base
        assert np.all(tex[row] == want), row
    half = gm.bake_procedural_texture(V, F, square_uv((0, 0), (0.5, 1.0)), "stripes", size=16, seed=0)
    assert np.array_equal(half[:, 8:], np.repeat(half[:, 7:8], 8, axis=1))  # filled from the chart's edge


def test_bake_refusals():
    V = np.array([[0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    F = np.array([[0, 1, 2]])
    uv = V[:, :2]
    with pytest.raises(InputError, match=exact("unknown cloth pattern 'dots'; valid: stripes, checks, print, plain")):
        gm.bake_procedural_texture(V, F, uv, "dots")
    for size in (15, 4097):
        with pytest.raises(InputError, match=exact(f"texture size {size} must lie in [16, 4096] texels")):
            gm.bake_procedural_texture(V, F, uv, "plain", size=size)
    assert gm.bake_procedural_texture(V, F, uv, "plain", size=16).shape == (16, 16, 3)
    with pytest.raises(InputError, match=exact("the garment's UV layout covers no texel; its texture coordinates "
                                               "are degenerate")):
        gm.bake_procedural_texture(V, F, np.zeros((3, 2)), "plain", size=16)


def test_material_image_reads_rgb_of_two_texels_or_more():
    from PIL import Image

    rgba = Image.fromarray(np.full((3, 4, 4), 9, np.uint8), "RGBA")
    got = gm._material_image(SimpleNamespace(material=SimpleNamespace(image=rgba)))
    assert got.shape == (3, 4, 3) and got.dtype == np.uint8 and np.all(got == 9)
    two = np.zeros((2, 2, 3), np.uint8)
    two[1, 1, 2] = 1  # two colours: a texture (one colour on 2 x 2 is trimesh's stand-in for no image)
    base = SimpleNamespace(image=None, baseColorTexture=Image.fromarray(two))
    assert np.array_equal(gm._material_image(SimpleNamespace(material=base)), two)
    assert gm._material_image(SimpleNamespace(material=SimpleNamespace(image=Image.new("RGB", (1, 5))))) is None
    assert gm._material_image(SimpleNamespace()) is None
    assert gm._material_image(SimpleNamespace(material=SimpleNamespace())) is None


# ------------------------------------------------------------------------------------------ survivors of the first run


def test_print_dots_sit_at_half_cell_offsets_row_by_row():
    """Dot centres: row r at height (r + 1/2) cell, arc (m + 1/2 - r/2) cell; radius a quarter cell."""
    cell = 0.09
    colors = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    pts = [  # (arc / cell, y / cell, on a dot)
        (0.5, 0.5, True), (0.0, 1.5, True), (1.0, 1.5, True), (0.5, 1.5, False), (1.0, -0.5, True),
        (1.2, -0.5, True), (1.3, -0.5, False), (-1.0, 3.5, True), (-0.5, 3.5, False), (0.0, 2.5, False),
        (0.5, 2.5, True), (0.0, 1.7, True), (0.0, 1.8, False),
    ]
    a = np.array([p[0] for p in pts]) * cell / 0.15  # arc = 0.15 atan2(x, z)
    P = np.column_stack([np.sin(a), np.array([p[1] for p in pts]) * cell, np.cos(a)])
    got = gm.cloth_pattern(P, "print", colors)
    assert np.array_equal(got, colors[[1 if p[2] else 0 for p in pts]])


def test_normalized_uv_of_a_layout_smaller_than_one():
    uv = np.array([[0.2, 0.1], [0.45, 0.1], [0.2, 0.6]])  # 0.25 x 0.5
    assert np.abs(gm.normalized_uv(uv) - [[0.01, 0.01], [0.5, 0.01], [0.01, 0.99]]).max() < 1e-15


def test_uv_overlap_of_slanted_triangles_and_other_areas():
    """A single slanted triangle covers its own area (no overlap); two copies of it overlap by half; the
    areas are the cross products of two edges from one corner (not a sum of products)."""
    tri = np.array([[0.1, 0.1], [0.9, 0.3], [0.4, 0.9]])
    F = np.array([[0, 1, 2]])
    assert gm.uv_overlap_fraction(tri, F, size=128) < 0.02
    two = np.vstack([tri, tri])
    assert gm.uv_overlap_fraction(two, np.array([[0, 1, 2], [3, 4, 5]]), size=128) == pytest.approx(0.5, abs=0.02)
    small = np.array([[0.0, 0.0], [0.25, 0.0], [0.0, 0.25], [0.25, 0.25]])
    assert gm.uv_overlap_fraction(small, np.array([[0, 1, 2], [1, 3, 2]]), size=128) < 0.02


def test_skin_weights_of_points_over_vertices_with_different_weight_sums():
    """Four points (not three: a per-column division would not even broadcast), body weights whose rows sum to
    1, 2 and 4: each transferred row is the barycentric blend of the body rows, renormalised."""
    body_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    body_F = np.array([[0, 1, 2]])
    W = np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 4.0]])
    P = np.array([[0.2, 0.3, 0.05], [0.5, -0.4, -0.1], [2.0, 2.0, 0.0], [0.0, 0.0, 1.0]])
    got = gm.transfer_skin_weights(P, body_V, body_F, W)
    bary = np.array([[0.5, 0.2, 0.3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [1.0, 0.0, 0.0]])
    want = bary * [1.0, 2.0, 4.0]
    want /= want.sum(1, keepdims=True)
    assert np.abs(got - want).max() < 1e-12


def test_bake_defaults_are_stripes_and_seed_zero():
    V = np.array([[0, 0, 0], [0.12, 0, 0], [0.12, 0.12, 0], [0, 0.12, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = square_uv((0, 0), (1, 1))
    assert np.array_equal(gm.bake_procedural_texture(V, F, uv, size=16),
                          gm.bake_procedural_texture(V, F, uv, "stripes", size=16, seed=0))
    assert not np.array_equal(gm.bake_procedural_texture(V, F, uv, size=16),
                              gm.bake_procedural_texture(V, F, uv, "stripes", size=16, seed=1))


def test_material_image_of_trimeshs_stand_in_is_none():
    """trimesh gives a mesh with texture coordinates and no image (an OBJ without .mtl, its own exports) a 2 x 2
    image of one colour; that is no texture of the file's own (the procedural pattern is baked instead)."""
    import trimesh

    visual = trimesh.visual.TextureVisuals(uv=np.zeros((3, 2)))
    assert np.asarray(visual.material.image).shape[:2] == (2, 2)
    assert gm._material_image(visual) is None


def test_sample_texture_of_no_points_is_empty():
    out = gm.sample_texture(np.zeros((4, 4, 3), np.uint8), np.zeros((0, 2)))
    assert out.shape == (0, 3) and out.dtype == np.float64
