"""MIR12e's speed changes of the mirror's session side (per frame, per actor), each pinned to the output it replaced."""

import numpy as np
import pytest

from bodystudio.body.pose import Pose, transfer_pose
from bodystudio.body.skinning import forward_kinematics, skinning_transforms
from bodystudio.body.statistical import load_statistical_model
from bodystudio.mirror.init import SourceBody
from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
from bodystudio.mirror.track import posed_frames, rest_chain, skin_vertices


@pytest.fixture(scope="module")
def reshaped():
    """A 6k source body of a random shape, its +10 cm / +15 kg target (rest vertices and rig)."""
    model = load_statistical_model("6k", progress=False)
    c = np.random.default_rng(1).normal(size=len(model.stddev)) * 0.5 * model.stddev
    body = SourceBody(c, model.vertices(c), model.skeleton(c), (), 0.0, model.weights, model.faces)
    ct = target_coeffs(model, c, {"taller": 0.1, "heavier": 15})
    Vt = model.vertices(ct)
    return body, Vt, target_skeleton(body, Vt, model, ct)


def test_posed_frames_are_the_forward_kinematics():
    model = load_statistical_model("6k", progress=False)
    sk = model.skeleton(np.zeros(len(model.stddev)))
    pose = Pose(np.random.default_rng(2).normal(0, 0.6, (sk.n_bones, 3)), np.array([0.3, 0.9, 2.1]))
    from scipy.spatial.transform import Rotation

    M, T = posed_frames(*rest_chain(sk), Rotation.from_rotvec(pose.rotations).as_matrix(), pose.translation,
                        np.asarray(sk.parents, np.int64))
    np.testing.assert_allclose(M, forward_kinematics(sk, pose), atol=1e-13)
    np.testing.assert_allclose(T, skinning_transforms(sk, pose)[:, :3], atol=1e-13)


@pytest.mark.parametrize("seed", [3, 4])
def test_source_and_target_in_one_pass_are_the_two_skinnings(reshaped, seed):
    """posed_source_and_target's one pass (MIR12e) against what it replaced: skin_vertices of the source by the
    pose and of the target by transfer_pose's rotation vectors (their round trip is the ~1e-13 m)."""
    body, Vt, rig = reshaped
    rng = np.random.default_rng(seed)
    pose = Pose(rng.normal(0, 0.5, (body.skeleton.n_bones, 3)), rng.normal(0, 1, 3))
    Vs_got, Vt_got = posed_source_and_target(body, Vt, pose, rig)
    Vs_want = skin_vertices(body.vertices, body.weights, body.skeleton, pose)
    Vt_want = skin_vertices(Vt, body.weights, rig, transfer_pose(pose, body.skeleton, rig))
    np.testing.assert_allclose(Vs_got, Vs_want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Vt_got, Vt_want, rtol=0, atol=1e-11)
    assert np.abs(Vt_got - Vs_got).max() > 0.05  # the target is its own body, not the source's
    # the subset path is the two skinnings' rows
    sub = np.arange(0, len(Vt), 7)
    Vs_sub, Vt_sub = posed_source_and_target(body, Vt, pose, rig, subset=sub)
    np.testing.assert_allclose(Vs_sub, Vs_want[sub], rtol=0, atol=1e-12)
    np.testing.assert_allclose(Vt_sub, Vt_want[sub], rtol=0, atol=1e-11)


def _mask_box_numpy(mask, margin_px):
    """refine.mask_box as numpy computed it before MIR12e."""
    m = np.asarray(mask, bool)
    ys, xs = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
    if not len(ys):
        return None
    return (max(ys[0] - margin_px, 0), min(ys[-1] + margin_px + 1, m.shape[0]),
            max(xs[0] - margin_px, 0), min(xs[-1] + margin_px + 1, m.shape[1]))


def test_mask_box_in_numba_is_numpys():
    from bodystudio.mirror.refine import mask_box

    rng = np.random.default_rng(5)
    for trial in range(40):
        mask = rng.random((48, 64)) < (0.002 if trial % 3 else 0.05)
        if trial % 7 == 0:
            mask[:] = False
        for margin in (0, 3, 40):
            assert mask_box(mask, margin) == _mask_box_numpy(mask, margin)
            assert mask_box(mask.astype(np.uint8), margin) == _mask_box_numpy(mask, margin)


def _two_people(rng, shape=(240, 420)):
    """A mask of two blobs ~200 px apart (two players) and the box / silhouette boxes of the refinement."""
    import cv2

    from bodystudio.mirror.refine import mask_box

    mask = np.zeros(shape, np.uint8)
    for cx in (100, 310):
        for _ in range(2):
            cv2.ellipse(mask, (cx + int(rng.integers(-20, 20)), 120 + int(rng.integers(-30, 30))),
                        (int(rng.integers(10, 40)), int(rng.integers(20, 80))), float(rng.uniform(0, 180)), 0, 360,
                        1, -1)
    allowed = mask.astype(bool)
    return allowed, mask_box(allowed, 40), mask_box(allowed, 0)


@pytest.mark.parametrize("spread_px", [6.0, 60.0])
def test_the_distance_near_one_body_is_the_whole_box_transform_where_it_is_read(spread_px):
    """MIR12e's window around the body (clipped away from the other player) reads the whole box's transform at
    every sample and its central differences; with points far outside (spread 60 px) the check grows the window."""
    from bodystudio.mirror.refine import _distance_near_the_body, _sample, silhouette_distance

    rng = np.random.default_rng(12)
    clipped = 0
    for _ in range(8):
        allowed, box, sil = _two_people(rng)
        whole, origin = silhouette_distance(allowed, 40, box)
        ys, xs = np.nonzero(allowed[:, :205])  # around the left player
        pick = rng.choice(len(ys), 300)
        points = np.c_[xs[pick], ys[pick]] - origin + rng.normal(0, spread_px, (300, 2))
        h, w = whole.shape
        points = points[(points[:, 0] >= 1) & (points[:, 1] >= 1) & (points[:, 0] < w - 2) & (points[:, 1] < h - 2)]
        dist = np.full_like(whole, np.nan)
        done, d = _distance_near_the_body(dist, allowed, box, sil, points, None)
        clipped += done[3] - done[2] < sil[3] - sil[2]
        np.testing.assert_allclose(d, _sample(whole, points), atol=1e-4)
        probes = (points[None] + np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[:, None]).reshape(-1, 2)
        np.testing.assert_allclose(_sample(dist, probes), _sample(whole, probes), atol=1e-4)
    if spread_px < 10:
        assert clipped == 8  # the other player's side was left out every time
    else:
        assert clipped < 8  # some windows had to grow back



def test_player_points_in_one_pass_are_numpys_point_cloud():
    """frames.point_cloud's numba pass (MIR12e) against the numpy mask, gathers and camera_to_world it replaced."""
    from bodystudio.geometry.camera import Camera
    from bodystudio.mirror.frames import _player_points, depth_ray_table

    cam = Camera.look_at("kinect", eye=(0.3, 1.1, 2.6), target=(0.0, 0.9, 0.0), fx=285.0, width=320, height=240)
    rng = np.random.default_rng(6)
    depth = np.where(rng.random((240, 320)) < 0.9, rng.uniform(0.5, 4.0, (240, 320)), 0.0)
    player = rng.integers(0, 3, (240, 320)).astype(np.uint8)
    rays = depth_ray_table(cam)
    for p in (1, 2, 5):
        sel = (player == p) & (depth > 0)
        z = depth[sel]
        want = cam.camera_to_world(np.c_[rays[sel] * z[:, None], z])
        got = _player_points(depth, player, rays, p, cam.R, cam.t)
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)


@pytest.mark.parametrize("players", [(1,), (2,), (1, 2), (2, 3, 5)])
def test_player_masks_are_the_isin_and_where_masks(players):
    """run.player_masks (MIR12e) against the np.isin / np.where expressions session_inputs had inline."""
    from bodystudio.mirror.run import player_masks

    rng = np.random.default_rng(8)
    players_c = rng.integers(0, 7, (48, 64)).astype(np.uint8)
    several = len(players) > 1
    person, others, labels = player_masks(players_c, players, several)
    want = players_c == players[0] if not several else np.isin(players_c, players)
    np.testing.assert_array_equal(person, want)
    np.testing.assert_array_equal(others, (players_c > 0) & ~want)
    if several:
        old = np.where(want, players_c, 0).astype(np.uint8)
        assert labels.dtype == old.dtype == np.uint8
        np.testing.assert_array_equal(labels, old)
    else:
        assert labels is None



def _register_reference(depth, player, rays, T, K, dist, width, height, footprint):
    """The SDK's registration as frames._register splats it, in Python (the same operations in the same order),
    with numpy's zeroing of the unreached pixels after it (before MIR12e)."""
    import math

    k1, k2, p1, p2, k3 = dist
    zbuf = np.full((height, width), np.inf)
    pbuf = np.zeros((height, width), np.uint8)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            z = depth[r, c]
            if z <= 0.0:
                continue
            x, y = rays[r, c, 0] * z, rays[r, c, 1] * z
            xc = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
            yc = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
            zc = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
            if zc <= 0.0:
                continue
            a, b = xc / zc, yc / zc
            r2 = a * a + b * b
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ad = a * radial + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
            bd = b * radial + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
            u = K[0, 0] * ad + K[0, 1] * bd + K[0, 2]
            v = K[1, 1] * bd + K[1, 2]
            half = 0.5 * footprint * z / zc + 0.25
            for rr in range(max(math.ceil(v - half), 0), min(math.floor(v + half), height - 1) + 1):
                for cc in range(max(math.ceil(u - half), 0), min(math.floor(u + half), width - 1) + 1):
                    if zc < zbuf[rr, cc]:
                        zbuf[rr, cc] = zc
                        pbuf[rr, cc] = player[r, c]
    zbuf[~np.isfinite(zbuf)] = 0.0
    return zbuf, pbuf


@pytest.mark.parametrize("color_fx", [525.0, 1100.0])
def test_registration_is_bit_for_bit_the_one_before_mir12e(color_fx):
    """register_depth_to_color with the unreached pixels zeroed in its numba pass (MIR12e) and the usual footprint
    splatted as a fixed 3x3 block of selects (MIR12f) against the splat and numpy's isfinite pass it had before:
    a Kinect v1's footprint (2-3 colour pixels a side, the block) and a colour camera of twice the focal length
    (3-5 pixels: the general loop), depth pixels at the colour image's border included."""
    from bodystudio.geometry.camera import Camera, RGBDSensor
    from bodystudio.mirror.frames import depth_ray_table, register_depth_to_color

    depth_cam = Camera.look_at("d", eye=(0.0, 1.0, 3.0), target=(0.0, 1.0, 0.0), fx=285.0, width=80, height=60)
    color = Camera.look_at("c", eye=(0.025, 1.0, 3.0), target=(0.025, 1.0, 0.0), fx=color_fx, width=160, height=120,
                           dist=np.array([0.05, -0.01, 0.001, -0.001, 0.0]))
    T = np.eye(4)
    T[:3, :3] = color.R @ depth_cam.R.T
    T[:3, 3] = color.t - T[:3, :3] @ depth_cam.t
    sensor = RGBDSensor("kinect", "v1", depth_cam, color, T)
    rng = np.random.default_rng(9)
    depth = np.where(rng.random((60, 80)) < 0.8, rng.uniform(0.8, 4.0, (60, 80)), 0.0)
    depth[:, :6] = 0.0  # a strip no depth reaches
    player = rng.integers(0, 3, (60, 80)).astype(np.uint8)
    got_z, got_p = register_depth_to_color(depth, player, sensor)
    footprint = 0.5 * (color.fx / depth_cam.fx + color.fy / depth_cam.fy)
    want_z, want_p = _register_reference(depth, player, depth_ray_table(depth_cam), T, color.K, color.dist, 160,
                                         120, footprint)
    assert 0 < (want_z > 0).sum() < want_z.size
    np.testing.assert_array_equal(got_z, want_z)
    np.testing.assert_array_equal(got_p, want_p)


@pytest.mark.parametrize("version", ["v1", "v2"])
def test_ik_in_numba_is_the_numpy_ik(version):
    """ik_pose's numba kernel (MIR12f) against the numpy path it replaced (track.ik_pose_numpy), warm-started frame
    after frame as the run calls it, on noisy Kinect joints with inferred and missing ones: the same rotations and
    translation to 1e-12 (the kernel's SVDs and sums round differently in the last bits); a rest-pose start; the
    same one-line errors when the pelvis cannot be fitted."""
    from bodystudio.errors import InputError
    from bodystudio.mirror.track import ik_pose, ik_pose_numpy, posed_kinect_joints

    model = load_statistical_model("6k", progress=False)
    rng = np.random.default_rng(11)
    sk = model.skeleton(rng.normal(size=len(model.stddev)) * 0.5 * model.stddev)
    got = want = None
    moved = 0.0
    for i in range(24):
        pose = Pose(rng.normal(0, 0.35, (sk.n_bones, 3)), rng.normal(0, 1, 3))
        K = posed_kinect_joints(sk, pose, version)
        K = K + rng.normal(0, 0.02, K.shape)
        tracked = rng.random(len(K)) > 0.2
        if i % 4 == 3:
            K[rng.integers(4, len(K))] = np.nan
        got = ik_pose(sk, K, tracked, version, previous=got)
        want = ik_pose_numpy(sk, K, tracked, version, previous=want)
        np.testing.assert_allclose(got.rotations, want.rotations, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.translation, want.translation, rtol=0, atol=1e-12)
        moved = max(moved, np.abs(got.rotations).max())
    assert moved > 0.5  # the solve did move the bones
    fresh = ik_pose(sk, K, None, version)
    np.testing.assert_allclose(fresh.rotations, ik_pose_numpy(sk, K, None, version).rotations, rtol=0, atol=1e-12)
    messages = set()
    for kept in (len(K) - 1, 0):  # only a foot (no pelvis joint), only the spine base: both raise the same line
        bad = np.full_like(K, np.nan)
        bad[kept] = K[kept]
        with pytest.raises(InputError) as a:
            ik_pose(sk, bad, None, version)
        with pytest.raises(InputError) as b:
            ik_pose_numpy(sk, bad, None, version)
        assert str(a.value) == str(b.value)
        messages.add(str(a.value))
    assert len(messages) == 2


def test_target_rest_chains_cached_by_content_follow_the_rig(reshaped):
    """skin_source_and_target caches the target's rest-frame products by the rig's content (the run builds an equal
    rig every frame, MIR12f): rigs of two targets called in turn, and an equal rig built anew, each pose their own
    body as skin_vertices does."""
    from bodystudio.mirror.track import _CONTENT_CHAINS

    body, Vt, rig = reshaped
    model = load_statistical_model("6k", progress=False)
    ct = target_coeffs(model, body.coeffs, {"taller": -0.1, "heavier": -10})
    Vt2 = model.vertices(ct)
    rig2 = target_skeleton(body, Vt2, model, ct)
    rig_again = target_skeleton(body, Vt, model, target_coeffs(model, body.coeffs, {"taller": 0.1, "heavier": 15}))
    assert rig_again is not rig
    rng = np.random.default_rng(8)
    pose = Pose(rng.normal(0, 0.5, (body.skeleton.n_bones, 3)), rng.normal(0, 1, 3))
    _CONTENT_CHAINS.clear()
    for V, r in ((Vt, rig), (Vt2, rig2), (Vt, rig_again), (Vt2, rig2)):
        _, got = posed_source_and_target(body, V, pose, r)
        want = skin_vertices(V, body.weights, r, transfer_pose(pose, body.skeleton, r))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-11)
    assert len(_CONTENT_CHAINS) == 2
