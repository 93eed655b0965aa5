"""Kinect mirror frames on tiny sensors with known answers: back-projection of the player's depth pixels,
the depth-to-colour registration (identity, a shift along the optical axis, the nearer surface winning),
the per-camera ray table and its cache, and the refusals of read_mirror_frame."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError, SessionError
from bodystudio.geometry.camera import Camera, RGBDSensor
from bodystudio.mirror import frames as frames_mod
from bodystudio.mirror.frames import (
    MirrorFrame,
    TrackedBody,
    depth_ray_table,
    iter_mirror_frames,
    player_mask_in_color,
    point_cloud,
    read_mirror_frame,
    register_depth_to_color,
)

h, w = 6, 8


def _camera(name, f=10.0, width=w, height=h, dist=None, R=None, t=(0.0, 0.0, 0.0)):
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return Camera(name, K, np.zeros(5) if dist is None else dist, np.eye(3) if R is None else R, np.array(t),
                  width, height)


def _sensor(color=None, depth_to_color=None, depth=None):
    depth = depth or _camera("d", t=(0.1, -0.2, 0.3))
    return RGBDSensor("k", "v2", depth, color or _camera("c"), np.eye(4) if depth_to_color is None else depth_to_color)


def test_ray_table_is_each_pixel_centre_undistorted_and_cached():
    cam = _camera("d", f=20.0)
    table = depth_ray_table(cam)
    r, c = np.mgrid[0:h, 0:w]
    np.testing.assert_allclose(table[..., 0], (c - (w - 1) / 2) / 20.0, atol=1e-12)
    np.testing.assert_allclose(table[..., 1], (r - (h - 1) / 2) / 20.0, atol=1e-12)
    assert depth_ray_table(cam) is table and not table.flags.writeable
    # a distorted camera's rays are undistorted (distorting them gives back the pixel centres)
    bent = _camera("d", f=20.0, dist=np.array([0.1, 0.0, 0.0, 0.0, 0.0]))
    rays = depth_ray_table(bent)
    P = np.c_[rays.reshape(-1, 2), np.ones(h * w)]
    np.testing.assert_allclose(bent.project(P), np.c_[c.ravel(), r.ravel()], atol=1e-6)
    assert np.abs(rays - table).max() > 5e-4



def test_ray_table_cache_holds_nine_cameras_then_starts_again(monkeypatch):
    monkeypatch.setattr(frames_mod, "_RAY_TABLES", {})
    for f in range(30, 39):
        depth_ray_table(_camera("d", f=float(f)))
    assert len(frames_mod._RAY_TABLES) == 9
    depth_ray_table(_camera("d", f=50.0))
    assert len(frames_mod._RAY_TABLES) == 1


def test_point_cloud_back_projects_the_players_measured_pixels():
    sensor = _sensor()
    depth = np.full((h, w), 2.0)
    depth[1, 2] = 3.0
    depth[2, 1] = 0.6
    depth[0, 0] = 0.0
    player = np.zeros((h, w), np.uint8)
    player[:3, :4] = 1
    player[4:, 4:] = 2
    frame = MirrorFrame(0, np.zeros((h, w, 3), np.uint8), depth, player, ())
    P = point_cloud(frame, sensor, 1)
    assert len(P) == 11  # 12 player pixels, one without depth
    uv, z = sensor.depth.project_with_depth(P)
    rows, cols = np.nonzero((player == 1) & (depth > 0))
    np.testing.assert_allclose(uv, np.c_[cols, rows], atol=1e-9)
    np.testing.assert_allclose(z, depth[rows, cols], atol=1e-12)
    assert len(point_cloud(frame, sensor, 2)) == 8 and len(point_cloud(frame, sensor, 6)) == 0
    for bad in (0, 7):
        with pytest.raises(InputError, match=f"player {bad} is not a Kinect player id; valid: 1..6"):
            point_cloud(frame, sensor, bad)
    small = MirrorFrame(0, frame.rgb, depth[:-1], player[:-1], ())
    with pytest.raises(InputError, match=r"point_cloud: depth \(5, 8\) is not the depth camera's \(6, 8\)"):
        point_cloud(small, sensor, 1)


def test_registration_with_identical_cameras_is_the_identity():
    sensor = _sensor()
    rng = np.random.default_rng(0)
    depth = rng.uniform(1.0, 3.0, (h, w))
    depth[2, 3] = 0.0
    player = rng.integers(0, 3, (h, w)).astype(np.uint8)
    d, p = register_depth_to_color(depth, player, sensor)
    np.testing.assert_allclose(d, depth, atol=1e-12)
    expect = player.copy()
    expect[2, 3] = 0
    np.testing.assert_array_equal(p, expect)
    assert d.dtype == np.float64 and p.dtype == np.uint8
    frame = MirrorFrame(0, np.zeros((h, w, 3), np.uint8), depth, player, ())
    np.testing.assert_array_equal(player_mask_in_color(frame, sensor), expect > 0)
    np.testing.assert_array_equal(player_mask_in_color(frame, sensor, 2), expect == 2)
    np.testing.assert_array_equal(player_mask_in_color(frame, sensor, 1), expect == 1)
    assert not player_mask_in_color(frame, sensor, 6).any()
    with pytest.raises(InputError, match="player 9 is not a Kinect player id"):
        player_mask_in_color(frame, sensor, 9)


def test_registration_moves_depth_into_the_colour_camera():
    """The colour camera 0.5 m behind the depth camera on its axis: colour depth is z + 0.5 and each depth
    pixel lands nearer the image centre (the colour camera sees the same ray set from farther away)."""
    T = np.eye(4)
    T[2, 3] = 0.5
    sensor = _sensor(depth_to_color=T)
    depth = np.full((h, w), 1.0)
    player = np.ones((h, w), np.uint8)
    d, p = register_depth_to_color(depth, player, sensor)
    hit = d > 0
    np.testing.assert_allclose(d[hit], 1.5, atol=1e-12)
    assert (p[hit] == 1).all() and not p[~hit].any()
    # the projections of the corners: x/z shrinks by 1 / 1.5, so the outer colour columns get no depth
    assert hit[h // 2, w // 2] and not hit[0, 0] and not hit[0, w - 1]
    # z_c <= 0 (behind the colour camera) is dropped
    T2 = np.eye(4)
    T2[2, 3] = -5.0
    d2, p2 = register_depth_to_color(depth, player, _sensor(depth_to_color=T2))
    assert not d2.any() and not p2.any()


def test_registration_keeps_the_nearer_surface():
    """A colour camera of half the focal length: two depth pixels fall on each colour pixel; the nearer wins."""
    color = _camera("c", f=5.0)
    sensor = _sensor(color=color)
    depth = np.full((h, w), 3.0)
    player = np.full((h, w), 2, np.uint8)
    depth[:, 3] = 1.0  # a near column, player 1
    player[:, 3] = 1
    d, p = register_depth_to_color(depth, player, sensor)
    near = p == 1
    assert near.any() and (d[near] == 1.0).all() and (d[p == 2] == 3.0).all()
    # the same scene with the near column farther than the wall: the wall wins there
    depth[:, 3] = 4.0
    d, p = register_depth_to_color(depth, player, sensor)
    assert (d[d > 0] == 3.0).all()
    with pytest.raises(InputError, match=r"depth \(5, 8\) and player \(6, 8\) must be \(6, 8\), the depth camera's"):
        register_depth_to_color(depth[:-1], player, sensor)
    with pytest.raises(InputError, match="must be"):
        register_depth_to_color(depth, player[:, :-1], sensor)


# --- reading frames (stand-in session) -----------------------------------------------------------------

class _Session:
    def __init__(self, frames, sensor=None, path="S"):
        from pathlib import Path

        self.path = Path(path)
        self.kinect = sensor
        self._frames = frames
        self.frame_ids = sorted(frames)

    def frame(self, i):
        return self._frames[i]


def _frame(i, sensor, bodies=(), rgb=True, depth=True, player=True, shape=None):
    ch, cw = sensor.color.height, sensor.color.width
    dh, dw = shape or (sensor.depth.height, sensor.depth.width)
    return SimpleNamespace(kinect_rgb=np.full((ch, cw, 3), i, np.uint8) if rgb else None,
                           kinect_depth_m=np.ones((dh, dw)) if depth else None,
                           kinect_player=np.zeros((dh, dw), np.uint8) if player else None,
                           kinect_bodies=list(bodies))


def _body(player, names, nan_joint=None, tracked=None):
    pos = np.arange(3.0 * len(names)).reshape(-1, 3)
    if nan_joint is not None:
        pos[nan_joint] = np.nan
    return {"player": player, "names": list(names), "positions": pos,
            "tracked": np.ones(len(names), bool) if tracked is None else tracked}


def test_read_mirror_frame_sorts_bodies_and_untracks_missing_joints():
    sensor = _sensor()
    names = kinect_joint_names("v2")
    tracked = np.ones(len(names), bool)
    tracked[5] = False
    bodies = [_body(3, names, nan_joint=2, tracked=tracked), _body(1, names)]
    s = _Session({4: _frame(4, sensor, bodies)}, sensor)
    f = read_mirror_frame(s, 4)
    assert f.index == 4 and isinstance(f.index, int) and [b.player for b in f.bodies] == [1, 3]
    b3 = f.body(3)
    assert isinstance(b3, TrackedBody) and b3.names == tuple(names)
    assert not b3.tracked[2] and not b3.tracked[5] and b3.tracked.sum() == len(names) - 2
    assert not b3.positions.flags.writeable and not b3.tracked.flags.writeable
    assert f.body(2) is None and f.body(1).tracked.all()
    assert (f.rgb == 4).all() and f.depth_m.shape == (h, w)
    # the session's arrays are not changed
    assert bodies[0]["tracked"][2] and np.isnan(bodies[0]["positions"][2]).all()
    # no joints file: nobody
    s2 = _Session({0: SimpleNamespace(**{**vars(_frame(0, sensor)), "kinect_bodies": None})}, sensor)
    assert read_mirror_frame(s2, 0).bodies == ()
    assert [fr.index for fr in iter_mirror_frames(_Session({2: _frame(2, sensor), 0: _frame(0, sensor)}, sensor))] \
        == [0, 2]
    assert [fr.index for fr in iter_mirror_frames(_Session({2: _frame(2, sensor), 0: _frame(0, sensor)}, sensor),
                                                  [2])] == [2]


def test_read_mirror_frame_refusals():
    sensor = _sensor()
    with pytest.raises(SessionError, match="^S: not a Kinect session \\(no kinect/calibration.json\\); the mirror "
                       "needs Kinect colour, depth, player mask and joints \\(`bodystudio synth mirror` or capture "
                       "import\\)$"):
        read_mirror_frame(_Session({0: None}, None), 0)
    with pytest.raises(SessionError, match="not a Kinect session"):
        list(iter_mirror_frames(_Session({0: None}, None)))
    for key, stream, what in (("rgb", "kinect/rgb", "colour image"), ("depth", "kinect/depth", "depth image"),
                              ("player", "kinect/player", "player mask")):
        s = _Session({3: _frame(3, sensor, **{key: False})}, sensor)
        with pytest.raises(SessionError, match=f"S/{stream}.*: missing, frame 3 has no Kinect {what}; the mirror"):
            read_mirror_frame(s, 3)
    big = _Session({0: _frame(0, sensor, shape=(h + 1, w))}, sensor)
    with pytest.raises(SessionError, match=r"kinect/depth.*: image is 8x7 but kinect/calibration.json says 8x6"):
        read_mirror_frame(big, 0)
    s = _Session({0: SimpleNamespace(**{**vars(_frame(0, sensor)), "kinect_rgb": np.zeros((h, w + 1, 3), np.uint8)})},
                 sensor)
    with pytest.raises(SessionError, match="kinect/rgb.*: image is 9x6 but kinect/calibration.json says 8x6"):
        read_mirror_frame(s, 0)
    s = _Session({0: SimpleNamespace(**{**vars(_frame(0, sensor)), "kinect_player": np.zeros((h, 2), np.uint8)})},
                 sensor)
    with pytest.raises(SessionError, match="kinect/player.*: image is 2x6"):
        read_mirror_frame(s, 0)
    s = _Session({1: _frame(1, sensor, [_body(1, kinect_joint_names("v1"))])}, sensor)
    with pytest.raises(SessionError, match="kinect/joints.*: joints are not the Kinect v2 joint set"):
        read_mirror_frame(s, 1)
