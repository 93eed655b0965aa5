"""Garments built from MakeHuman's proxies and the body surface: fit, hem lines, UVs, texture, skinning."""

import igl
import numpy as np
import pytest

from bodystudio.body import Pose
from bodystudio.garment import garments as gm


def test_cut_mesh_at_isoline_is_exact_on_a_plane():
    # a 10x10 grid of the unit square cut at x = 0.33: the kept area is exactly 0.33, hem vertices on the line
    n = 10
    xs, ys = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1))
    V = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    idx = np.arange(xs.size).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    Vc, Fc, M = gm.cut_mesh_at_isoline(V, F, V[:, 0] - 0.33)
    area = 0.5 * igl.doublearea(Vc, Fc).sum()
    assert area == pytest.approx(0.33, abs=1e-12)
    assert Vc[:, 0].max() == pytest.approx(0.33, abs=1e-12)
    assert np.allclose(M @ V, Vc) and np.allclose(np.asarray(M.sum(1)).ravel(), 1.0)
    # consistent winding: every kept triangle faces +z like the input
    n_z = np.cross(Vc[Fc[:, 1]] - Vc[Fc[:, 0]], Vc[Fc[:, 2]] - Vc[Fc[:, 0]])[:, 2]
    assert np.all(n_z > 0)


@pytest.mark.parametrize("name", ["tights", "skirt", "tshirt", "longsleeve"])
def test_garment_is_well_formed_and_outside_the_skin(garments, garment_body, name):
    g = garments[name]
    n = g.n_vertices
    assert g.faces.max() < n and g.uv.shape == (n, 2) and g.weld.shape == (n,)
    assert g.uv.min() >= 0 and g.uv.max() <= 1
    assert g.texture.dtype == np.uint8 and g.texture.shape == (256, 256, 3)
    assert g.weights.shape == (n, garment_body.skeleton.n_bones)
    assert np.allclose(g.weights.sum(1), 1.0) and g.weights.min() >= 0
    assert gm.uv_overlap_fraction(g.uv, g.faces) < gm.MAX_UV_OVERLAP
    S, *_ = igl.signed_distance(g.vertices, garment_body.vertices, garment_body.faces)
    # measured: every vertex outside by >= 3 mm; median 6-8 mm (skirt 27 mm)
    assert np.mean(S > 0.003) > 0.99, np.mean(S > 0.003)
    assert np.median(S) < (0.1 if name == "skirt" else 0.02)


def test_hem_lines_follow_the_skeleton(garments, garment_body):
    sk = garment_body.skeleton
    hip_y = 0.5 * (sk.heads[sk.index("thigh_l")][1] + sk.heads[sk.index("thigh_r")][1])
    shirt, long_, tights = garments["tshirt"], garments["longsleeve"], garments["tights"]
    # the waist hem is a clean horizontal cut 6 cm above the hip joints (offset along normals moves it < 1 cm)
    assert shirt.vertices[:, 1].min() == pytest.approx(hip_y + 0.06, abs=0.01)
    assert tights.vertices[:, 1].max() == pytest.approx(hip_y + 0.06, abs=0.01)
    # short sleeves end on the upper arm, long ones at the wrist
    wrist_x = abs(sk.tails[sk.index("lowerarm_l")][0])
    elbow_x = abs(sk.heads[sk.index("lowerarm_l")][0])
    assert np.abs(shirt.vertices[:, 0]).max() < elbow_x
    assert np.abs(long_.vertices[:, 0]).max() > 0.9 * wrist_x
    assert np.abs(long_.vertices[:, 0]).max() < wrist_x + 0.03


def test_procedural_texture_matches_the_pattern_on_the_surface(garments):
    g = garments["tshirt"]
    # the texture looked up at each vertex's UV gives the stripe colour of its rest-pose position
    want = gm.cloth_pattern(g.vertices, "stripes", gm.cloth_colors(0))
    got = gm.sample_texture(g.texture, g.uv)
    agree = np.mean(np.abs(got - want).max(1) < 0.1)
    assert agree > 0.85, agree  # measured 0.90 at 256 texels (vertices on a stripe border blend both colours)


def test_posed_garment_follows_the_body(garments, garment_body):
    body = garment_body
    rot = np.zeros((body.skeleton.n_bones, 3))
    for bone, v in (("upperarm_l", (0, 0, -0.7)), ("lowerarm_r", (0.9, 0, 0)), ("thigh_l", (-0.6, 0, 0)),
                    ("calf_l", (0.8, 0, 0)), ("spine_02", (0.1, 0.3, 0))):
        rot[body.skeleton.index(bone)] = v
    pose = Pose(rot, np.array([0.1, 0.0, 0.2]))
    Vb, _ = body.pose(pose)
    for name in ("tshirt", "longsleeve", "tights"):
        g = garments[name]
        rest, _, _ = igl.point_mesh_squared_distance(g.vertices, body.vertices, body.faces)
        posed, _, _ = igl.point_mesh_squared_distance(gm.pose_garment(g, body, pose), Vb, body.faces)
        # the garment keeps its distance to the skin: median change measured <= 0.02 mm
        change = np.abs(np.sqrt(posed) - np.sqrt(rest))
        assert np.median(change) < 1e-4, (name, np.median(change))
        # a garment left in the rest pose is far from the posed body
        unposed, _, _ = igl.point_mesh_squared_distance(g.vertices, Vb, body.faces)
        assert np.median(np.sqrt(unposed)) > 0.02


def test_weight_transfer_matches_makehumans_own_proxy_weights(garment_body):
    from bodystudio.body.makehuman import load_group_faces
    from bodystudio.body.model import rig_definition, shaped_vertices
    from bodystudio.body.skeleton import load_skin_weights

    quads, _, _ = load_group_faces("helper-tights")
    ids = np.unique(quads)
    truth = load_skin_weights(rig_definition(), 0, vertex_ids=ids)
    V = shaped_vertices()[ids]
    W = gm.transfer_skin_weights(V, garment_body.vertices, garment_body.faces, garment_body.weights)
    tv = 0.5 * np.abs(W - truth).sum(1)
    assert tv.mean() < 0.055, tv.mean()  # measured 0.037 on the 2k body (0.024 on the full one)
    uniform = np.full_like(W, 1.0 / W.shape[1])
    assert 0.5 * np.abs(uniform - truth).sum(1).mean() > 0.9


def test_weight_diffusion_keeps_a_skirt_from_tearing(garments, garment_body):
    from bodystudio.capture.motion import motion_sequence

    body, g = garment_body, garments["skirt"]
    E = np.vstack([g.faces[:, [0, 1]], g.faces[:, [1, 2]], g.faces[:, [2, 0]]])
    L0 = np.linalg.norm(g.vertices[E[:, 0]] - g.vertices[E[:, 1]], axis=1)
    poses = motion_sequence("walk", 12, body.skeleton, 0)
    W0 = gm.transfer_skin_weights(g.vertices, body.vertices, body.faces, body.weights)

    def stretch(W):
        worst = 0.0
        for p in poses:
            Vp = gm.pose_garment(gm.Garment("s", g.vertices, g.faces, g.uv, g.texture, W, g.weld), body, p)
            worst = max(worst, np.percentile(np.linalg.norm(Vp[E[:, 0]] - Vp[E[:, 1]], axis=1) / L0, 99))
        return worst

    raw, smooth, makehuman = stretch(W0), stretch(gm.smooth_skin_weights(W0, g.faces, g.weld, 30)), stretch(g.weights)
    assert raw > 3.0 and smooth < 2.0 and makehuman < 2.4, (raw, smooth, makehuman)


def test_user_garment_mesh_is_bound_like_a_dressed_one(tmp_path, garments, garment_body):
    import trimesh

    g = garments["tshirt"]
    path = tmp_path / "shirt.obj"
    trimesh.Trimesh(g.vertices, g.faces, visual=trimesh.visual.TextureVisuals(uv=g.uv), process=False).export(path)
    user = gm.load_garment_mesh(path, garment_body, smooth_iterations=0)
    assert user.n_vertices >= len(np.unique(g.weld))
    d, _, _ = igl.point_mesh_squared_distance(user.vertices, g.vertices, g.faces)
    assert np.sqrt(d).max() < 0.005  # kept in place (only pushed out of the skin where needed)
    # weights from the nearest skin agree with the shirt's own (body weights interpolated at the cut)
    _, tri, C = igl.point_mesh_squared_distance(user.vertices, g.vertices, g.faces)
    own = g.weights[g.faces[tri, 0]]
    assert np.mean(0.5 * np.abs(user.weights - own).sum(1)) < 0.1
    # a PLY without UVs gets an xatlas atlas and the procedural texture
    ply = tmp_path / "shirt.ply"
    trimesh.Trimesh(g.vertices, g.faces, process=False).export(ply)
    plain = gm.load_garment_mesh(ply, garment_body, texture_size=64)
    assert plain.uv.shape == (plain.n_vertices, 2) and plain.texture.shape == (64, 64, 3)


def test_user_glb_keeps_its_own_texture(tmp_path, garments, garment_body):
    import trimesh
    from PIL import Image

    g = garments["tights"]
    path = tmp_path / "tights.glb"
    visual = trimesh.visual.TextureVisuals(uv=g.uv, image=Image.fromarray(g.texture))
    trimesh.Trimesh(g.vertices, g.faces, visual=visual, process=False).export(path)
    user = gm.load_garment_mesh(path, garment_body, pattern="checks")
    assert np.array_equal(user.texture, g.texture)  # the file's image, not a new procedural one
    assert np.abs(gm.sample_texture(user.texture, user.uv) - gm.sample_texture(g.texture, g.uv)).max() < 0.02


def test_garments_fit_bodies_of_any_rig(garments):
    from bodystudio.body import build_body

    body = build_body(resolution="2k", rig="cmu_mb")
    rot = np.zeros((body.skeleton.n_bones, 3))
    rot[body.skeleton.index("LeftForeArm")] = (0.0, 0.0, 0.8)
    rot[body.skeleton.index("RightUpLeg")] = (-0.5, 0.0, 0.0)
    pose = Pose(rot, np.zeros(3))
    Vb, _ = body.pose(pose)
    for name in ("tshirt", "longsleeve", "tights"):
        g = gm.dress(body, name, texture_size=32)
        # hem lines come from the game_engine bones of the same shape: the same cut as on that rig
        assert np.allclose(np.sort(g.vertices[:, 1]), np.sort(garments[name].vertices[:, 1]), atol=1e-9)
        assert g.weights.shape == (g.n_vertices, 31)
        rest, _, _ = igl.point_mesh_squared_distance(g.vertices, body.vertices, body.faces)
        posed, _, _ = igl.point_mesh_squared_distance(gm.pose_garment(g, body, pose), Vb, body.faces)
        assert np.median(np.abs(np.sqrt(posed) - np.sqrt(rest))) < 1e-3
