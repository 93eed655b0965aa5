"""The garment builders that need the MakeHuman body (issue 17: the functions of ``garments.py`` no fast test reached).

One 2k body per test module (``functools.cache``: built once per process, before mutmut forks its mutant
children), and the function under test called inside each test on those cached inputs, so every test is
credited with its own calls (docs/MUTATION.md's blind spot note). Exact expectations where the maths has
one: hem lines at the stated heights (on a skeleton with hand-placed joints, so left/right and head/tail
mix-ups change the numbers), the arm chain's arc length, the shell offset by the stated distance, weights
that are the body's interpolated ones, a loaded mesh equal to the written one.
"""

import dataclasses
import functools

import igl
import numpy as np
import pytest

from bodystudio.body import build_body
from bodystudio.body.phenotype import Phenotype
from bodystudio.errors import AssetError, FileFormatError, InputError
from bodystudio.garment import garments as gm

SHAPE = Phenotype(gender=0.8, height=0.7, weight=0.3)
LOCAL = {"upperarm-fat-decr-incr": 0.6, "hip-scale-horiz-decr-incr": 0.5}  # the hips move the skirt


@functools.cache
def _body():
    return build_body(resolution="2k")


@functools.cache
def _shaped(rig):
    return build_body(SHAPE, LOCAL, resolution="2k", rig=rig)


@functools.cache
def _proxy(name):
    V, F, uv, weld, W = gm.proxy_garment_mesh(_body(), name)
    return V, F, uv, weld, W


@functools.cache
def _shirt_shell(sleeve):
    return gm.shirt_garment_mesh(_body(), sleeve)


def _with_joints(body, **joints):
    """``body`` with some bone heads (``name=(x, y, z)``) or tails (``name_tail=...``) moved."""
    sk = body.skeleton
    heads, tails = sk.heads.copy(), sk.tails.copy()
    for key, value in joints.items():
        if key.endswith("_tail"):
            tails[sk.index(key[:-5])] = value
        else:
            heads[sk.index(key)] = value
    return dataclasses.replace(body, skeleton=dataclasses.replace(sk, heads=heads, tails=tails))


# --- hem_reference ------------------------------------------------------------------------------

def test_hem_reference_of_a_game_engine_body_is_the_body_itself():
    body = _body()
    assert gm.hem_reference(body) is body


def test_hem_reference_of_another_rig_is_the_same_shape_on_the_game_engine_rig():
    body = _shaped("cmu_mb")
    ref = gm.hem_reference(body)
    truth = _shaped("game_engine")
    assert ref.rig == "game_engine" and ref.resolution == "2k"
    assert ref.phenotype == SHAPE and ref.local == LOCAL
    # same (shaped) vertices as the body: the shape and the local modifier both reached build_body
    assert np.array_equal(ref.vertices, body.vertices)
    assert np.array_equal(ref.skeleton.heads, truth.skeleton.heads)
    assert ref.skeleton.bone_names == truth.skeleton.bone_names


# --- leggings_field -----------------------------------------------------------------------------

def test_leggings_field_is_the_distance_beyond_the_nearer_hem():
    # hand-placed, asymmetric joints: waist hem at mean(0.90, 0.84) + 0.06 = 0.93, ankle hem at
    # mean(0.10, 0.04) + 0.06 = 0.13
    body = _with_joints(_body(), thigh_l=(0.1, 0.90, 0.0), thigh_r=(-0.1, 0.84, 0.0),
                        foot_l=(0.1, 0.10, 0.0), foot_r=(-0.1, 0.04, 0.0))
    y = np.array([0.0, 0.10, 0.13, 0.50, 0.90, 0.93, 1.20])
    V = np.column_stack([np.full_like(y, 0.3), y, np.full_like(y, -0.2)])
    want = [0.13, 0.03, 0.0, -0.37, -0.03, 0.0, 0.27]
    assert gm.leggings_field(V, body) == pytest.approx(want, abs=1e-12)


def test_leggings_field_of_another_rig_uses_the_game_engine_bones():
    V = _shaped("game_engine").vertices
    got = gm.leggings_field(V, _shaped("cmu_mb"))
    assert np.array_equal(got, gm.leggings_field(V, _shaped("game_engine")))
    sk = _shaped("game_engine").skeleton
    waist = 0.5 * (sk.heads[sk.index("thigh_l"), 1] + sk.heads[sk.index("thigh_r"), 1]) + 0.06
    assert got[V[:, 1] > waist] == pytest.approx(V[V[:, 1] > waist, 1] - waist, abs=1e-12)


# --- arm_coordinate -----------------------------------------------------------------------------

def _l_arm_body():
    """Left arm: shoulder (0.2, 1.4, 0) -> elbow 0.3 m along +x -> wrist 0.25 m down; right arm: 0.25 m along
    -x, then 0.3 m down."""
    return _with_joints(_body(), upperarm_l=(0.2, 1.4, 0.0), upperarm_l_tail=(0.5, 1.4, 0.0),
                        lowerarm_l=(0.5, 1.4, 0.0), lowerarm_l_tail=(0.5, 1.15, 0.0),
                        upperarm_r=(-0.2, 1.4, 0.0), upperarm_r_tail=(-0.45, 1.4, 0.0),
                        lowerarm_r=(-0.45, 1.4, 0.0), lowerarm_r_tail=(-0.45, 1.1, 0.0))


def test_arm_coordinate_is_the_arc_length_of_the_closest_chain_point():
    body = _l_arm_body()
    pts = np.array([
        [0.20, 1.40, 0.00],  # shoulder: 0
        [0.35, 1.42, 0.00],  # over the upper arm's middle: 0.15
        [0.50, 1.40, 0.00],  # elbow: 0.3
        [0.52, 1.30, 0.00],  # beside the forearm: 0.3 + 0.1
        [0.50, 1.15, 0.00],  # wrist: 0.55
        [0.55, 1.00, 0.00],  # past the wrist: clipped to 0.55
        [0.15, 1.41, 0.00],  # before the shoulder: the upper arm is not clipped there, -0.05
        [0.48, 1.50, 0.00],  # behind the elbow on the forearm's line: the upper arm is nearer, 0.28
        [0.35, 1.40, 0.07],  # off the plane: 0.15
    ])
    want = [0.0, 0.15, 0.3, 0.4, 0.55, 0.55, -0.05, 0.28, 0.15]
    assert gm.arm_coordinate(pts, body, "l") == pytest.approx(want, abs=1e-12)
    right = pts * [-1, 1, 1]
    # right arm 0.25 then 0.3: the same points mirrored
    want_r = [0.0, 0.15, 0.25, 0.25 + 0.12, 0.25 + 0.27, 0.55, -0.05, 0.25, 0.15]
    got_r = gm.arm_coordinate(right + [[0, 0, 0]] * 9, body, "r")
    assert got_r[[0, 1, 6, 8]] == pytest.approx([want_r[i] for i in (0, 1, 6, 8)], abs=1e-12)
    # the right forearm starts at x = -0.45: (-0.47, 1.28) lies 0.12 down it, (-0.45, 1.0) 0.3 (its end)
    assert gm.arm_coordinate(np.array([[-0.47, 1.28, 0.0], [-0.45, 1.0, 0.0], [-0.45, 1.40, 0.0]]), body, "r") \
        == pytest.approx([0.37, 0.55, 0.25], abs=1e-12)


def test_arm_coordinate_on_the_real_body_runs_from_the_shoulder_to_the_wrist():
    body = _body()
    sk = body.skeleton
    for side in ("l", "r"):
        up, low = sk.index(f"upperarm_{side}"), sk.index(f"lowerarm_{side}")
        L1, L2 = sk.lengths[up], sk.lengths[low]
        pts = np.array([sk.heads[up], sk.heads[low], sk.tails[low], 0.5 * (sk.heads[low] + sk.tails[low])])
        assert gm.arm_coordinate(pts, body, side) == pytest.approx([0.0, L1, L1 + L2, L1 + 0.5 * L2], abs=1e-9)


# --- shirt_region_field ---------------------------------------------------------------------------

def _shirt_case():
    """A body with hand-placed joints and eight hand-placed vertices (the field is per body vertex).

    Hips at y 0.90 / 0.92 (waist hem 0.97), neck at (0, 1.5, 0) (neckline 1.485 at the back, 1.435 at the
    front), the arms of :func:`_l_arm_body` (left 0.3 + 0.25 m, right 0.25 + 0.3 m)."""
    base = _l_arm_body()
    base = _with_joints(base, thigh_l=(0.1, 0.90, 0.0), thigh_r=(-0.1, 0.92, 0.0), neck_01=(0.0, 1.5, 0.0))
    sk = base.skeleton
    V = np.array([
        [0.0, 1.00, 0.00],  # 0 torso: waist -0.03
        [0.0, 0.95, 0.00],  # 1 below the waist hem: +0.02
        [0.0, 1.49, 0.00],  # 2 above the back neckline: +0.005
        [0.0, 1.45, 0.04],  # 3 half way to the front: neckline at 1.46, -0.01
        [0.0, 1.45, 0.20],  # 4 far front (clipped to the full 5 cm dip): +0.015
        [0.0, 1.45, -0.10],  # 5 back (clipped to no dip): -0.035
        [0.35, 1.28, 0.00],  # 6 below the left upper arm, 0.15 along it (weights: upper 0.3, hand 0.3)
        [-0.40, 1.20, 0.00],  # 7 right arm, weight exactly 0.5: not the arm
    ])
    W = np.zeros((len(V), sk.n_bones))
    W[:, sk.index("spine_02")] = 1.0
    W[6] = 0.0
    W[6, [sk.index("upperarm_l"), sk.index("hand_l"), sk.index("spine_02")]] = 0.3, 0.3, 0.4
    W[7] = 0.0
    W[7, [sk.index("lowerarm_r"), sk.index("spine_02")]] = 0.5, 0.5
    return dataclasses.replace(base, vertices=V, weights=W)


def test_shirt_region_field_is_the_largest_of_the_hem_fields():
    body = _shirt_case()
    # vertex 6: 0.12 below the upper arm (0.15 from the forearm's line): arm coordinate 0.15, short sleeve hem
    # 0.45 * 0.3 = 0.135: +0.015
    want = [-0.03, 0.02, 0.005, -0.01, 0.015, -0.035, 0.015, 0.97 - 1.20]
    assert gm.shirt_region_field(body, "short") == pytest.approx(want, abs=1e-12)
    # long sleeves end 3 cm before the wrist: hem 0.55 - 0.03, vertex 6 inside (the neckline's 1.28 - 1.485
    # wins over the waist's 0.97 - 1.28 and the sleeve's 0.15 - 0.52)
    want_long = want[:6] + [1.28 - 1.485, 0.97 - 1.20]
    assert gm.shirt_region_field(body, "long") == pytest.approx(want_long, abs=1e-12)


def test_shirt_region_field_sleeves_on_each_side():
    body = _shirt_case()
    sk = body.skeleton
    # vertex 7 on the right arm with arm weight 0.6 (lower 0.3 + upper 0.3): (-0.4, 1.2, 0) is 0.05 from the
    # forearm, 0.2 down it: coordinate 0.25 + 0.2; short hem 0.45 * 0.25: +0.3375, long hem 0.52: -0.07
    W = body.weights.copy()
    W[7] = 0.0
    W[7, [sk.index("lowerarm_r"), sk.index("upperarm_r"), sk.index("spine_02")]] = 0.3, 0.3, 0.4
    right = dataclasses.replace(body, weights=W)
    assert gm.shirt_region_field(right, "short")[7] == pytest.approx(0.45 - 0.1125, abs=1e-12)
    assert gm.shirt_region_field(right, "long")[7] == pytest.approx(0.45 - 0.52, abs=1e-12)


def test_shirt_region_field_of_another_rig_uses_the_game_engine_bones():
    got = gm.shirt_region_field(_shaped("cmu_mb"), "short")
    assert np.array_equal(got, gm.shirt_region_field(_shaped("game_engine"), "short"))


# --- shirt_garment_mesh ---------------------------------------------------------------------------

def test_shirt_garment_mesh_is_the_body_region_offset_along_the_normals():
    body = _body()
    sk = body.skeleton
    hip_y = 0.5 * (sk.heads[sk.index("thigh_l"), 1] + sk.heads[sk.index("thigh_r"), 1])
    from bodystudio.geometry.mesh import vertex_normals

    N = vertex_normals(body.vertices, body.faces)
    for offset in (0.0, 0.02):
        V, F, M = gm.shirt_garment_mesh(body, "short", offset_m=offset)
        shell = body.vertices + offset * N
        assert M.shape == (len(V), body.n_vertices)
        assert np.allclose(M @ shell, V, atol=1e-12) and np.allclose(np.asarray(M.sum(1)).ravel(), 1.0)
        assert F.max() == len(V) - 1 and F.min() == 0
        # body vertices inside the shirt are kept, moved out by exactly the offset
        field = gm.shirt_region_field(body, "short")
        inside = np.flatnonzero(field < 0)
        whole = np.flatnonzero(np.isclose(np.asarray(M.max(1).todense()).ravel(), 1.0))
        src = np.asarray(M[whole].argmax(1)).ravel()
        assert set(src) <= set(inside) and len(src) > 0.75 * len(inside)  # measured 520 of 650
        assert np.allclose(V[whole], body.vertices[src] + offset * N[src], atol=1e-12)
        if offset == 0.0:
            # on the surface itself the waist hem is a horizontal cut 6 cm above the hips
            assert V[:, 1].min() == pytest.approx(hip_y + 0.06, abs=1e-9)
            assert np.sum(np.abs(V[:, 1] - (hip_y + 0.06)) < 1e-9) > 20
    # the default offset is 8 mm
    Vd, _, Md = _shirt_shell("short")
    assert np.allclose(Vd, Md @ (body.vertices + 0.008 * N), atol=1e-12)


def test_shirt_garment_mesh_keeps_one_piece_and_the_sleeve_length():
    body = _body()
    sk = body.skeleton
    from scipy.sparse.csgraph import connected_components

    wrist_x = abs(sk.tails[sk.index("lowerarm_l"), 0])
    elbow_x = abs(sk.heads[sk.index("lowerarm_l"), 0])
    for sleeve in ("short", "long"):
        V, F, M = gm.shirt_garment_mesh(body, sleeve)
        A = igl.adjacency_matrix(F)
        assert connected_components(A, directed=False)[0] == 1
        assert len(np.unique(F)) == len(V)  # every kept vertex is on a kept face
        reach = np.abs(V[:, 0]).max()
        assert (reach < elbow_x) if sleeve == "short" else (wrist_x - 0.06 < reach < wrist_x + 0.03)
    # the long shirt is the short one with longer sleeves: more vertices, the same torso
    assert len(_shirt_shell("long")[0]) > len(_shirt_shell("short")[0])


# --- proxy_garment_mesh -----------------------------------------------------------------------------

def _makehuman_weights(ids):
    from bodystudio.body.model import rig_definition
    from bodystudio.body.skeleton import load_skin_weights

    return load_skin_weights(rig_definition(), 0, vertex_ids=ids)


def test_skirt_is_makehumans_proxy_with_its_own_weights():
    from bodystudio.body.makehuman import load_group_faces
    from bodystudio.body.model import shaped_vertices

    V, F, uv, weld, W = gm.proxy_garment_mesh(_body(), "skirt")
    quads, _, _ = load_group_faces("helper-skirt")
    ids = np.unique(quads)
    # welded vertices are the proxy's shaped vertices, one per MakeHuman vertex
    assert len(np.unique(weld)) == len(ids) and len(V) > len(ids)  # UV seams split some
    assert np.array_equal(V, shaped_vertices()[ids][weld])
    assert np.allclose(W, _makehuman_weights(ids)[weld] / _makehuman_weights(ids)[weld].sum(1, keepdims=True))
    assert np.allclose(W.sum(1), 1.0)
    assert len(F) == 2 * len(quads) and F.max() == len(V) - 1
    # MakeHuman's charts rescaled into [0.01, 0.99] with the aspect kept
    assert uv.min() == pytest.approx(0.01) and uv.max() == pytest.approx(0.99)
    assert gm.uv_overlap_fraction(uv, F) < gm.MAX_UV_OVERLAP


def test_skirt_follows_the_body_shape():
    from bodystudio.body.makehuman import load_group_faces
    from bodystudio.body.model import shaped_vertices

    V, _, _, weld, _ = gm.proxy_garment_mesh(_shaped("game_engine"), "skirt")
    ids = np.unique(load_group_faces("helper-skirt")[0])
    assert np.array_equal(V, shaped_vertices(SHAPE, LOCAL)[ids][weld])
    assert not np.allclose(V, shaped_vertices(SHAPE, {})[ids][weld], atol=1e-3)  # the local modifiers count


def test_tights_are_the_suit_between_the_waist_and_the_ankles():
    body = _body()
    sk = body.skeleton
    V, F, uv, weld, W = gm.proxy_garment_mesh(body, "tights")
    waist = 0.5 * (sk.heads[sk.index("thigh_l"), 1] + sk.heads[sk.index("thigh_r"), 1]) + 0.06
    ankle = 0.5 * (sk.heads[sk.index("foot_l"), 1] + sk.heads[sk.index("foot_r"), 1]) + 0.06
    assert V[:, 1].max() == pytest.approx(waist, abs=1e-9) and V[:, 1].min() == pytest.approx(ankle, abs=1e-9)
    assert np.sum(np.abs(V[:, 1] - waist) < 1e-9) > 20 and np.sum(np.abs(V[:, 1] - ankle) < 1e-9) > 20
    # one piece (the largest component), re-indexed, seam copies welded by position
    from scipy.sparse.csgraph import connected_components

    assert connected_components(igl.adjacency_matrix(F), directed=False)[0] == 1
    assert len(np.unique(F)) == len(V)
    assert np.array_equal(weld, gm._weld_positions(V))
    assert uv.min() == pytest.approx(0.01) and uv.max() == pytest.approx(0.99)
    assert np.allclose(W.sum(1), 1.0) and W.min() >= 0
    # MakeHuman's weights of the suit, interpolated at the cut: uncut vertices carry them exactly
    from bodystudio.body.makehuman import load_group_faces
    from bodystudio.body.model import shaped_vertices

    ids = np.unique(load_group_faces("helper-tights")[0])
    Vs = shaped_vertices()[ids]
    truth = _makehuman_weights(ids)
    truth = truth / truth.sum(1, keepdims=True)
    d, j, _ = igl.point_mesh_squared_distance(V, Vs, np.arange(len(Vs))[:, None].repeat(3, 1))
    exact = d < 1e-20
    assert exact.mean() > 0.8
    assert np.allclose(W[exact], truth[j[exact]], atol=1e-9)


def test_proxy_weights_of_a_rig_without_proxy_weights_are_the_skins_diffused(monkeypatch):
    body = _body()
    V0, F0, uv0, weld0, _ = _proxy("skirt")

    def no_proxy_weights(*args, **kwargs):
        raise AssetError("this rig has no weights for the proxies")

    monkeypatch.setattr(gm, "load_skin_weights", no_proxy_weights)
    V, F, uv, weld, W = gm.proxy_garment_mesh(body, "skirt")
    assert np.array_equal(V, V0) and np.array_equal(F, F0)
    want = gm.smooth_skin_weights(gm.transfer_skin_weights(V, body.vertices, body.faces, body.weights), F, weld, 30)
    assert np.allclose(W, want / want.sum(1, keepdims=True), atol=1e-12)
    once = gm.smooth_skin_weights(gm.transfer_skin_weights(V, body.vertices, body.faces, body.weights), F, weld, 29)
    assert np.abs(W - once).max() > 1e-6  # 30 steps, not 29


def test_overlapping_proxy_charts_are_rebuilt_with_xatlas(monkeypatch, caplog):
    body = _body()
    V0, F0, uv0, weld0, W0 = _proxy("skirt")
    monkeypatch.setattr(gm, "MAX_UV_OVERLAP", -1.0)  # every layout "overlaps"
    with caplog.at_level("INFO", logger="bodystudio.garment.garments"):
        V, F, uv, weld, W = gm.proxy_garment_mesh(body, "skirt")
    assert "skirt: MakeHuman's UV charts overlap; rebuilding them with xatlas" in [r.getMessage() for r in
                                                                                 caplog.records]
    vmap, Fx, uvx = gm.xatlas_uv(V0, F0)
    assert np.array_equal(F, Fx) and np.allclose(uv, uvx)
    assert np.array_equal(V, V0[vmap]) and np.array_equal(weld, weld0[vmap]) and np.allclose(W, W0[vmap])


def test_overlap_threshold_is_strict(monkeypatch):
    V0, F0, uv0, _, _ = _proxy("skirt")
    frac = gm.uv_overlap_fraction(uv0, F0)
    monkeypatch.setattr(gm, "MAX_UV_OVERLAP", frac)  # equal: not above it, MakeHuman's charts kept
    _, F, uv, _, _ = gm.proxy_garment_mesh(_body(), "skirt")
    assert np.array_equal(F, F0) and np.array_equal(uv, uv0)


# --- xatlas_uv ------------------------------------------------------------------------------------

def test_xatlas_uv_covers_the_same_surface_with_unit_square_charts():
    V, F, _ = _shirt_shell("short")
    vmap, Fx, uv = gm.xatlas_uv(V, F)
    assert vmap.dtype == np.int64 and Fx.dtype == np.int64 and uv.dtype == np.float64
    assert Fx.shape == F.shape and uv.shape == (len(vmap), 2) and Fx.max() == len(vmap) - 1
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    # the same triangles (each face's corners are the same positions, in order)
    Vx = V[vmap]
    a = np.sort([tuple(np.round(Vx[f].ravel(), 9)) for f in Fx], axis=0)
    b = np.sort([tuple(np.round(V[f].ravel(), 9)) for f in F], axis=0)
    assert np.array_equal(a, b)
    # charts do not overlap
    assert gm.uv_overlap_fraction(uv, Fx) < 0.01


# --- dress ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["tights", "skirt"])
def test_dressed_proxy_is_pushed_out_of_the_skin_once_per_welded_vertex(name):
    body = _body()
    g = gm.dress(body, name, "checks", texture_size=16, seed=2)
    V0, F0, uv0, weld0, W0 = _proxy(name)
    assert g.name == name and np.array_equal(g.faces, F0) and np.array_equal(g.uv, uv0)
    assert np.array_equal(g.weld, weld0) and np.array_equal(g.weights, W0)
    n_weld = int(weld0.max()) + 1
    Vw = np.zeros((n_weld, 3))
    Vw[weld0] = V0
    assert np.allclose(g.vertices, gm.push_outside_body(Vw, body.vertices, body.faces)[weld0], atol=1e-12)
    S, *_ = igl.signed_distance(g.vertices, body.vertices, body.faces)
    assert S.min() > gm.MIN_CLEARANCE_M - 1e-4
    # seam copies stay together
    first = np.unique(weld0, return_index=True)[1]
    assert np.array_equal(g.vertices, g.vertices[first][weld0])
    assert np.array_equal(g.texture, gm.bake_procedural_texture(g.vertices, g.faces, g.uv, "checks", 16, 2))


@pytest.mark.parametrize("name,sleeve", [("tshirt", "short"), ("longsleeve", "long")])
def test_dressed_shirt_is_the_shell_with_xatlas_uvs_and_the_skins_weights(name, sleeve):
    body = _body()
    g = gm.dress(body, name, "stripes", texture_size=16, seed=1)
    Vs, Fs, M = _shirt_shell(sleeve)
    vmap, F, uv = gm.xatlas_uv(Vs, Fs)
    assert np.array_equal(g.faces, F) and np.allclose(g.uv, uv) and np.array_equal(g.weld, vmap)
    assert np.array_equal(g.vertices, Vs[vmap])
    W = np.asarray(M @ body.weights)[vmap]
    assert np.allclose(g.weights, W / W.sum(1, keepdims=True), atol=1e-12)
    assert np.allclose(g.weights.sum(1), 1.0, atol=1e-12)
    assert np.array_equal(g.texture, gm.bake_procedural_texture(g.vertices, g.faces, g.uv, "stripes", 16, 1))


def test_dress_defaults_are_stripes_of_seed_0_at_512_texels():
    g = gm.dress(_body(), "skirt")
    assert g.texture.shape == (gm.TEXTURE_SIZE, gm.TEXTURE_SIZE, 3) == (512, 512, 3)
    want = gm.bake_procedural_texture(g.vertices, g.faces, g.uv, "stripes", 512, 0)
    assert np.array_equal(g.texture, want)


@pytest.mark.parametrize("kwargs,message", [
    ({"name": "cape"}, "unknown garment 'cape'; valid: tights, skirt, tshirt, longsleeve"),
    ({"pattern": "tartan"}, "unknown cloth pattern 'tartan'; valid: stripes, checks, print, plain"),
    ({"texture_size": 15}, "texture size 15 must lie in [16, 4096] texels"),
    ({"texture_size": 4097}, "texture size 4097 must lie in [16, 4096] texels"),
])
def test_dress_refusals(kwargs, message):
    args = {"name": "skirt", "pattern": "stripes", "texture_size": 16} | kwargs
    with pytest.raises(InputError) as e:
        gm.dress(_body(), args.pop("name"), **args)
    assert str(e.value) == message


def test_dress_needs_a_body_model():
    with pytest.raises(InputError) as e:
        gm.dress({"vertices": 0}, "skirt")
    assert str(e.value) == "dress needs a BodyModel (bodystudio.body.build_body), got dict"


def test_dress_accepts_the_smallest_texture():
    assert gm.dress(_body(), "skirt", texture_size=16).texture.shape == (16, 16, 3)


# --- load_garment_mesh --------------------------------------------------------------------------------

def _export(path, V, F, uv=None, image=None):
    import trimesh

    visual = None
    if uv is not None:
        from PIL import Image

        visual = trimesh.visual.TextureVisuals(uv=uv, image=None if image is None else Image.fromarray(image))
    trimesh.Trimesh(V, F, visual=visual, process=False).export(path)
    return path


def _write_obj(path, V, F, uv):
    """An OBJ with texture coordinates and no material (17 significant digits: read back exactly)."""
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V] + [f"vt {u:.17g} {v:.17g}" for u, v in uv]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in F + 1]
    path.write_text("\n".join(lines) + "\n")
    return path


def _reload(path):
    import trimesh

    m = trimesh.load(path, process=False, force="mesh")
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), getattr(m.visual, "uv", None)


def test_loaded_obj_with_uvs_is_bound_like_the_functions_say(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    vmap, F, uv = gm.xatlas_uv(Vs, Fs)
    path = _write_obj(tmp_path / "shirt.obj", Vs[vmap], F, uv)
    g = gm.load_garment_mesh(path, body, pattern="checks", texture_size=16, seed=4, smooth_iterations=3)
    V0, F0, uv0 = _reload(path)
    assert g.name == "shirt" and np.array_equal(g.faces, F0) and np.array_equal(g.uv, uv0)
    assert np.array_equal(V0, Vs[vmap]) and np.array_equal(uv0, uv)  # the file holds the shell
    V = gm.push_outside_body(V0, body.vertices, body.faces)
    assert np.array_equal(g.vertices, V)
    assert np.array_equal(g.weld, gm._weld_positions(V0))
    W = gm.smooth_skin_weights(gm.transfer_skin_weights(V, body.vertices, body.faces, body.weights), F0, g.weld, 3)
    assert np.allclose(g.weights, W, atol=1e-12)
    assert np.array_equal(g.texture, gm.bake_procedural_texture(V0, F0, uv0, "checks", 16, 4))
    # the weights follow the skin under the shirt: the shell's own (body weights through M)
    own = np.asarray(_shirt_shell("short")[2] @ body.weights)[vmap]
    assert np.mean(0.5 * np.abs(g.weights - own).sum(1)) < 0.1


def test_loaded_mesh_defaults_diffuse_30_steps_and_bake_stripes_512(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    vmap, F, uv = gm.xatlas_uv(Vs, Fs)
    path = _write_obj(tmp_path / "shirt.obj", Vs[vmap], F, uv)
    g = gm.load_garment_mesh(path, body)
    V0, F0, uv0 = _reload(path)
    V = gm.push_outside_body(V0, body.vertices, body.faces)
    W = gm.smooth_skin_weights(gm.transfer_skin_weights(V, body.vertices, body.faces, body.weights), F0, g.weld, 30)
    assert np.allclose(g.weights, W, atol=1e-12)
    assert np.array_equal(g.texture, gm.bake_procedural_texture(V0, F0, uv0, "stripes", 512, 0))


def test_loaded_mesh_inside_the_skin_is_pushed_out(tmp_path):
    body = _body()
    # the body's own surface between the shirt's hems (offset 0): on the skin, pushed out to the clearance
    Vs, Fs, _ = gm.shirt_garment_mesh(body, "short", offset_m=-0.003)
    path = _export(tmp_path / "inner.ply", Vs, Fs)
    g = gm.load_garment_mesh(path, body, texture_size=16, smooth_iterations=0)
    S, *_ = igl.signed_distance(g.vertices, body.vertices, body.faces)
    # measured: median 4.0 mm, 5th percentile 3.9 mm (pushed along the pseudonormal: a little less in hollows)
    assert np.median(S) == pytest.approx(gm.MIN_CLEARANCE_M, abs=1e-4) and np.percentile(S, 5) > 0.0035
    d_in, *_ = igl.signed_distance(_reload(path)[0], body.vertices, body.faces)
    assert np.median(d_in) < 0.0  # the file's shell was 3 mm inside


def test_loaded_ply_without_uvs_gets_an_xatlas_atlas(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    path = _export(tmp_path / "shirt.ply", Vs, Fs)
    g = gm.load_garment_mesh(path, body, pattern="plain", texture_size=16, seed=5, smooth_iterations=0)
    V0, F0, _ = _reload(path)
    vmap, F, uv = gm.xatlas_uv(V0, F0)
    assert np.array_equal(g.faces, F) and np.allclose(g.uv, uv) and np.array_equal(g.weld, vmap)
    assert np.array_equal(g.vertices, gm.push_outside_body(V0[vmap], body.vertices, body.faces))
    W = gm.transfer_skin_weights(g.vertices, body.vertices, body.faces, body.weights)
    assert np.allclose(g.weights, gm.smooth_skin_weights(W, F, vmap, 0), atol=1e-12)
    assert np.array_equal(g.texture, gm.bake_procedural_texture(V0[vmap], F, uv, "plain", 16, 5))


def test_loaded_uvs_outside_the_unit_square_are_normalised(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    vmap, F, uv = gm.xatlas_uv(Vs, Fs)
    for shift in ((2.0, 0.0), (-1.0, 0.0), (0.0, 0.5)):
        path = _write_obj(tmp_path / "shifted.obj", Vs[vmap], F, uv * 1.5 + shift)
        g = gm.load_garment_mesh(path, body, texture_size=16, smooth_iterations=0)
        _, _, uv0 = _reload(path)
        assert np.allclose(g.uv, gm.normalized_uv(uv0), atol=1e-12)
    # UVs exactly on the unit square's border are kept as they are
    inside = (uv - uv.min(0)) / (uv.max(0) - uv.min(0))
    path = _write_obj(tmp_path / "border.obj", Vs[vmap], F, inside)
    g = gm.load_garment_mesh(path, body, texture_size=16, smooth_iterations=0)
    assert np.allclose(g.uv, _reload(path)[2], atol=1e-12)
    assert g.uv.min() == 0.0 and g.uv.max() == 1.0


def test_loaded_glb_keeps_its_own_texture_image(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    vmap, F, uv = gm.xatlas_uv(Vs, Fs)
    image = np.random.default_rng(0).integers(0, 256, (8, 12, 3), dtype=np.uint8)
    path = _export(tmp_path / "shirt.glb", Vs[vmap], F, uv, image)
    g = gm.load_garment_mesh(path, body, texture_size=16, smooth_iterations=0)
    assert np.array_equal(g.texture, image)
    assert np.array_equal(g.weld, gm._weld_positions(_reload(path)[0]))


def test_loaded_glb_with_trimeshs_stand_in_image_gets_the_procedural_texture(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    vmap, F, uv = gm.xatlas_uv(Vs, Fs)
    path = _export(tmp_path / "shirt.glb", Vs[vmap], F, uv)  # trimesh writes its 2 x 2 grey stand-in
    g = gm.load_garment_mesh(path, body, texture_size=16, smooth_iterations=0)
    V0, F0, uv0 = _reload(path)
    assert np.array_equal(g.texture, gm.bake_procedural_texture(V0, F0, uv0, "stripes", 16, 0))


def _refusal(path, message, kind=FileFormatError, **kwargs):
    with pytest.raises(kind) as e:
        gm.load_garment_mesh(path, _body(), texture_size=16, **kwargs)
    assert str(e.value) == message.format(path=path)


def test_load_garment_mesh_refuses_missing_and_unsupported_files(tmp_path):
    _refusal(tmp_path / "none.obj", "{path}: no such garment mesh file")
    (tmp_path / "shirt.stl").write_text("solid x\nendsolid x\n")
    _refusal(tmp_path / "shirt.stl", "{path}: unsupported garment format; use .obj, .glb, .gltf or .ply")
    (tmp_path / "shirt.OBJ").write_text("v 0 0 0\n")  # upper-case suffix accepted, no faces refused
    _refusal(tmp_path / "shirt.OBJ", "{path}: contains no triangles; give a triangle mesh of the garment")


def test_load_garment_mesh_refuses_unreadable_files(tmp_path):
    path = tmp_path / "broken.glb"
    path.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(FileFormatError) as e:
        gm.load_garment_mesh(path, _body())
    assert str(e.value).startswith(f"{path}: cannot read the garment mesh (")


def test_load_garment_mesh_refuses_non_finite_vertices(tmp_path):
    Vs, Fs, _ = _shirt_shell("short")
    V = Vs.copy()
    V[[3, 7]] = np.nan
    V[11, 0] = np.inf
    path = tmp_path / "nan.obj"
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in Fs))
    _refusal(path, "{path}: 3 vertices are NaN or infinite")


def test_load_garment_mesh_refuses_other_units_and_far_garments(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    extent_body = float(np.ptp(body.vertices, axis=0).max())
    cm = _export(tmp_path / "cm.ply", Vs * 100, Fs)
    ext = float(np.ptp(_reload(cm)[0], axis=0).max())
    _refusal(cm, f"{{path}}: the garment spans {ext:.3g} units but the body {extent_body:.2f} m; export it in "
                 "metres (y up, facing +z) around the body's rest pose", InputError)
    tiny = _export(tmp_path / "tiny.ply", (Vs - Vs.mean(0)) * 0.0199 / np.ptp(Vs, axis=0).max() + Vs.mean(0), Fs)
    with pytest.raises(InputError, match="export it in metres"):  # 2 cm across is not a garment
        gm.load_garment_mesh(tiny, body, texture_size=16)
    # just under 1.5 body extents is accepted as a size (then refused as too far from the body)
    big = _export(tmp_path / "big.ply", (Vs - Vs.mean(0)) * 1.49 * extent_body / np.ptp(Vs, axis=0).max()
                  + Vs.mean(0), Fs)
    with pytest.raises(InputError, match="from the body surface"):
        gm.load_garment_mesh(big, body, texture_size=16)
    far = _export(tmp_path / "far.ply", Vs + [0.0, 0.0, 0.5], Fs)
    d2, _, _ = igl.point_mesh_squared_distance(_reload(far)[0], body.vertices, body.faces)
    median = float(np.median(np.sqrt(d2)))
    _refusal(far, f"{{path}}: the garment lies {median:.2f} m (median) from the body surface; place it on the "
                  "body's rest pose (within 0.15 m)", InputError)
    # a looser bound accepts it; a tighter one refuses a garment 5 cm out
    assert gm.load_garment_mesh(far, body, texture_size=16, max_distance_m=median + 0.01,
                                smooth_iterations=0).n_vertices > 0
    near = _export(tmp_path / "near.ply", Vs + [0.0, 0.0, 0.05], Fs)
    with pytest.raises(InputError, match=r"within 0\.03 m"):
        gm.load_garment_mesh(near, body, texture_size=16, max_distance_m=0.03)


# --- survivors of the first mutation run ----------------------------------------------------------------

def test_arm_coordinate_tie_keeps_the_upper_arm():
    # binary fractions: the point is exactly 0.125 from both segments; the upper arm (checked first) wins
    body = _with_joints(_body(), upperarm_l=(0.25, 1.5, 0.0), upperarm_l_tail=(0.75, 1.5, 0.0),
                        lowerarm_l=(0.75, 1.5, 0.0), lowerarm_l_tail=(0.75, 1.25, 0.0))
    got = gm.arm_coordinate(np.array([[0.625, 1.375, 0.0], [0.875, 1.375, 0.0]]), body, "l")
    assert list(got) == [0.375, 0.5 + 0.125]


def test_shirt_defaults_are_short_sleeves():
    body = _body()
    assert np.array_equal(gm.shirt_region_field(body), gm.shirt_region_field(body, "short"))
    V, F, M = gm.shirt_garment_mesh(body)
    Vs, Fs, Ms = _shirt_shell("short")
    assert np.array_equal(V, Vs) and np.array_equal(F, Fs)


def test_gltf_is_a_garment_format_and_read_errors_name_their_type(tmp_path):
    path = tmp_path / "shirt.GLTF"
    path.write_text("{not json")
    with pytest.raises(FileFormatError) as e:
        gm.load_garment_mesh(path, _body())
    msg = str(e.value)
    assert msg.startswith(f"{path}: cannot read the garment mesh (") and "NoneType" not in msg
    kind = msg.split("cannot read the garment mesh (", 1)[1].split(":", 1)[0]
    assert kind.isidentifier() and kind[0].isupper()


def test_a_garment_wider_than_one_and_a_half_bodies_is_refused_as_other_units(tmp_path):
    body = _body()
    Vs, Fs, _ = _shirt_shell("short")
    extent_body = float(np.ptp(body.vertices, axis=0).max())
    wide = _export(tmp_path / "wide.ply", (Vs - Vs.mean(0)) * 1.6 * extent_body / np.ptp(Vs, axis=0).max()
                   + Vs.mean(0), Fs)
    with pytest.raises(InputError, match="export it in metres"):
        gm.load_garment_mesh(wide, body, texture_size=16)
