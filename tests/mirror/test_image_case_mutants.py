"""Fast tests of the mirror's test-case builders (issue 17, second round): ``mirror.image_case`` (the rendered
source/target frame pair of the image-step tests and benchmarks: its SDK-like player mask, the pair's ground
truth) and ``mirror.init_case`` (the Kinect observations of a posed subject: flying-pixel removal, back-projection,
the scene). Each test calls the function under test; the 2k image case is built inside its test."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import image_case as ic
from bodystudio.mirror import init_case as nc

# ------------------------------------------------------------------------------------------ image_case


def _disc(h=60, w=80, r=15):
    yy, xx = np.mgrid[:h, :w]
    return ((yy - h // 2) ** 2 + (xx - w // 2) ** 2) < r * r


def test_sdk_player_mask_without_noise_is_the_mask_on_the_coarse_grid():
    """No flips, holes or shift: the mask and depth sampled every ``depth_scale`` pixels and blown up again."""
    mask = _disc()
    depth = np.where(mask, 2.0, 4.5) + np.linspace(0, 0.01, 80)[None, :]
    m, d = ic.sdk_player_mask(mask, depth, np.random.default_rng(0), flip_rate=0.0, shift_px=0.0, hole_rate=0.0)
    assert m.dtype == bool and d.dtype == np.float64 and m.shape == mask.shape
    rows, cols = np.arange(60) // 2 * 2, np.arange(80) // 2 * 2
    assert np.array_equal(m, mask[np.ix_(rows, cols)])
    assert np.array_equal(d, depth[np.ix_(rows, cols)].astype(np.float32))  # sampled in float32 (the SDK's)
    m3, _ = ic.sdk_player_mask(mask, depth, np.random.default_rng(0), depth_scale=3, flip_rate=0.0,
                               shift_px=0.0, hole_rate=0.0)
    assert ic.iou(m3, mask) > 0.8 and not np.array_equal(m3, m)  # a coarser grid: blockier


def test_sdk_player_mask_defaults():
    """depth_scale 2, flip_rate 0.35, shift_px 1.5, hole_rate 0.02: the defaults give what they give spelled out."""
    mask = _disc(120, 160, 40)
    depth = np.where(mask, 2.0, 4.5)
    for seed in range(3):
        m, d = ic.sdk_player_mask(mask, depth, np.random.default_rng(seed))
        m2, d2 = ic.sdk_player_mask(mask, depth, np.random.default_rng(seed), depth_scale=2, flip_rate=0.35,
                                    shift_px=1.5, hole_rate=0.02)
        assert np.array_equal(m, m2) and np.array_equal(d, d2)


def test_sdk_player_mask_flips_only_boundary_pixels_at_its_rate():
    mask = _disc(120, 160, 40)
    small = mask[::2, ::2]
    import cv2

    k = np.ones((3, 3), np.uint8)
    boundary = cv2.dilate(small.astype(np.uint8), k) != cv2.erode(small.astype(np.uint8), k)
    flips = []
    for seed in range(4):
        m, _ = ic.sdk_player_mask(mask, np.full(mask.shape, 2.0), np.random.default_rng(seed), shift_px=0.0,
                                  hole_rate=0.0)
        changed = m[::2, ::2] != small
        assert not changed[~boundary].any()
        flips.append(changed[boundary].mean())
    assert np.mean(flips) == pytest.approx(0.35, abs=0.05)  # flip_rate
    m, _ = ic.sdk_player_mask(mask, np.full(mask.shape, 2.0), np.random.default_rng(0), flip_rate=0.8,
                              shift_px=0.0, hole_rate=0.0)
    assert (m[::2, ::2] != small)[boundary].mean() == pytest.approx(0.8, abs=0.06)


def test_sdk_player_mask_holes_and_shift():
    mask = _disc(120, 160, 40)
    depth = np.full(mask.shape, 2.0)
    _, d = ic.sdk_player_mask(mask, depth, np.random.default_rng(1), flip_rate=0.0, shift_px=0.0)
    assert (d[::2, ::2] == 0).mean() == pytest.approx(0.02, abs=0.01) and set(np.unique(d)) == {0.0, 2.0}
    _, d = ic.sdk_player_mask(mask, depth, np.random.default_rng(1), flip_rate=0.0, shift_px=0.0, hole_rate=0.3)
    assert (d[::2, ::2] == 0).mean() == pytest.approx(0.3, abs=0.03)
    # a registration shift of up to shift_px moves mask and depth together (the same offset)
    shifts = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        m, d = ic.sdk_player_mask(mask, np.where(mask, 2.0, 4.5), rng, flip_rate=0.0, shift_px=6.0, hole_rate=0.0)
        assert np.array_equal(m[d > 0], d[d > 0] == 2.0)
        cy, cx = np.argwhere(m).mean(axis=0)
        shifts.append((cx - 79.5, cy - 59.5))
    shifts = np.array(shifts)
    assert np.abs(shifts).max() <= 6.0 + 1.0 and np.abs(shifts).max() > 2.0
    ref = np.random.default_rng(3)
    ref.random((60, 80))  # the flips' draw
    ref.random((60, 80))  # the holes' draw
    dx, dy = ref.uniform(-6.0, 6.0, 2)
    m, _ = ic.sdk_player_mask(mask, np.where(mask, 2.0, 4.5), np.random.default_rng(3), flip_rate=0.0,
                              shift_px=6.0, hole_rate=0.0)
    cy, cx = np.argwhere(m).mean(axis=0)
    assert cx - 79.5 == pytest.approx(dx, abs=2.0) and cy - 59.5 == pytest.approx(dy, abs=2.0)


def test_iou():
    a = np.zeros((4, 4), bool)
    a[:2] = True
    b = np.zeros((4, 4), bool)
    b[1:3] = True
    assert ic.iou(a, b) == pytest.approx(4 / 12) and ic.iou(a, a) == 1.0
    assert ic.iou(np.zeros(3), np.zeros(3)) == 1.0 and ic.iou([1, 0], [2, 0]) == 1.0


def test_make_image_case_refuses_a_third_actor():
    with pytest.raises(InputError) as info:
        ic.make_image_case(actors=3)
    assert str(info.value) == "actors must be 1 or 2, got 3"


def test_make_image_case_ground_truth():
    """The frame pair's parts agree: masks are the renders', the target taller by the default edit (+10 %
    stature, +15 kg), the pairs project the visible vertices, the player mask close to the true mask."""
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror import run

    model = load_statistical_model("2k", progress=False)
    case = ic.make_image_case(seed=0, model=model, n_handles=200, rim_cos=None)
    H, W = 480, 640
    assert case.rgb.shape == (H, W, 3) and case.target_rgb.shape == (H, W, 3) and case.background.shape == (H, W, 3)
    assert case.actors == 1 and case.camera.width == W
    assert np.allclose(case.camera.center, (0.0, 1.0, 2.4), atol=0.03)  # distance_m (colour 2.5 cm aside)
    # both stand on the floor
    assert case.source_vertices[:, 1].min() == pytest.approx(0.0, abs=1e-9)
    assert case.target_vertices[:, 1].min() == pytest.approx(0.0, abs=1e-9)
    src_h, tgt_h = np.ptp(case.source_vertices[:, 1]), np.ptp(case.target_vertices[:, 1])
    assert 1.05 < tgt_h / src_h < 1.15  # about +10 % (posed: a walk frame)
    assert case.target_mask.sum() > case.true_mask.sum() * 1.1  # taller and heavier
    # the renders: the source over the background with noise, the target without
    out = ~case.true_mask & ~case.target_mask
    d = case.rgb[out].astype(float) - case.background[out]
    assert 1.5 < d.std() < 2.5 and np.array_equal(case.target_rgb[out], case.background[out])
    assert np.abs(case.rgb[case.true_mask].astype(float) - case.background[case.true_mask]).mean() > 10
    # the SDK-like mask: close to the truth, not equal; the depth at the person and the plate behind
    assert 0.8 < ic.iou(case.player_mask, case.true_mask) < 0.99
    assert np.median(case.depth_color[case.true_mask & case.player_mask]) == pytest.approx(2.4, abs=0.3)
    assert (case.depth_color[~case.true_mask] == ic.BACKGROUND_DEPTH_M).mean() > 0.9
    # the handle pairs: visible vertices projected into both bodies; n_handles of them at most
    assert 20 < len(case.src_uv) <= 200 and case.src_uv.shape == case.dst_uv.shape
    uv = np.round(case.src_uv).astype(int)
    import cv2

    near = cv2.dilate(case.true_mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # rim vertices: the edge
    assert near[np.clip(uv[:, 1], 0, H - 1), np.clip(uv[:, 0], 0, W - 1)].mean() > 0.97
    assert np.median(case.src_uv[:, 1] - case.dst_uv[:, 1]) > 2  # the target's head higher: rows decrease
    assert np.array_equal(case.pair_groups, np.zeros(len(case.src_uv)))
    assert case.dense is not None and case.faces.shape == (len(model.faces), 3)
    # the mirror run's defaults when not given
    default = ic.make_image_case(seed=0, model=model, edits={"stature_m": 0.0, "mass_kg": 0.0})
    assert len(default.src_uv) > 200 and len(default.src_uv) <= run.N_HANDLES + 2 * len(model.faces)
    assert np.allclose(default.source_vertices, case.source_vertices)
    assert np.allclose(default.target_vertices, default.source_vertices, atol=2e-3)  # a zero edit


def test_make_image_case_of_two_actors_side_by_side():
    from bodystudio.body.statistical import load_statistical_model

    model = load_statistical_model("2k", progress=False)
    case = ic.make_image_case(seed=1, actors=2, model=model, n_handles=100, rim_cos=None)
    n = len(model.mean) // 3 if model.mean.ndim == 1 else len(model.mean)
    V = case.source_vertices
    assert len(V) == 2 * n and case.faces.shape == (2 * len(model.faces), 3) and case.faces.max() == 2 * n - 1
    assert V[:n, 0].mean() == pytest.approx(-0.45, abs=0.1) and V[n:, 0].mean() == pytest.approx(0.45, abs=0.1)
    assert set(np.unique(case.pair_groups)) == {0, 1} and len(case.src_uv) <= 100
    left = case.src_uv[case.pair_groups == 0, 0].mean()
    right = case.src_uv[case.pair_groups == 1, 0].mean()
    assert left < 320 < right  # actor 0 at -x on the left
    assert not np.allclose(V[:n, 1].max(), V[n:, 1].max(), atol=1e-3)  # two subjects


def test_cached_image_case_is_memoised():
    ic.cached_image_case.cache_clear()
    calls = []
    orig = ic.make_image_case

    def fake(edits=None, seed=0, actors=1, **kw):
        calls.append((edits, seed, actors))
        return object()

    ic.make_image_case = fake
    try:
        a = ic.cached_image_case((("stature_m", 0.1),), seed=2)
        assert ic.cached_image_case((("stature_m", 0.1),), seed=2) is a
        ic.cached_image_case(None, 0, 2)
    finally:
        ic.make_image_case = orig
        ic.cached_image_case.cache_clear()
    assert calls == [({"stature_m": 0.1}, 2, 1), (None, 0, 2)]


# ------------------------------------------------------------------------------------------ init_case

def test_drop_flying_pixels_removes_only_mixtures_between_surfaces():
    depth = np.full((5, 9), 3.0)
    depth[:, :4] = 2.0
    depth[2, 4] = 2.5  # between the near and the far surface: a mixture
    depth[0, 8] = 0.0  # no measurement (counts as far)
    out = nc.drop_flying_pixels(depth)
    assert out[2, 4] == 0.0 and out.dtype == np.float64
    keep = np.ones(depth.shape, bool)
    keep[2, 4] = False
    assert np.array_equal(out[keep], depth[keep])  # the edges of both surfaces stay
    # a step smaller than step_m is no mixture; a larger step_m keeps it
    assert nc.drop_flying_pixels(depth, step_m=0.6)[2, 4] == 2.5
    d2 = depth.copy()
    d2[2, 4] = 2.02
    assert nc.drop_flying_pixels(d2)[2, 4] == 2.02
    # beside a hole: a pixel with a nearer neighbour and the hole (far) is a mixture
    d3 = np.full((3, 3), 2.0)
    d3[1, 1], d3[0, 0], d3[2, 2] = 2.5, 0.0, 2.0
    assert nc.drop_flying_pixels(d3)[1, 1] == 0.0
    d4 = np.full((3, 3), 2.5)
    d4[0, 0] = 2.0
    assert nc.drop_flying_pixels(d4)[1, 1] == 2.5  # nearer neighbour only: an edge, kept


def test_back_project_is_the_cameras_unprojection_of_the_valid_pixels():
    from bodystudio.geometry.camera import kinect_v2

    cam = kinect_v2().depth
    depth = np.zeros((cam.height, cam.width))
    depth[100:110, 200:220] = 2.0
    depth[105, 220] = 2.5  # a mixture at the patch's edge (nearer on its left, nothing on its right)
    P = nc.back_project(depth, cam)
    assert P.shape == (200, 3)
    Q = nc.back_project(depth, cam, player_mask=False)
    assert Q.shape == (201, 3)
    rows, cols = np.nonzero(depth == 2.0)
    expect = cam.unproject(np.stack([cols, rows], 1).astype(float), np.full(len(rows), 2.0))
    assert np.allclose(P, expect)
    uv, z = cam.project_with_depth(P)
    assert np.allclose(z, 2.0) and np.allclose(uv, np.stack([cols, rows], 1), atol=1e-6)


def test_synthetic_scene_observations_are_the_posed_body_seen_by_the_kinect():
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.body.skinning import posed_joints

    scene = nc.synthetic_scene(2, n_frames=2, motion="walk", version="v1", resolution="2k", seed=1,
                               offset=(0.2, 0.0, 0.1), frame_stride=3, joint_noise_m=0.02)
    assert len(scene.observations) == 2 and len(scene.poses) == 2 and len(scene.true_joints) == 2
    assert scene.sensor.version == "v1" and scene.sensor.depth.width == 320
    assert scene.truth["stature_m"] == pytest.approx(np.ptp(scene.body.vertices[:, 1]), abs=0.03)
    from bodystudio.capture.motion import motion_sequence

    seq = motion_sequence("walk", 6, scene.body.skeleton, seed=1)
    from scipy.spatial import cKDTree

    for k, (obs, pose, truth) in enumerate(zip(scene.observations, scene.poses, scene.true_joints, strict=True)):
        assert obs.frame == k and obs.version == "v1"
        assert np.allclose(pose.rotations, seq[3 * k].rotations)  # frame_stride
        assert np.allclose(pose.translation, seq[3 * k].translation + [0.2, 0.0, 0.1])  # offset
        heads, tails = posed_joints(scene.body.skeleton, pose)
        assert np.allclose(truth, kinect_joints(scene.body.skeleton, heads, tails, "v1"))
        V, _ = scene.body.pose(pose)
        dist, _ = cKDTree(V).query(obs.points)
        assert len(obs.points) > 500 and np.median(dist) < 0.02  # the body's surface, with Kinect noise
        err = np.linalg.norm(obs.joints - truth, axis=1)
        assert 0.01 < np.median(err) < 0.12 and obs.tracked.all()  # joint_noise_m 2 cm + 6 % bone jitter
    clean = nc.synthetic_scene(2, n_frames=1, version="v2", resolution="2k", noise=False, joint_noise_m=0.0)
    obs = clean.observations[0]
    assert np.allclose(obs.joints, clean.true_joints[0], atol=1e-9) and obs.version == "v2"
    V, _ = clean.body.pose(clean.poses[0])
    assert np.allclose(clean.poses[0].translation, [0.1, 0.0, 0.2])  # the default offset
    dist, _ = cKDTree(V).query(obs.points)
    assert np.median(dist) < 0.015 and (dist > 0.05).mean() < 0.002  # nearest vertex; no flying pixels


def test_synthetic_scene_defaults_and_what_it_hands_on(monkeypatch):
    """With spies for the body, the motion, the depth simulation and the tracker: the defaults (6 frames of a walk,
    v2, the 6k body, seed 0, 10 / 20 cm offset, noise on, 1 cm joint noise with 3 cm bone jitter) and the subject."""
    from bodystudio.body.population import sample_population

    seen = {}
    real_motion = nc.motion_sequence

    def body(phenotype, local, resolution):
        seen["body"] = (phenotype, local, resolution)
        return real_body
    from bodystudio.body import build_body

    real_body = build_body(*sample_population(1, seed=4)[0], resolution="2k")

    def motion(name, n, skeleton, seed):
        seen["motion"] = (name, n, seed)
        return real_motion(name, n, skeleton, seed=seed)

    def depth(V, F, sensor, rng, noise):
        seen.setdefault("depth", []).append((sensor.version, noise, rng.random()))
        d = np.zeros((sensor.depth.height, sensor.depth.width))
        d[200, 250] = 2.0
        return d

    def tracker(heads, tails, skeleton, version, rng, noise_m, bone_length_jitter):
        seen["tracker"] = (version, noise_m, bone_length_jitter)
        return np.zeros((25, 3)), np.ones(25, bool)

    monkeypatch.setattr(nc, "build_body", body)
    monkeypatch.setattr(nc, "motion_sequence", motion)
    monkeypatch.setattr(nc, "simulate_kinect_depth", depth)
    monkeypatch.setattr(nc, "simulate_tracker_joints", tracker)
    scene = nc.synthetic_scene(4)
    phenotype, local = sample_population(1, seed=4)[0]
    assert seen["body"][2] == "6k" and seen["body"][1] == local and seen["body"][0].to_dict() == phenotype.to_dict()
    assert seen["motion"] == ("walk", 6, 0) and len(scene.observations) == 6
    assert scene.sensor.version == "v2" and scene.sensor.depth.width == 512
    assert [d[:2] for d in seen["depth"]] == [("v2", True)] * 6 and seen["tracker"] == ("v2", 0.01, 0.03)
    assert np.allclose(scene.poses[0].translation - real_motion("walk", 6, real_body.skeleton, seed=0)[0].translation,
                       (0.1, 0.0, 0.2))
    first = [d[2] for d in seen["depth"]]
    seen.clear()
    nc.synthetic_scene(4, n_frames=2, frame_stride=3, version="v1", noise=False, joint_noise_m=0.02, seed=7)
    assert seen["motion"] == ("walk", 6, 7) and seen["tracker"] == ("v1", 0.02, pytest.approx(0.06))
    assert [d[:2] for d in seen["depth"]] == [("v1", False)] * 2
    seen.clear()
    nc.synthetic_scene(4)
    assert [d[2] for d in seen["depth"]] == first  # the rng is seeded
    assert len(scene.observations[0].points) == 1  # the one valid pixel back-projected


def test_drop_flying_pixels_window_dtype_and_near_depths():
    # the 3 x 3 window only: a nearer (or farther) surface two pixels away does not make a mixture
    row = np.array([[2.0, 2.5, 2.5, 3.0, 3.0]])
    d = np.repeat(row, 3, axis=0)
    assert nc.drop_flying_pixels(d)[1, 2] == 2.5
    row = np.array([[3.0, 2.5, 2.5, 2.0, 2.0]])
    assert nc.drop_flying_pixels(np.repeat(row, 3, axis=0))[1, 2] == 2.5
    # float32 depth comes back as float64; depths under 1 m are measurements too
    d32 = np.full((3, 3), 0.8, np.float32)
    d32[1, 1] = 0.85
    d32[0, :] = 0.5
    d32[2, :] = 0.0
    out = nc.drop_flying_pixels(d32)
    assert out.dtype == np.float64 and out[1, 1] == 0.0 and out[0, 0] == pytest.approx(0.5)
    from bodystudio.geometry.camera import kinect_v2

    cam = kinect_v2().depth
    near = np.zeros((cam.height, cam.width))
    near[50:54, 60:65] = 0.7
    assert nc.back_project(near, cam).shape == (20, 3)


def test_make_image_case_is_this_subject_pose_camera_and_noise_by_default():
    """Which case the defaults build: subject ``sample_subject(1)`` in the 2k model, +10 % stature / +15 kg, frame 10
    of a walk (seed 0), the Kinect v1 colour camera at 2.4 m aimed at (0, 0.9, 0), the plate of seed 0 and the
    sensor noise of ``default_rng(0)``; the 2k model is loaded when none is given."""
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_subject
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.motion import motion_sequence
    from bodystudio.capture.render import background_plate, render, render_rgb
    from bodystudio.geometry.camera import kinect_v1

    model = load_statistical_model("2k", progress=False)
    case = ic.make_image_case(rim_cos=None, n_handles=100)
    c = model.project(build_body(*sample_subject(1), resolution="2k").vertices)
    src = model.body(c)
    pose = motion_sequence("walk", 11, src.skeleton, seed=0)[10]
    Vs, _ = src.pose(pose)
    Vs = Vs + np.array([0.0, -Vs[:, 1].min(), 0.0])
    np.testing.assert_allclose(case.source_vertices, Vs, atol=1e-9)
    tgt = model.body(model.edit(c, {"stature_m": 0.10 * model.measure(c)["stature_m"], "mass_kg": 15.0},
                                others="follow"))
    Vt, _ = tgt.pose(pose)
    np.testing.assert_allclose(case.target_vertices, Vt + np.array([0.0, -Vt[:, 1].min(), 0.0]), atol=1e-9)
    cam = kinect_v1(eye=(0.0, 1.0, 2.4), target=(0.0, 0.9, 0.0)).color
    assert np.array_equal(case.camera.R, cam.R) and np.array_equal(case.camera.t, cam.t)
    plate = background_plate(cam, seed=0)
    assert np.array_equal(case.background, plate)
    rs = render(Vs, model.faces, cam)
    rgb = render_rgb(Vs, model.faces, cam, background=plate, result=rs, noise_std=2.0, rng=np.random.default_rng(0))
    assert np.array_equal(case.rgb, rgb)
    assert len(case.src_uv) <= 100
