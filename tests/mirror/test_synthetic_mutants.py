"""Fast tests of the synthetic mirror session's parts (bodystudio.mirror.synthetic; issue 17, second round): the
ground truth every mirror figure is scored against. Each test calls the function under test (no session is
written): the sensor, the room's geometry and materials, the ground-truth target body (the edit really reaches
the stature / mass of the model), the SDK player mask (jitter only at the edges, no player without depth), the
tracker's visibility rule, the walk-in timing at the frame rate, the depth frame's noise order, the render labels
and the records; the session writer's refusals. The 6k model and one subject are built once per process."""

import functools
import types

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import synthetic as sy


@functools.cache
def _model_and_body():
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_subject
    from bodystudio.body.statistical import load_statistical_model

    model = load_statistical_model("6k", progress=False)
    phenotype, local = sample_subject(3)
    return model, build_body(phenotype, local, resolution="6k")


# ------------------------------------------------------------------------------------------ the sensor

def test_mirror_sensor_v2_is_the_kinect_v2_with_its_colour_scaled_to_640x480():
    from bodystudio.geometry.camera import kinect_v2

    s, ref = sy.mirror_sensor("v2"), kinect_v2(eye=sy.KINECT_EYE, target=sy.KINECT_TARGET)
    c = s.color
    assert (c.width, c.height) == (640, 480) and (s.depth.width, s.depth.height) == (512, 424)
    assert np.allclose(c.K, [[ref.color.fx / 2.25, 0, 319.5], [0, ref.color.fy / 2.25, 239.5], [0, 0, 1]])
    assert np.array_equal(c.R, ref.color.R) and np.array_equal(c.t, ref.color.t)
    assert np.array_equal(c.dist, ref.color.dist) and c.name == ref.color.name
    assert s.depth is ref.depth or np.array_equal(s.depth.K, ref.depth.K)
    assert s.version == "v2" and s.name == ref.name and s.baseline_m == ref.baseline_m
    assert s.depth_range_m == ref.depth_range_m and np.array_equal(s.depth_to_color[0], ref.depth_to_color[0])
    assert np.allclose(s.depth.center, sy.KINECT_EYE, atol=0.05)


def test_mirror_sensor_v1_and_the_refusal():
    from bodystudio.geometry.camera import kinect_v1

    assert sy.mirror_sensor().version == "v2" and sy.mirror_sensor().depth.width == 512  # v2 by default
    s = sy.mirror_sensor("v1")
    ref = kinect_v1("320x240", eye=sy.KINECT_EYE, target=sy.KINECT_TARGET)
    assert np.array_equal(s.depth.R, ref.depth.R) and np.array_equal(s.color.R, ref.color.R)
    assert s.version == "v1" and (s.depth.width, s.depth.height) == (320, 240) and s.color.width == 640
    assert np.allclose(s.depth.center, sy.KINECT_EYE, atol=0.05)
    with pytest.raises(InputError) as info:
        sy.mirror_sensor("v3")
    assert str(info.value) == "--kinect 'v3' is not a Kinect version; valid: v1, v2"


# ------------------------------------------------------------------------------------------ the room

def _signed_volume(V, F):
    return np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0


def test_box_is_a_closed_outward_box_of_its_corners():
    V, F = sy._box((0, 0, 0), (1, 2, 3))
    assert V.shape == (8, 3) and F.shape == (12, 3)
    assert {tuple(v) for v in V} == {(x, y, z) for x in (0, 1) for y in (0, 2) for z in (0, 3)}
    assert _signed_volume(V, F) == pytest.approx(6.0, abs=1e-12)
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()  # closed (every edge in two triangles)


@pytest.mark.parametrize("n", [1, 3])
def test_quad_is_an_n_by_n_grid_of_consistently_oriented_triangles(n):
    a, b, c, d = (0, 0, 0), (2, 0, 0), (2, 0, 1), (0, 0, 1)
    V, F = sy._quad(a, b, c, d, n)
    assert V.shape == ((n + 1) ** 2, 3) and F.shape == (2 * n * n, 3)
    grid = np.array([(2 * i / n, 0.0, j / n) for i in range(n + 1) for j in range(n + 1)])

    def rows(X):
        X = np.round(X, 9)
        return X[np.lexsort(X.T[::-1])]

    assert np.allclose(rows(V), rows(grid))
    nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert np.allclose(nrm[:, [0, 2]], 0) and np.allclose(np.abs(nrm[:, 1]).sum() / 2, 2.0)
    assert np.all(nrm[:, 1] * np.sign(np.cross(np.subtract(b, a), np.subtract(d, a))[1]) > 0)
    assert np.array_equal(sy._quad(a, b, c, d)[0], sy._quad(a, b, c, d, 1)[0])  # n defaults to 1


def test_mirror_room_materials_and_extent():
    room = sy.mirror_room()
    counts = np.bincount(room.material, minlength=len(sy.MATERIALS))
    assert counts.tolist() == [200, 4 * 72, 12, 12, 12, 12]
    assert np.allclose(room.vertices.min(0), (-2.8, 0.0, -1.3)) and np.allclose(room.vertices.max(0), (2.8, 2.8, 1.5))
    V, F = room.vertices, room.faces
    for name, lo, hi in (("shelf", (-1.95, 0, -1.3), (-1.05, 1.9, -0.95)),
                         ("cabinet", (1.0, 0, -1.3), (2.0, 0.8, -0.8)),
                         ("picture", (-0.35, 1.25, -1.3), (0.45, 1.85, -1.27)),
                         ("plant", (1.25, 0.8, -1.15), (1.55, 1.35, -0.9))):
        P = V[F[room.material == sy.MATERIALS.index(name)].ravel()]
        assert np.allclose(P.min(0), lo) and np.allclose(P.max(0), hi), name
    floor = V[F[room.material == 0].ravel()]
    assert np.allclose(floor[:, 1], 0.0)
    assert F.max() == len(V) - 1 and len(np.unique(F)) == len(V)  # every part's faces offset to its vertices


def test_lattice_noise_interpolates_its_lattice_and_wraps():
    cell = 0.2
    lattice = np.random.default_rng(5).uniform(-1.0, 1.0, (96, 96))
    ij = np.array([[0, 0], [3, 7], [50, 2], [94, 94]])
    vals = sy._lattice_noise(ij * cell, cell, np.random.default_rng(5))
    assert np.allclose(vals, lattice[ij[:, 0], ij[:, 1]], atol=1e-9)
    assert np.allclose(sy._lattice_noise((ij + 95) * cell, cell, np.random.default_rng(5)), vals, atol=1e-9)
    small = sy._lattice_noise(np.array([[1.0, 1.0]]) * cell, cell, np.random.default_rng(5), size=8)
    assert small[0] == pytest.approx(np.random.default_rng(5).uniform(-1.0, 1.0, (8, 8))[1, 1], abs=1e-9)


#: The cubic-spline lattice noise overshoots its [-1, 1] lattice values a little between lattice points.
NOISE_MAX = 1.3


def _albedo(material, P, seed=0):
    P = np.asarray(P, float)
    return sy.room_albedo(P, np.full(len(P), sy.MATERIALS.index(material)), seed)


def test_room_albedo_per_material():
    n = 200
    rng = np.random.default_rng(0)
    # floor: oak, a tone per 14 cm plank (0.8-1.15) with +-0.06 grain; the seams darker by 0.45
    k = rng.integers(60, 85, n)
    x = k * 0.14 - 10.0 + 0.07  # plank centres (planks start where (x + 10) / 0.14 is whole)
    z = rng.uniform(-1, 1, n)
    a = _albedo("floor", np.c_[x, np.zeros(n), z], seed=3)
    ratio = a / [0.62, 0.45, 0.28]
    assert np.allclose(ratio, ratio[:, :1])
    tone = np.random.default_rng([3, 1]).uniform(0.8, 1.15, 200)[np.floor((x + 10.0) / 0.14).astype(int) % 200]
    assert np.all(np.abs(ratio[:, 0] - tone) <= 0.06 + 1e-9) and np.std(ratio[:, 0] - tone) > 0.01
    seam = _albedo("floor", np.c_[k * 0.14 - 10.0 + 0.003, np.zeros(n), z], seed=3) / [0.62, 0.45, 0.28]
    assert np.all(seam[:, 0] < 0.45 * (1.15 + 0.06) + 1e-9) and np.all(seam[:, 0] > 0.45 * (0.8 - 0.06) - 1e-9)
    # walls: paint with +-6 % mottle, a green-grey dado below 0.9 m
    y = np.r_[rng.uniform(0.0, 0.89, n), rng.uniform(0.91, 2.8, n)]
    a = _albedo("wall", np.c_[rng.uniform(-2, 2, 2 * n), y, rng.uniform(-1, 1, 2 * n)])
    paint = np.where((y < 0.9)[:, None], [0.45, 0.52, 0.47], [0.86, 0.82, 0.74])
    r = a / paint
    assert np.allclose(r, r[:, :1]) and np.all(np.abs(r - 1) <= 0.06 * NOISE_MAX) and r.std() > 0.005
    # shelf: boards every 38 cm and above 1.85 m, book spines of 3.5 cm from a 500-colour palette
    pal = np.random.default_rng([4, 2]).uniform(0.1, 0.85, (500, 3))
    xs, ys = rng.uniform(-1.9, -1.1, n), rng.uniform(0.04, 0.37, n)
    books = _albedo("shelf", np.c_[xs, ys, np.zeros(n)], seed=4)
    idx = (np.floor((xs + 10.0) / 0.035).astype(int) + 37 * np.floor(ys / 0.38).astype(int)) % 500
    assert np.allclose(books, pal[idx])
    boards = _albedo("shelf", [[-1.5, 0.39, 0.0], [-1.5, 0.01, 0.0], [-1.5, 1.86, 0.0]], seed=4)
    assert np.allclose(boards, [0.30, 0.20, 0.12])
    # cabinet: blue-grey +-5 %, door seams (every 50 cm) darker by half
    a = _albedo("cabinet", np.c_[rng.uniform(1.01, 1.2, n), rng.uniform(0, 0.8, n), np.zeros(n)])
    r = a / [0.36, 0.42, 0.52]
    assert np.allclose(r, r[:, :1]) and np.all(np.abs(r - 1) <= 0.05 * NOISE_MAX) and r.std() > 0.005
    s = _albedo("cabinet", [[1.25, 0.4, 0.0], [1.26, 0.4, 0.0]]) / [0.36, 0.42, 0.52]
    assert 0.5 * (1 - 0.05 * NOISE_MAX) <= s[0, 0] <= 0.5 * (1 + 0.05 * NOISE_MAX) and s[1, 0] > 0.9
    # picture: 0.5 +- 0.45 per channel, three different noises; plant: one leaf noise in three greens
    a = _albedo("picture", np.c_[rng.uniform(-0.3, 0.4, n), rng.uniform(1.3, 1.8, n), np.zeros(n)])
    assert np.all(np.abs(a - 0.5) <= 0.45 * NOISE_MAX) and a.std(0).min() > 0.05
    assert abs(np.median(a) - 0.5) < 0.1 and (np.abs(a - 0.5) < 0.44).mean() > 0.9
    assert abs(np.corrcoef(a[:, 0], a[:, 1])[0, 1]) < 0.9
    a = _albedo("plant", np.c_[rng.uniform(1.25, 1.55, n), rng.uniform(0.8, 1.35, n), rng.uniform(-1.1, -0.9, n)])
    leaf = (a[:, 1] - 0.45) / 0.2
    assert np.allclose((a[:, 0] - 0.15) / 0.08, leaf) and np.allclose((a[:, 2] - 0.15) / 0.05, leaf)
    assert leaf.std() > 0.05 and np.abs(leaf).max() <= NOISE_MAX
    # the same seed gives the same albedo; another seed another one; the order of materials does not matter
    P = np.c_[rng.uniform(-2, 2, 50), rng.uniform(0, 2.8, 50), rng.uniform(-1.3, 1.5, 50)]
    M = rng.integers(0, len(sy.MATERIALS), 50)
    assert np.array_equal(sy.room_albedo(P, M, 1), sy.room_albedo(P, M, 1))
    assert not np.allclose(sy.room_albedo(P, M, 1), sy.room_albedo(P, M, 2))
    out = sy.room_albedo(P, M, 1)
    assert out.min() >= 0.0 and out.max() <= 1.0


def test_room_albedo_clips_to_the_unit_range():
    # the brightest plank tone with grain can exceed 1 only after scaling: clip keeps [0, 1] anyway
    a = _albedo("wall", [[0.0, 2.0, 0.0]] * 3)
    assert np.all((a >= 0) & (a <= 1))


def test_room_plate_colour_and_depth_of_the_back_wall():
    """A pinhole camera looking straight at the back wall from the room's middle: the depth is the distance to
    the wall plane, the colour albedo x (ambient + the two lamps' Lambert terms) x the falloff, as stated."""
    from bodystudio.geometry.camera import Camera

    K = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    R = np.diag([1.0, -1.0, -1.0])  # looking along -z (world), y up
    center = np.array([0.0, 1.4, 1.0])
    cam = Camera("c", K, np.zeros(5), R, -R @ center, 64, 48)
    room = sy.mirror_room()
    image, depth = sy.room_plate(room, cam, seed=2)
    assert image.dtype == np.uint8 and image.shape == (48, 64, 3) and depth.dtype == np.float64
    assert depth[24, 32] == pytest.approx(2.27, abs=1e-3)  # z = 1.0 -> the picture's front at z = -1.27
    n = np.array([0.0, 0.0, 1.0])
    shade = 0.35 + sum(i * max(0.0, n @ (np.asarray(d) / np.linalg.norm(d)))
                       for d, i in (((0.0, 1.0, 0.4), 0.55), ((0.3, 0.4, 1.0), 0.3)))
    shade *= 1.0 - 0.08 * 1.0  # the falloff at the back wall (z = -1.3): -(z + 1.3) / 4.8 + 1 = 1
    P = cam.unproject(np.array([[32.0, 24.0]]), np.array([depth[24, 32]]))
    expect = np.round(sy.room_albedo(P, np.array([sy.MATERIALS.index("picture")]), 2) * shade * 255.0)
    assert np.abs(image[24, 32].astype(float) - expect[0]).max() <= 1.0
    # the falloff: a floor pixel near the camera is lit by the full factor of its z
    assert image.std() > 10 and (depth > 0).all()


# ------------------------------------------------------------------------------------------ the actors

def test_clothing_albedo_dresses_by_the_dominant_bone():
    _, body = _model_and_body()
    a = sy.clothing_albedo(body, 7)
    assert a.shape == (body.n_vertices, 3) and a.min() >= 0 and a.max() <= 1
    assert np.array_equal(a, sy.clothing_albedo(body, 7)) and not np.allclose(a, sy.clothing_albedo(body, 8))
    names = body.skeleton.bone_names
    dominant = np.asarray(np.argmax(body.weights, axis=1)).ravel()
    rng = np.random.default_rng([7, 5])
    shirt = np.asarray(sy._SHIRTS[rng.integers(len(sy._SHIRTS))])
    stripe = np.asarray(sy._SHIRTS[rng.integers(len(sy._SHIRTS))])
    trousers = np.asarray(sy._TROUSERS[rng.integers(len(sy._TROUSERS))])
    skin = np.asarray(sy._SKINS[rng.integers(len(sy._SKINS))])

    def part(bones):
        return np.isin(dominant, [names.index(b) for b in bones if b in names])

    V = body.vertices
    in_shirt = part(sy._CLOTHING["shirt"])
    plain = in_shirt & (np.floor(V[:, 1] / 0.045) % 2 == 1)
    striped = in_shirt & (np.floor(V[:, 1] / 0.045) % 2 == 0)
    assert plain.sum() > 50 and striped.sum() > 50
    for mask, colour, tol in ((plain, shirt, 0.06), (striped, 0.6 * shirt + 0.4 * stripe, 0.06),
                              (part(sy._CLOTHING["trousers"]), trousers, 0.06),
                              (part(sy._CLOTHING["shoes"]), np.array([0.08, 0.08, 0.09]), 0.06)):
        r = a[mask] / colour
        assert mask.any() and np.allclose(r, r[:, :1]) and np.all(np.abs(r - 1) <= tol + 1e-9)
    # hands are skin; the top of the head is hair (another colour than the skin)
    hand = part(("hand_l", "hand_r"))
    assert hand.any() and np.all(np.abs(a[hand] / skin - 1) <= 0.06 + 1e-9)
    head = dominant == names.index("head")
    top = head & (V[:, 1] > V[:, 1].max() - 0.05)
    assert top.any() and np.all(np.abs(a[top] / skin - 1) > 0.06)
    face_front = head & (V[:, 1] < V[:, 1].max() - 0.08) & (V[:, 2] > np.median(V[head, 2]))
    assert face_front.any() and np.all(np.abs(a[face_front] / skin - 1) <= 0.06 + 1e-9)
    back = head & (V[:, 1] > V[:, 1].max() - 0.19) & (V[:, 2] < np.median(V[head, 2]) - 0.02)
    assert back.any() and np.all(np.abs(a[back] / skin - 1) > 0.06)  # hair at the back of the head too


@pytest.mark.parametrize("edits, attribute, delta", [({"taller": 0.1}, "stature_m", 0.1),
                                                     ({"heavier": 10.0}, "mass_kg", 10.0)])
def test_target_rest_body_has_the_edited_stature_or_mass(edits, attribute, delta):
    """The ground-truth target (Eq. 4 added to the actor's own mesh) measures the edit: the model's measured
    attribute changes by exactly the edit, the actor's mesh by the model's change."""
    from bodystudio.body.measure import measure_attributes

    model, body = _model_and_body()
    target, c_s, c_t = sy.target_rest_body(model, body, edits)
    assert np.allclose(c_s, model.project(body.vertices))
    assert model.measure(c_t)[attribute] - model.measure(c_s)[attribute] == pytest.approx(delta, abs=2e-3)
    dV = model.vertices(c_t) - model.vertices(c_s)
    assert np.allclose(target.vertices, body.vertices + dV)
    m_s = measure_attributes(body.vertices, body.faces, vertex_ids=body.vertex_ids)
    m_t = measure_attributes(target.vertices, target.faces, vertex_ids=target.vertex_ids)
    assert m_t[attribute] - m_s[attribute] == pytest.approx(delta, rel=0.1)
    sk_s, sk_t = model.skeleton(c_s), model.skeleton(c_t)
    assert np.allclose(target.skeleton.heads, body.skeleton.heads + sk_t.heads - sk_s.heads)
    assert np.allclose(target.skeleton.tails, body.skeleton.tails + sk_t.tails - sk_s.tails)
    assert target.skeleton.bone_names == body.skeleton.bone_names
    assert np.array_equal(target.skeleton.parents, body.skeleton.parents)
    assert np.array_equal(target.skeleton.rolls, body.skeleton.rolls)
    assert target.faces is body.faces and target.weights is body.weights and target.rig == body.rig
    assert target.resolution == body.resolution and np.array_equal(target.vertex_ids, body.vertex_ids)
    # zero edits give the actor back (the same object), with the projection as both coefficient sets
    same, c0, c1 = sy.target_rest_body(model, body, {"taller": 0.0})
    assert same is body and np.allclose(c0, c_s) and np.array_equal(c0, c1) and c0 is not c1


def test_yaw_turns_about_the_vertical_through_the_root():
    from bodystudio.body.pose import Pose
    from bodystudio.body.skinning import posed_joints

    _, body = _model_and_body()
    sk = body.skeleton
    rest = Pose(np.zeros((sk.n_bones, 3)), np.zeros(3))
    turned = sy._yaw(sk, rest, np.pi / 2, (1.0, 0.0, 2.0))
    assert np.array_equal(turned.translation, [1.0, 0.0, 2.0])
    h0, _ = posed_joints(sk, rest)
    h1, _ = posed_joints(sk, turned)
    root = int(np.flatnonzero(sk.parents < 0)[0])
    d0 = h0 - h0[root]
    d1 = h1 - h1[root] if False else h1 - (h0[root] + [1.0, 0.0, 2.0])
    # +90 degrees about +y: (x, y, z) -> (z, y, -x)
    assert np.allclose(d1, np.c_[d0[:, 2], d0[:, 1], -d0[:, 0]], atol=1e-6)
    assert np.array_equal(rest.rotations, np.zeros((sk.n_bones, 3)))  # the input pose is not changed


def test_actor_poses_stand_in_place_without_a_walk():
    _, body = _model_and_body()
    poses, stand = sy.actor_poses(body.skeleton, 14, 10, (0.3, 0.4), 1.0, "a_pose", 0, walk_in=False)
    assert len(poses) == 14 and poses[:10] == [None] * 10 and stand == 10
    for p in poses[10:]:
        assert np.allclose(p.translation, (0.3, 0.0, 0.4))
    few, stand = sy.actor_poses(body.skeleton, 5, 10, (0.0, 0.4), 1.0, "a_pose", 0)
    assert few == [None] * 5 and stand == 10


def test_actor_poses_walk_in_at_walking_speed_sampled_at_the_frame_rate():
    _, body = _model_and_body()
    for fps in (30.0, 15.0):
        poses, stand = sy.actor_poses(body.skeleton, 200, 10, (0.0, 0.4), 1.0, "arms_raise", 0, fps=fps)
        start = np.array([sy.ENTRY_X_M, 0.1])
        walk = int(np.ceil(np.linalg.norm(np.array([0.0, 0.4]) - start) / sy.WALK_SPEED_M_S * fps))
        turn = int(round(sy.TURN_S * fps))
        assert poses[9] is None and stand == 10 + walk + turn and len(poses) == 200
        xz = np.array([p.translation[[0, 2]] for p in poses[10:stand]])
        assert np.allclose(xz[0], start + (np.array([0.0, 0.4]) - start) / walk)  # one step in at frame 10
        dist = np.linalg.norm(np.array([0.0, 0.4]) - start)
        speed = np.linalg.norm(np.diff(xz[: int(0.6 * walk)], axis=0), axis=1) * fps
        # constant speed before the slow-down: the walk's whole frames at about WALK_SPEED_M_S
        assert np.allclose(speed, dist / walk * fps, rtol=1e-6) and abs(speed[0] - sy.WALK_SPEED_M_S) < 0.05
        assert np.allclose(xz[walk - 1:], (0.0, 0.4)) and xz[0, 0] > 2.0  # from +x (side 1), out of view
        assert np.all(np.diff(np.linalg.norm(np.diff(xz[int(0.75 * walk):walk], axis=0), axis=1)) < 1e-9)  # eases in
        assert np.allclose(poses[stand].translation, (0.0, 0.0, 0.4))


def test_actor_poses_turn_to_face_the_kinect_and_the_gait_fades():
    from bodystudio.body.skinning import posed_joints

    _, body = _model_and_body()
    sk = body.skeleton
    poses, stand = sy.actor_poses(sk, 120, 0, (0.0, 0.4), -1.0, "a_pose", 0)
    names = sk.bone_names
    li, ri = names.index("upperarm_l"), names.index("upperarm_r")

    def facing(p):  # the direction the body faces: up x (left shoulder -> right shoulder) in the floor plane
        h, _ = posed_joints(sk, p)
        lr = h[ri] - h[li]
        return np.arctan2(-lr[2], lr[0])

    from bodystudio.body.pose import Pose

    front = facing(Pose(np.zeros((sk.n_bones, 3)), np.zeros(3)))

    def turned(p):
        return float(np.angle(np.exp(1j * (facing(p) - front))))

    assert abs(turned(poses[stand])) < 1e-6 and abs(turned(poses[-1])) < 1e-6
    walk_dir = np.arctan2(*(np.array([0.0, 0.4]) - np.array([-sy.ENTRY_X_M, 0.1])))
    assert abs(abs(turned(poses[0])) - abs(walk_dir)) < 0.15  # walking sideways into the room
    walk = int(np.ceil(np.linalg.norm(np.array([0.0, 0.4]) - [-sy.ENTRY_X_M, 0.1]) / sy.WALK_SPEED_M_S * sy.FPS))
    turn = int(round(sy.TURN_S * sy.FPS))
    assert stand == walk + turn
    # half way through the turn (over the last TURN_S of the walk) the body has turned half way
    assert abs(abs(turned(poses[walk - turn // 2 - 1])) - abs(walk_dir) * (turn // 2 + 1) / turn) < 0.15
    assert abs(turned(poses[walk])) < 0.1
    # the gait (a walk on the spot at the frame rate) fades out over the last 1.5 TURN_S of the walk-in
    from bodystudio.capture.motion import motion_sequence

    gait = motion_sequence("walk", stand, sk, 0, fps=sy.FPS)
    root = int(np.flatnonzero(sk.parents < 0)[0])
    rest = np.arange(sk.n_bones) != root
    for k in (2, walk - turn, walk, stand - 1):
        fade = float(np.clip((walk + turn - k) / (1.5 * turn), 0.0, 1.0))
        assert np.allclose(poses[k].rotations[rest], gait[k].rotations[rest] * fade, atol=1e-12), k
    assert np.abs(gait[2].rotations[rest]).max() > 0.05


# ------------------------------------------------------------------------------------------ the SDK

def test_sdk_player_mask_jitters_only_at_the_edges_and_follows_the_truth():
    yy, xx = np.mgrid[:96, :128]
    labels = np.zeros((96, 128), np.uint8)
    labels[((yy - 48) ** 2 + (xx - 40) ** 2) < 25**2] = 1
    labels[20:80, 80:110] = 2
    depth = np.full(labels.shape, 2.0)
    depth[48, 40] = 0.0
    depth[50, 95] = -1.0
    outs = [sy.sdk_player_mask(labels, depth, np.random.default_rng(s)) for s in range(6)]
    from scipy import ndimage

    edge = np.zeros(labels.shape, bool)
    for k in (1, 2):
        m = labels == k
        edge |= ndimage.binary_dilation(m, iterations=7) & ~ndimage.binary_erosion(m, iterations=7)
    for out in outs:
        assert out.dtype == np.uint8 and out.shape == labels.shape
        assert out[48, 40] == 0 and out[50, 95] == 0  # no depth, no player
        inner = ~edge & (depth > 0)
        assert np.array_equal(out[inner], labels[inner])
        assert set(np.unique(out)) <= {0, 1, 2}
    changed = np.array([(o != labels) & (depth > 0) for o in outs])
    assert changed.any(axis=0)[edge].mean() > 0.2  # the boundary moves, differently per frame
    assert (changed.sum(axis=(1, 2)) > 20).all() and not np.array_equal(outs[0], outs[1])
    # about jitter_px: a larger amplitude moves the boundary farther
    big = sy.sdk_player_mask(labels, depth, np.random.default_rng(0), jitter_px=4.0)
    none = sy.sdk_player_mask(labels, depth, np.random.default_rng(0), jitter_px=0.0)
    assert (big != labels).sum() > 1.5 * (outs[0] != labels).sum()
    truth = labels.copy()
    truth[depth <= 0] = 0
    assert np.array_equal(none, truth)  # no jitter: the truth (pixel centres at the boundary's half pixel)
    assert not sy.sdk_player_mask(np.zeros((16, 16), np.uint8), np.ones((16, 16)), np.random.default_rng(0)).any()


def test_sdk_player_mask_uses_a_smooth_field_per_player():
    """The boundary field is smooth along the contour (correlated over ~8 px), not per-pixel noise."""
    labels = np.zeros((96, 128), np.uint8)
    labels[:, :64] = 1
    out = sy.sdk_player_mask(labels, np.ones(labels.shape), np.random.default_rng(3), jitter_px=3.0)
    edge_col = np.array([np.flatnonzero(row == 0)[0] if (row == 0).any() else 128 for row in out])
    steps = np.abs(np.diff(edge_col))
    assert np.median(steps) <= 1 and (steps <= 2).mean() > 0.9 and edge_col.std() > 0.5


def test_tracked_joints_reports_bodies_enough_in_view():
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.body.pose import Pose
    from bodystudio.body.skinning import posed_joints

    _, body = _model_and_body()
    sk = body.skeleton
    sensor = sy.mirror_sensor("v2")

    def joints(x, z):
        h, t = posed_joints(sk, Pose(np.zeros((sk.n_bones, 3)), np.array([x, 0.0, z])))
        return kinect_joints(sk, h, t, "v2"), h, t

    truth, h, t = joints(0.0, 0.4)
    positions, tracked = sy.tracked_joints(truth, sensor, h, t, sk, "v2", np.random.default_rng(0))
    assert positions.shape == truth.shape and tracked.all()
    err = np.linalg.norm(positions - truth, axis=1)
    assert 0.003 < np.median(err) < 0.06  # the tracker's noise (1 cm, 3 % bone jitter)
    out_truth, out_h, out_t = joints(3.0, 0.4)
    assert sy.tracked_joints(out_truth, sensor, out_h, out_t, sk, "v2", np.random.default_rng(0)) is None
    # half in view: reported with min_visible 0.3, the joints outside not tracked; refused at the default 0.7
    for x in np.linspace(0.8, 2.0, 25):
        truth, h, t = joints(x, 0.4)
        uv, z = sensor.depth.project_with_depth(truth)
        inside = sensor.depth.in_image(np.nan_to_num(uv, nan=-1.0))
        if 0.35 < inside.mean() < 0.65:
            break
    assert 0.35 < inside.mean() < 0.65
    assert sy.tracked_joints(truth, sensor, h, t, sk, "v2", np.random.default_rng(0)) is None
    pos, tr = sy.tracked_joints(truth, sensor, h, t, sk, "v2", np.random.default_rng(0), min_visible=0.3)
    assert np.array_equal(tr, inside) and np.isfinite(pos).all()
    # beyond the depth range: not in view
    far, hf, tf = joints(0.0, -6.0)
    assert sy.tracked_joints(far, sensor, hf, tf, sk, "v2", np.random.default_rng(0)) is None
    near, hn, tn = joints(0.0, 2.8)  # 20 cm in front of the sensor: closer than its range
    assert sy.tracked_joints(near, sensor, hn, tn, sk, "v2", np.random.default_rng(0)) is None


# ------------------------------------------------------------------------------------------ depth and labels

@functools.cache
def _static_v1():
    sensor = sy.mirror_sensor("v1")
    return sensor, sy.static_room_depth(sy.mirror_room(), sensor)


def test_static_room_depth_is_the_rooms_render_with_its_own_dropouts():
    from bodystudio.capture.render import render

    sensor = sy.mirror_sensor("v1")
    room = sy.mirror_room()
    static = sy.static_room_depth(room, sensor)  # called here, not the cached one (a mutant must run it)
    assert np.array_equal(static.missing, _static_v1()[1].missing)
    ref = render(room.vertices, room.faces, sensor.depth)
    assert np.array_equal(static.depth, ref.depth.astype(np.float64)) and static.depth.dtype == np.float64
    proj = render(room.vertices, room.faces, sensor.projector).depth
    assert np.array_equal(static.projector_depth, proj.astype(np.float64))
    assert static.missing.dtype == bool and 0.0 < static.missing.mean() < 0.2  # shadows behind the furniture
    assert (static.depth > 0).mean() > 0.95


def _box_actor(x=0.0, z=0.6):
    V, F = sy._box((x - 0.25, 0.3, z - 0.15), (x + 0.25, 1.7, z + 0.15))
    return V, F


def test_kinect_depth_frame_puts_the_actor_in_front_of_the_room_with_its_noise():
    sensor, static = _static_v1()
    V, F = _box_actor()
    depth, body, in_front = sy.kinect_depth_frame(static, V, F, sensor, np.random.default_rng(0))
    assert depth.shape == static.depth.shape and in_front.sum() > 500
    assert np.array_equal(in_front, body.mask & ((body.depth < static.depth) | (static.depth <= 0)))
    # the actor's depth where it is seen (noise: quantised disparity, a few mm at 2.4 m); the room elsewhere
    seen = in_front & (depth > 0)
    assert seen.mean() / in_front.mean() > 0.8
    assert np.median(np.abs(depth[seen] - body.depth[seen])) < 0.01
    room = ~in_front & (depth > 0) & (static.depth > 0)
    assert np.median(np.abs(depth[room] - static.depth[room])) < 0.03
    # a projector shadow beside the box (the projector is 7.5 cm to the side): missing room pixels next to it
    from scipy import ndimage

    ring = ndimage.binary_dilation(in_front, iterations=6) & ~in_front
    assert (depth[ring] == 0).mean() > (depth[~ring & ~in_front] == 0).mean() + 0.05
    # the room's own dropouts stay where the actor does not cover them
    far = ~ndimage.binary_dilation(in_front, iterations=12)
    assert (depth[far & static.missing] == 0).mean() > 0.95
    # no actor: the room only (same noise model)
    empty, body0, front0 = sy.kinect_depth_frame(static, np.zeros((0, 3)), np.zeros((0, 3), np.int64), sensor,
                                                 np.random.default_rng(0))
    assert not front0.any() and not body0.mask.any() and body0.triangle_id.min() == -1
    assert (empty[static.missing] == 0).all() and (empty > 0).mean() > 0.8
    assert np.median(np.abs(empty[empty > 0] - static.depth[empty > 0])) < 0.03
    lo, hi = sensor.depth_range_m
    assert ((empty == 0) | ((empty >= lo) & (empty <= hi))).all()


def test_kinect_depth_frame_shadow_band_and_same_result_per_seed():
    sensor, static = _static_v1()
    V, F = _box_actor(0.3)
    a = sy.kinect_depth_frame(static, V, F, sensor, np.random.default_rng(5))[0]
    b = sy.kinect_depth_frame(static, V, F, sensor, np.random.default_rng(5))[0]
    assert np.array_equal(a, b)
    # the shadow is on one side of the box only (the projector's side), within the band
    _, body, in_front = sy.kinect_depth_frame(static, V, F, sensor, np.random.default_rng(5))
    cols = np.flatnonzero(in_front.any(axis=0))
    rows = np.flatnonzero(in_front.any(axis=1))
    mid = slice(rows[len(rows) // 4], rows[3 * len(rows) // 4])
    left = (a[mid, cols[0] - 5:cols[0]] == 0).mean()
    right = (a[mid, cols[-1] + 1:cols[-1] + 6] == 0).mean()
    assert max(left, right) > 0.45 and max(left, right) > 2 * min(left, right)


def test_labelled_render_labels_each_actor_and_hides_what_is_behind_the_room():
    cam = sy.mirror_sensor("v1").color
    V1, F1 = _box_actor(-0.5)
    V2, F2 = _box_actor(0.5)
    room_depth = np.zeros((cam.height, cam.width))
    r, labels, V, F = sy._labelled_render([(V1, F1), (V2, F2)], cam, room_depth)
    assert np.array_equal(V, np.r_[V1, V2]) and np.array_equal(F, np.r_[F1, F2 + 8])
    assert set(np.unique(labels)) == {0, 1, 2} and labels.dtype == np.uint8
    c1 = np.mean(np.nonzero(labels == 1)[1])
    c2 = np.mean(np.nonzero(labels == 2)[1])
    assert c1 < c2  # actor 1 at -x is on the left of the image
    assert np.array_equal(r.mask, labels > 0) and (r.triangle_id[labels == 0] == -1).all()
    assert (r.depth[labels == 0] == 0).all() and (r.depth[labels > 0] > 0).all()
    assert (r.triangle_id[labels == 2] >= 12).all() and (r.triangle_id[labels == 1] < 12).all()
    # a wall 2 m away hides nothing; a wall in front of actor 2's depth hides it
    near = np.where(np.arange(cam.width)[None, :] > cam.width // 2, 1.0, 0.0) * np.ones((cam.height, 1))
    r2, labels2, _, _ = sy._labelled_render([(V1, F1), (V2, F2)], cam, near)
    assert (labels2 == 2).sum() == 0 and (labels2 == 1).sum() == (labels == 1).sum()
    assert not r2.mask[:, cam.width // 2 + 1:].any()


def test_player_labels_map_render_order_to_player_ids():
    labels = np.array([[0, 1, 2], [2, 1, 0]], np.uint8)
    out = sy._player_labels(labels, [{"player": 2}, {"player": 1}])
    assert np.array_equal(out, [[0, 2, 1], [1, 2, 0]]) and out.dtype == np.uint8
    assert np.array_equal(sy._player_labels(labels[:, :2] * 0 + np.array([0, 1], np.uint8), [{"player": 4}]),
                          [[0, 4], [0, 4]])


# ------------------------------------------------------------------------------------------ the session

@pytest.mark.parametrize("kw, message", [
    ({"actors": 3}, "--actors 3: a mirror session has 1 or 2 actors"),
    ({"n_frames": 10}, "--frames 10: need 11..99999 (the first 10 show the empty room)"),
    ({"n_frames": 100000}, "--frames 100000: need 11..99999 (the first 10 show the empty room)"),
    ({"n_frames": 20.0}, "--frames 20.0: need 11..99999 (the first 10 show the empty room)"),
    ({"motion": "dance"}, "unknown motion 'dance'; valid: arms_raise, walk, turn, arm_flex, a_pose, t_pose"),
    ({"edited_players": (2,)}, "edited players [2]: choose among the actors' players 1..1"),
    ({"edited_players": ()}, "edited players []: choose among the actors' players 1..1"),
    ({"actors": 2, "edited_players": (0, 1)}, "edited players [0, 1]: choose among the actors' players 1..2"),
    ({"edits": {"taller": 2.0}}, "edit taller=2.0 is out of range: use -0.3 to +0.3 m"),
    ({"version": "v3"}, "--kinect 'v3' is not a Kinect version; valid: v1, v2"),
])
def test_synth_mirror_session_refuses_bad_arguments_before_writing(tmp_path, kw, message):
    out = tmp_path / "s"
    args = dict(subject_seed=3, n_frames=12)
    args.update(kw)
    with pytest.raises(InputError) as info:
        sy.synth_mirror_session(out, model=object(), **args)
    assert str(info.value) == message and not out.exists()


def test_synth_mirror_session_refuses_an_existing_folder(tmp_path):
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    (tmp_path / "file").write_text("x")
    for p in (tmp_path / "full", tmp_path / "file"):
        with pytest.raises(InputError) as info:
            sy.synth_mirror_session(p, subject_seed=3, n_frames=12, model=object())
        assert str(info.value) == f"{p}: output exists and is not an empty folder; choose a new folder"


def _cast_member(player=1, edits=None):
    model, body = _model_and_body()
    target, c_s, c_t = sy.target_rest_body(model, body, edits or {})
    poses, stand = sy.actor_poses(body.skeleton, 12, 10, (0.0, 0.4), -1.0, "a_pose", 0, walk_in=False)
    return {"player": player, "subject_seed": 3, "phenotype": types.SimpleNamespace(to_dict=lambda: {"p": 1}),
            "local": {"l": 2}, "body": body, "target": target, "c_s": c_s, "c_t": c_t, "poses": poses,
            "albedo": np.full((body.n_vertices, 3), 0.5), "measured": {"stature_m": 1.7}, "enter_frame": 10,
            "stand_frame": stand, "target_measured": {"stature_m": 1.8} if edits else None}


def test_actor_record_and_arrays():
    a = _cast_member(1, {"taller": 0.1})
    rec = sy._actor_record(a)
    assert rec == {"player": 1, "subject_seed": 3, "phenotype": {"p": 1}, "local": {"l": 2},
                   "measured": {"stature_m": 1.7}, "enter_frame": 10, "stand_frame": 10,
                   "target_measured_model": {"stature_m": 1.8}}
    assert "target_measured_model" not in sy._actor_record(dict(a, target_measured=None))
    b = dict(a, player=2, albedo=np.full((a["body"].n_vertices, 3), 0.25))
    arr = sy._actor_arrays([a, b], a["body"].faces)
    assert arr["players"].tolist() == [1, 2] and arr["faces"] is a["body"].faces
    for key, get in (("source_rest_vertices", lambda m: m["body"].vertices),
                     ("target_rest_vertices", lambda m: m["target"].vertices),
                     ("source_coeffs", lambda m: m["c_s"]), ("target_coeffs", lambda m: m["c_t"]),
                     ("source_heads", lambda m: m["body"].skeleton.heads),
                     ("source_tails", lambda m: m["body"].skeleton.tails),
                     ("target_heads", lambda m: m["target"].skeleton.heads),
                     ("target_tails", lambda m: m["target"].skeleton.tails), ("albedo", lambda m: m["albedo"])):
        assert np.array_equal(arr[key], np.stack([get(a), get(b)])), key
    assert not np.allclose(arr["source_rest_vertices"][0], arr["target_rest_vertices"][0])
    assert set(arr) == {"players", "faces", "source_rest_vertices", "target_rest_vertices", "source_coeffs",
                        "target_coeffs", "source_heads", "source_tails", "target_heads", "target_tails", "albedo"}


class _Writer:
    """Records what the session writer is handed."""

    def __init__(self, *args, **kw):
        self.args, self.kw, self.calls = args, kw, {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def __getattr__(self, name):
        if not name.startswith("write_"):
            raise AttributeError(name)

        def record(*args, **kw):
            self.calls.setdefault(name, []).append((args, kw))
        return record


@functools.cache
def _plate_v1():
    sensor, static = _static_v1()
    plate, room_depth = sy.room_plate(sy.mirror_room(), sensor.color, 0)
    return sensor, static, plate, room_depth


def _frame_of(writer, name, i=None):
    return {args[0]: (args[1:], kw) for args, kw in writer.calls.get(name, [])}


def test_write_frame_of_the_actor_with_its_ground_truth():
    from bodystudio.body.kinect import kinect_joint_names, kinect_joints
    from bodystudio.body.pose import transfer_pose
    from bodystudio.body.skinning import posed_joints

    sensor, static, plate, room_depth = _plate_v1()
    a = _cast_member(1, {"taller": 0.1})
    names = kinect_joint_names("v1")
    w = _Writer()
    sy._write_frame(w, 11, [a], static, sensor, plate, room_depth, names, True, np.random.default_rng(0))
    gt = _frame_of(w, "write_gt_mirror")[11][0][0]
    pose = a["poses"][11]
    V, _ = a["body"].pose(pose)
    h, t = posed_joints(a["body"].skeleton, pose)
    assert gt["players"].tolist() == [1] and gt["reported"].tolist() == [True]
    assert gt["source_vertices"].dtype == np.float32 and np.allclose(gt["source_vertices"][0], V, atol=1e-6)
    assert np.allclose(gt["kinect_joints"][0], kinect_joints(a["body"].skeleton, h, t, "v1"))
    assert gt["kinect_joints"].shape == (1, len(names), 3)
    assert np.array_equal(gt["pose_rotations"][0], pose.rotations)
    assert np.array_equal(gt["pose_translations"][0], pose.translation)
    Vt, _ = a["target"].pose(transfer_pose(pose, a["body"].skeleton, a["target"].skeleton))
    assert np.allclose(gt["target_vertices"][0], Vt, atol=1e-6)
    assert np.ptp(Vt[:, 1]) - np.ptp(V[:, 1]) == pytest.approx(0.1, abs=0.02)
    # the SDK: one body of player 1 with the joint names; the player mask inside the actor's depth pixels
    (bodies,), kw = _frame_of(w, "write_kinect_bodies")[11]
    assert kw == {"joint_set": "v1"} and len(bodies) == 1 and bodies[0]["player"] == 1
    assert bodies[0]["names"] == names and bodies[0]["tracked"].mean() > 0.8
    assert np.linalg.norm(bodies[0]["positions"] - gt["kinect_joints"][0], axis=1).mean() < 0.06
    (depth,), _ = _frame_of(w, "write_kinect_depth")[11]
    (player,), _ = _frame_of(w, "write_kinect_player")[11]
    assert depth.shape == (240, 320) and player.shape == depth.shape and (player == 1).sum() > 300
    assert (depth[player > 0] > 0).all() and np.median(depth[player == 1]) == pytest.approx(2.6, abs=0.3)
    # colour: the actor over the plate with sensor noise; its labels; the target the same frame edited
    (rgb,), _ = _frame_of(w, "write_kinect_rgb")[11]
    persons = {kw.get("target", False): args[1] for args, kw in w.calls["write_gt_person"]}
    (trgb,), _ = _frame_of(w, "write_gt_target_rgb")[11]
    person, tperson = persons[False], persons[True]
    assert rgb.dtype == np.uint8 and rgb.shape == plate.shape and (person == 1).sum() > 2000
    assert set(np.unique(person)) == {0, 1} and set(np.unique(tperson)) == {0, 1}
    top = np.flatnonzero((person == 1).any(axis=1))[0]
    assert top - np.flatnonzero((tperson == 1).any(axis=1))[0] > 10  # taller: the head higher
    bg = (person == 0) & (tperson == 0)
    noise = rgb[bg].astype(float) - plate[bg]
    assert 1.5 < noise.std() < 2.5 and abs(noise.mean()) < 0.2  # SENSOR_NOISE_STD 2 grey levels
    assert np.array_equal(trgb[bg], rgb[bg])  # the same noise in the target render
    assert np.abs(rgb[person == 1].astype(float) - plate[person == 1]).mean() > 10
    # not edited: no target render at all
    w2 = _Writer()
    sy._write_frame(w2, 11, [a], static, sensor, plate, room_depth, names, False, np.random.default_rng(0))
    assert "write_gt_target_rgb" not in w2.calls and len(w2.calls["write_gt_person"]) == 1
    assert "target_vertices" not in _frame_of(w2, "write_gt_mirror")[11][0][0]


def test_write_frame_of_the_empty_room():
    from bodystudio.body.kinect import kinect_joint_names

    sensor, static, plate, room_depth = _plate_v1()
    a = _cast_member(1, {"taller": 0.1})
    names = kinect_joint_names("v1")
    w = _Writer()
    sy._write_frame(w, 3, [a], static, sensor, plate, room_depth, names, True, np.random.default_rng(1))
    gt = _frame_of(w, "write_gt_mirror")[3][0][0]
    n, b = a["body"].n_vertices, a["body"].skeleton.n_bones
    assert gt["players"].shape == (0,) and gt["source_vertices"].shape == (0, n, 3)
    assert gt["kinect_joints"].shape == (0, len(names), 3) and gt["pose_rotations"].shape == (0, b, 3)
    assert gt["pose_translations"].shape == (0, 3) and gt["reported"].shape == (0,)
    assert gt["target_vertices"].shape == (0, n, 3)
    (bodies,), _ = _frame_of(w, "write_kinect_bodies")[3]
    (player,), _ = _frame_of(w, "write_kinect_player")[3]
    (depth,), _ = _frame_of(w, "write_kinect_depth")[3]
    assert bodies == [] and not player.any() and (depth > 0).mean() > 0.8
    (rgb,), _ = _frame_of(w, "write_kinect_rgb")[3]
    (trgb,), _ = _frame_of(w, "write_gt_target_rgb")[3]
    persons = [args[1] for args, kw in w.calls["write_gt_person"]]
    assert all(not p.any() and p.shape == plate.shape[:2] and p.dtype == np.uint8 for p in persons)
    assert np.array_equal(rgb, trgb) and 1.5 < (rgb.astype(float) - plate).std() < 2.5


def test_write_frame_of_an_actor_out_of_the_trackers_view():
    """An actor present but not reported by the tracker: in the ground truth (not reported), not in the SDK's
    bodies nor its player mask, still in the colour image and the true person labels."""
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.body.pose import Pose

    sensor, static, plate, room_depth = _plate_v1()
    a = _cast_member(2)
    a["poses"] = [Pose(p.rotations, p.translation + [1.3, 0.0, 0.0]) if p is not None else None
                  for p in a["poses"]]
    w = _Writer()
    sy._write_frame(w, 11, [a], static, sensor, plate, room_depth, kinect_joint_names("v1"), False,
                    np.random.default_rng(0))
    gt = _frame_of(w, "write_gt_mirror")[11][0][0]
    (bodies,), _ = _frame_of(w, "write_kinect_bodies")[11]
    (player,), _ = _frame_of(w, "write_kinect_player")[11]
    person = w.calls["write_gt_person"][0][0][1]
    assert gt["players"].tolist() == [2] and gt["reported"].tolist() == [False]
    assert bodies == [] and not player.any() and set(np.unique(person)) == {0, 2}


def test_synth_mirror_session_assembles_the_cast_and_metadata(tmp_path, monkeypatch, caplog):
    """The setup of a session with its writer and frame writer replaced by recorders: two actors, the edit on
    player 2 only, standing in place; the metadata, the subject and actor records, the frames in order; every
    argument handed to the writer and the frame writer, the timings and the closing log line."""
    import logging
    import re
    import time

    import bodystudio.capture.session as session_mod
    from bodystudio.body import build_body
    from bodystudio.body.measure import measure_attributes
    from bodystudio.body.population import sample_subject
    from bodystudio.geometry.camera import CameraRig

    model, _ = _model_and_body()
    writers, frames = [], []

    def writer(*args, **kw):
        writers.append(_Writer(*args, **kw))
        return writers[-1]

    monkeypatch.setattr(session_mod, "SessionWriter", writer)
    monkeypatch.setattr(session_mod, "open_session", lambda p: ("opened", p))
    monkeypatch.setattr(sy, "_write_frame", lambda w, i, cast, static, sensor, plate, rd, names, edited, rng:
                        frames.append((i, cast, sensor.version, names, edited, plate.shape, rd.shape, w, static,
                                       rng, plate, sensor)))
    timings = {}
    wall, cpu = time.perf_counter(), time.process_time()
    with caplog.at_level(logging.INFO, logger=sy.log.name):
        out = sy.synth_mirror_session(tmp_path / "s", subject_seed=5, n_frames=12, actors=2,
                                      edits={"taller": 0.1}, version="v1", motion="a_pose", seed=4, model=model,
                                      edited_players=(2,), walk_in=False, timings=timings)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    assert out == ("opened", tmp_path / "s")
    (w,) = writers
    assert w.args[0] == tmp_path / "s" and w.kw["source"] == "synthetic"
    assert w.kw["command"] == "bodystudio synth mirror"
    meta = w.kw["metadata"]
    assert meta == {"generator": "bodystudio synth mirror", "subject_seed": 5, "actors": 2, "fps": 30.0,
                    "kinect": "v1", "seed": 4, "motion": "a_pose", "edits": {"taller": 0.1},
                    "edited_players": [2], "template": "6k", "background_frames": 10, "noise_std": 2.0,
                    "walk_in": False, "actor_frames": [{"player": 1, "enter_frame": 10, "stand_frame": 10},
                                                       {"player": 2, "enter_frame": 10, "stand_frame": 10}]}
    assert [f[0] for f in frames] == list(range(12)) and all(f[2] == "v1" and f[4] is True for f in frames)
    assert frames[0][3] == sy.kinect_joint_names("v1") and frames[0][5] == (480, 640, 3)
    assert frames[0][6] == (480, 640)
    cast = frames[0][1]
    assert [a["player"] for a in cast] == [1, 2] and [a["subject_seed"] for a in cast] == [5, 6]
    assert cast[0]["target"] is cast[0]["body"] and cast[1]["target"] is not cast[1]["body"]
    assert cast[0]["target_measured"] is None and cast[1]["target_measured"]["stature_m"] == pytest.approx(
        model.measure(cast[1]["c_s"])["stature_m"] + 0.1, abs=2e-3)
    for a, spot in zip(cast, sy.STAND_SPOTS[2], strict=True):
        assert a["poses"][9] is None and np.allclose(a["poses"][11].translation, (spot[0], 0.0, spot[1]))
        assert a["stand_frame"] == 10 and a["enter_frame"] == 10
        assert a["measured"]["stature_m"] == pytest.approx(np.ptp(a["body"].vertices[:, 1]), abs=0.02)
        assert a["albedo"].shape == (a["body"].n_vertices, 3) and a["body"].resolution == "6k"
    assert not np.allclose(cast[0]["albedo"][:10], cast[1]["albedo"][:10])
    (subject_args, subject_kw), = w.calls["write_gt_subject"]
    assert subject_kw["template"] == "6k" and subject_kw["bone_names"] == list(cast[0]["body"].skeleton.bone_names)
    assert subject_kw["stature_m"] == cast[0]["measured"]["stature_m"] and len(subject_kw["actors"]) == 2
    assert subject_kw["actors"][1]["target_measured_model"] == cast[1]["target_measured"]
    assert subject_kw["n_vertices"] == cast[0]["body"].n_vertices and subject_kw["mass_kg"] == \
        cast[0]["measured"]["mass_kg"]
    (sensor,), _ = w.calls["write_kinect_calibration"][0]
    assert sensor.version == "v1" and sensor.depth.width == 320
    (arrays,), _ = w.calls["write_gt_mirror_actors"][0]
    assert arrays["players"].tolist() == [1, 2] and arrays["faces"] is cast[0]["body"].faces
    assert timings["n_frames"] == 12 and timings["setup_s"] > 0 and timings["frames_s"] >= 0
    assert timings["ms_per_frame_cpu"] == pytest.approx(1e3 * timings["frames_cpu_s"] / 12)
    assert 0 <= timings["setup_s"] + timings["frames_s"] <= wall and timings["frames_s"] >= 0
    assert 0 <= timings["setup_cpu_s"] + timings["frames_cpu_s"] <= cpu + 1e-3 and timings["frames_cpu_s"] >= 0
    (message,) = [r.getMessage() for r in caplog.records if r.name == sy.log.name and r.getMessage().startswith(
        "wrote")]
    assert re.fullmatch(rf"wrote {re.escape(str(tmp_path / 's'))}: 12 frames, 2 actor\(s\), setup \d+\.\d s, "
                        r"total \d+\.\d s", message), message
    # every argument handed on: the writer's empty camera rig, the subject record, the frame writer's arguments
    assert len(w.args) == 2 and isinstance(w.args[1], CameraRig)
    assert subject_args[0] == cast[0]["phenotype"].to_dict() and subject_args[1] is cast[0]["local"]
    assert subject_kw["rig"] is model.rig
    assert all(f[7] is w and isinstance(f[8], sy.StaticDepth) and f[9] is frames[0][9] for f in frames)
    assert frames[0][9].bit_generator.state == np.random.default_rng([4, 5, 2]).bit_generator.state
    assert np.array_equal(frames[0][10], sy.room_plate(sy.mirror_room(), frames[0][11].color, 4)[0])
    for k, a in enumerate(cast):
        phenotype, local = sample_subject(5 + k)
        assert a["phenotype"].to_dict() == phenotype.to_dict()
        assert np.array_equal(a["albedo"], sy.clothing_albedo(a["body"], 5 + k))
        assert a["measured"] == measure_attributes(a["body"].vertices, a["body"].faces,
                                                      vertex_ids=a["body"].vertex_ids, muscularity=phenotype.muscle)
    body = build_body(*sample_subject(6), resolution=model.resolution, rig=model.rig)
    assert np.allclose(cast[1]["body"].vertices, body.vertices, atol=1e-9)
    # one actor, walking in, no edits: nobody edited; the actor enters at frame 10
    frames.clear()
    sy.synth_mirror_session(tmp_path / "t", subject_seed=5, n_frames=12, version="v1", model=model)
    meta = writers[-1].kw["metadata"]
    assert meta["edited_players"] == [] and meta["edits"] == {} and meta["actors"] == 1 and meta["walk_in"] is True
    assert meta["actor_frames"][0]["enter_frame"] == 10 and meta["actor_frames"][0]["stand_frame"] == 12  # the walk cut
    assert frames[0][4] is False and frames[0][1][0]["target"] is frames[0][1][0]["body"]
    a = frames[0][1][0]  # the walk of the default seed (0) + 101, from the first entry side
    poses, _ = sy.actor_poses(a["body"].skeleton, 12, 10, sy.STAND_SPOTS[1][0], sy.ENTRY_SIDE[0], "arms_raise", 101)
    assert all(np.array_equal(p.rotations, q.rotations) and np.array_equal(p.translation, q.translation)
               for p, q in zip(a["poses"][10:], poses[10:], strict=True))


def test_time_synth_mirror_times_a_taller_edit_session(tmp_path, monkeypatch):
    seen = {}

    def synth(folder, subject_seed, n_frames, actors, edits, version, timings):
        seen.update(folder=folder, subject_seed=subject_seed, n_frames=n_frames, actors=actors, edits=edits,
                    version=version)
        timings.update(setup_s=1.5, frames_s=2.0)

    monkeypatch.setattr(sy, "synth_mirror_session", synth)
    out = sy.time_synth_mirror(tmp_path / "s", n_frames=12, actors=2, version="v1")
    assert out == {"setup_s": 1.5, "frames_s": 2.0}
    assert seen == {"folder": tmp_path / "s", "subject_seed": 3, "n_frames": 12, "actors": 2,
                    "edits": {"taller": 0.1}, "version": "v1"}
    sy.time_synth_mirror(tmp_path / "t")
    assert seen["n_frames"] == 40 and seen["actors"] == 1 and seen["version"] == "v2"


def test_write_frame_noise_is_the_first_draw_added_and_clipped_to_8_bits():
    """The colour noise: the rng's first draw (SENSOR_NOISE_STD grey levels) added to the plate, rounded and
    clipped to 0..255 exactly (a black and a white band saturate); the frame index on every labels write."""
    from bodystudio.body.kinect import kinect_joint_names

    sensor, static, plate, room_depth = _plate_v1()
    plate = plate.copy()
    plate[:20], plate[20:40] = 0, 255
    a = _cast_member(1, {"taller": 0.1})
    w = _Writer()
    sy._write_frame(w, 3, [a], static, sensor, plate, room_depth, kinect_joint_names("v1"), True,
                    np.random.default_rng(5))
    noise = np.random.default_rng(5).normal(0.0, sy.SENSOR_NOISE_STD, plate.shape).astype(np.float32)
    expected = np.clip(np.round(plate.astype(np.float32) + noise), 0, 255).astype(np.uint8)
    (rgb,), _ = _frame_of(w, "write_kinect_rgb")[3]
    (trgb,), _ = _frame_of(w, "write_gt_target_rgb")[3]
    assert np.array_equal(rgb, expected) and np.array_equal(trgb, expected)
    assert rgb[:20].min() == 0 and rgb[20:40].max() == 255 and (rgb[20:40] < 255).any()
    assert [args[0] for args, kw in w.calls["write_gt_person"]] == [3, 3]


def test_write_frame_of_two_actors_in_their_clothing_colours():
    """Two actors side by side (players 1 and 2, the second one's faces offset by the first one's vertices): each
    in the depth, the SDK mask and the labels where it stands, both drawn in their own albedo (green, blue) in the
    colour image and the target render; the target's vertices float32."""
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.body.pose import Pose

    sensor, static, plate, room_depth = _plate_v1()
    cast = []
    for player, dx, colour in ((1, -0.4, (0.0, 1.0, 0.0)), (2, 0.4, (0.0, 0.0, 1.0))):
        a = _cast_member(player, {"taller": 0.1})
        a["poses"] = [Pose(p.rotations, p.translation + [dx, 0.0, 0.0]) if p is not None else None
                      for p in a["poses"]]
        a["albedo"] = np.tile(colour, (a["body"].n_vertices, 1))
        cast.append(a)
    w = _Writer()
    sy._write_frame(w, 11, cast, static, sensor, plate, room_depth, kinect_joint_names("v1"), True,
                    np.random.default_rng(0))
    gt = _frame_of(w, "write_gt_mirror")[11][0][0]
    assert gt["players"].tolist() == [1, 2] and gt["target_vertices"].dtype == np.float32
    (depth,), _ = _frame_of(w, "write_kinect_depth")[11]
    (player,), _ = _frame_of(w, "write_kinect_player")[11]
    cols = {p: np.flatnonzero((player == p).any(axis=0)) for p in (1, 2)}
    assert (player == 1).sum() > 300 and (player == 2).sum() > 300
    assert cols[1].mean() < depth.shape[1] / 2 < cols[2].mean()  # player 1 on the left (x < 0)
    assert np.median(depth[player == 2]) == pytest.approx(2.6, abs=0.3)
    (rgb,), _ = _frame_of(w, "write_kinect_rgb")[11]
    (trgb,), _ = _frame_of(w, "write_gt_target_rgb")[11]
    persons = {kw.get("target", False): args[1] for args, kw in w.calls["write_gt_person"]}
    for image, person in ((rgb, persons[False]), (trgb, persons[True])):
        assert set(np.unique(person)) == {0, 1, 2}
        g = image[person == 1].astype(float).mean(axis=0)
        assert g[1] > g[0] + 30 and g[1] > g[2] + 30  # green: the middle channel in RGB and BGR alike
        b = image[person == 2].astype(float).mean(axis=0)
        assert max(b[0], b[2]) > b[1] + 30  # blue: not the skin's colour nor the green


def test_actor_poses_frame_by_frame_with_the_ease_and_the_standing_motion():
    """Every frame of a walk-in (seed 3, 15 fps): on the floor (y = 0) at ``start + ease(s) (stand - start)``
    with ``ease = 1 - (1 - s)^2`` over the last 30 % of the walk, heading along the walk and turning over the
    last TURN_S, the gait of this seed and frame rate; then ``motion`` of the stand frames' length at the spot."""
    from bodystudio.body.pose import Pose
    from bodystudio.capture.motion import motion_sequence

    _, body = _model_and_body()
    sk = body.skeleton
    fps, seed, n, enter, spot = 15.0, 3, 60, 4, np.array([0.2, 0.5])
    poses, stand = sy.actor_poses(sk, n, enter, tuple(spot), -1.0, "arms_raise", seed, fps=fps)
    start = np.array([-sy.ENTRY_X_M, spot[1] - 0.3])
    walk = int(np.ceil(np.linalg.norm(spot - start) / sy.WALK_SPEED_M_S * fps))
    turn = int(round(sy.TURN_S * fps))
    n_walk = walk + turn
    assert stand == enter + n_walk and len(poses) == n and n - stand > 5
    heading = float(np.arctan2(*(spot - start)))
    gait = motion_sequence("walk", n_walk, sk, seed, fps=fps)
    eased = 0
    for k in range(n_walk):
        s = min(1.0, (k + 1) / walk)
        ease = 1.0 - (1.0 - s) ** 2 if s > 0.7 else s
        eased += 0.7 < s < 1.0
        p = poses[enter + k]
        xz = start + ease * (spot - start)
        assert np.allclose(p.translation, (xz[0], 0.0, xz[1]), atol=1e-12), k
        fade = float(np.clip((walk + turn - k) / (1.5 * turn), 0.0, 1.0))
        t = float(np.clip((k - walk + turn) / turn, 0.0, 1.0))
        want = sy._yaw(sk, Pose(gait[k].rotations * fade, np.zeros(3)), heading * (1.0 - t), p.translation)
        assert np.allclose(p.rotations, want.rotations, atol=1e-12), k
    assert eased >= 3
    standing = motion_sequence("arms_raise", n - stand, sk, seed, fps=fps)
    for k in range(n - stand):
        want = sy._yaw(sk, standing[k], 0.0, (spot[0], 0.0, spot[1]))
        assert np.allclose(poses[stand + k].rotations, want.rotations, atol=1e-12), k
        assert np.allclose(poses[stand + k].translation, (spot[0], 0.0, spot[1]), atol=1e-12)


def test_room_plate_and_its_room_albedo_pinned_to_the_reviewed_output():
    """A regression pin, not a derivation: the v1 colour camera's plate (seed 0) as 40 x 40 px block means of
    colour and depth, stored from the output reviewed in mirror-synthetic.md's first measurement (the texture's
    seeds, frequencies and palettes, the lamps, the falloff, every wall's corners). A deliberate change of the
    room regenerates the file (the snippet in docs/mutation/mirror-synthetic.md)."""
    from pathlib import Path

    golden = np.load(Path(__file__).with_name("synthetic_room_plate_v1_seed0.npz"))
    sensor, _ = _static_v1()
    plate, room_depth = sy.room_plate(sy.mirror_room(), sensor.color, 0)  # not the cached plate: the code under test

    def blocks(a, b=40):
        h, w = a.shape[:2]
        return a[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b, *a.shape[2:]).astype(float).mean(
            axis=(1, 3))

    assert np.abs(blocks(plate) - golden["colour"]).max() < 0.02  # ~1 pixel in 1600 off by one grey level
    assert np.abs(blocks(room_depth) - golden["depth"]).max() < 1e-4
