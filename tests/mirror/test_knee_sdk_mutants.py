"""mir12ac's knee angle from the SDK's joints against hand-built legs (mutOO; < 1 s, no body model).

``sdk_knee_angle`` on legs whose rest knee angle is set by construction (vertical thighs, the calf turned out by a
known angle, a frame bent forward past the flexion limit); ``knee_joint_frames`` on a stand-in session whose bodies
lie at distances exact in binary from the observations' joints; ``knee_angle_rows`` on stand-in linear joints
(``_model_kinect_joints`` replaced) against a central-difference gradient of the angle written from its docstring.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.mirror import init as init_mod

NAMES = kinect_joint_names("v2")
IX = {n: NAMES.index(n) for n in NAMES}


def _legs(out_left, out_right, flex_left=0.0, shift=(0.0, 0.0, 0.0)):
    """SDK joints (J, 3), NaN but the legs: thighs 0.4 m straight down from hips 0.2 m apart, each calf turned out
    by its angle (radians) in the frontal plane, the left one also bent forward by ``flex_left``."""
    K = np.full((len(NAMES), 3), np.nan)
    for side, out, flex, (h, k, a) in ((1, out_left, flex_left, ("HipLeft", "KneeLeft", "AnkleLeft")),
                                       (-1, out_right, 0.0, ("HipRight", "KneeRight", "AnkleRight"))):
        K[IX[h]] = [0.1 * side, 0.0, 0.0]
        K[IX[k]] = [0.1 * side, -0.4, 0.0]
        c = np.array([side * np.sin(out) * np.cos(flex), -np.cos(out) * np.cos(flex), np.sin(flex)])
        K[IX[a]] = K[IX[k]] + 0.4 * c
    return K + np.asarray(shift)


def _obs(K, version="v2", tracked=None, frame=0):
    tracked = np.isfinite(K).all(axis=1) if tracked is None else tracked
    return SimpleNamespace(joints=K, tracked=tracked, version=version, frame=frame)


def test_sdk_knee_angle_is_the_mean_over_legs_and_frames_with_its_standard_error():
    obs = [_obs(_legs(0.05, 0.03)), _obs(_legs(0.07, 0.01, shift=(0.3, 0.1, 2.0)))]
    mean, se = init_mod.sdk_knee_angle(obs, "v2")
    v = np.array([0.05, 0.03, 0.07, 0.01])
    assert mean == pytest.approx(v.mean(), abs=1e-12)
    assert se == pytest.approx(v.std() / 2.0, abs=1e-12)


def test_sdk_knee_angle_skips_bent_untracked_and_other_version_frames():
    bent = _legs(0.0, 0.02, flex_left=np.radians(30))  # left knee bent 30 deg: only the right leg counts
    lost = _legs(0.2, 0.2)
    tracked = np.isfinite(lost).all(axis=1)
    tracked[IX["AnkleRight"]] = False
    nan = _legs(0.2, 0.2)
    nan[IX["KneeLeft"]] = np.nan
    obs = [_obs(_legs(0.04, 0.06)), _obs(bent), _obs(lost, tracked=tracked), _obs(nan, tracked=np.ones(25, bool)),
           _obs(_legs(0.3, 0.3), version="v1")]
    mean, se = init_mod.sdk_knee_angle(obs, "v2")
    v = np.array([0.04, 0.06, 0.02])
    assert mean == pytest.approx(v.mean(), abs=1e-12) and se == pytest.approx(v.std() / np.sqrt(3), abs=1e-12)
    # a wider flexion limit takes the bent leg too (its rest angle is 0)
    mean, _ = init_mod.sdk_knee_angle(obs, "v2", max_flexion_deg=31.0)
    assert mean == pytest.approx(np.mean([0.04, 0.06, 0.0, 0.02]), abs=1e-12)
    mean, _ = init_mod.sdk_knee_angle(obs, "v2", max_flexion_deg=29.0)
    assert mean == pytest.approx(v.mean(), abs=1e-12)
    assert init_mod.sdk_knee_angle([_obs(lost, tracked=tracked)], "v2") == (None, None)
    assert init_mod.sdk_knee_angle([], "v2") == (None, None)


def test_sdk_knee_angle_reads_v1_joints_by_their_names():
    names1 = kinect_joint_names("v1")
    K2 = _legs(0.05, 0.01)
    K1 = np.full((len(names1), 3), np.nan)
    for n in ("HipLeft", "KneeLeft", "AnkleLeft", "HipRight", "KneeRight", "AnkleRight"):
        K1[names1.index(init_mod._kinect_name(n, "v1"))] = K2[IX[n]]
    mean, _ = init_mod.sdk_knee_angle([_obs(K1, version="v1"), _obs(K2)], "v1")
    assert mean == pytest.approx(0.03, abs=1e-12)


def _body(K, player=1, dx=0.0):
    P = np.asarray(K, float) + [dx, 0.0, 0.0]
    return {"player": player, "positions": P.tolist(), "tracked": [True] * len(P)}


def test_knee_joint_frames_take_the_nearest_body_within_reach_between_the_observations():
    K0 = np.zeros((4, 3))
    K0[:, 1] = [0.0, 0.5, 1.0, 1.5]
    obs = [_obs(K0 + [0.0, 0, 0], version="a", frame=10), _obs(K0 + [1.0, 0, 0], version="b", frame=14)]
    half = np.array(K0, float)
    half[0] = np.nan
    frames = {
        9: [_body(K0)],  # before the first observation
        10: [_body(K0, 3, dx=0.125), _body(K0, 2, dx=0.0625), _body(np.zeros((3, 3)), 4)],  # nearest: player 2
        11: [_body(K0, dx=0.25)],  # at the reach exactly: not the actor
        12: [_body(K0, 5, dx=0.0625)],  # as near to frame 10's as to 14's joints (1 m): frame 10's
        13: [_body(K0, 6, dx=0.9375), _body(np.full((4, 3), np.nan), 7, dx=0.9375)],
        14: None,
        15: [_body(K0, dx=1.0)],  # after the last observation
        16: [{**_body(half, 8, dx=1.0)}],
    }
    session = SimpleNamespace(frame_ids=np.arange(9, 17),
                              frame=lambda i: SimpleNamespace(kinect_bodies=frames[int(i)]))
    out = init_mod.knee_joint_frames(session, obs[::-1])
    assert [f.frame for f in out] == [10, 12, 13]
    assert all(type(f.frame) is int for f in out)
    np.testing.assert_allclose(out[0].joints, K0 + [0.0625, 0, 0])
    assert [f.version for f in out] == ["a", "a", "b"]
    np.testing.assert_allclose(out[2].joints, K0 + [0.9375, 0, 0])
    np.testing.assert_array_equal(out[1].tracked, [True] * 4)
    # a body's untracked and NaN joints are not tracked; a wider reach takes frame 11
    frames[11] = [{**_body(half, 9, dx=0.25), "tracked": [True, True, False, True]}]
    out = init_mod.knee_joint_frames(session, obs, reach_m=0.5)
    assert [f.frame for f in out] == [10, 11, 12, 13]
    np.testing.assert_array_equal(out[1].tracked, [False, True, False, True])
    assert init_mod.knee_joint_frames(session, []) == []


def _angle(hip, knee, ankle, side):
    """The docstring's angle: asin of the calf direction along the x axis made normal to the thigh, signed by side."""
    t = (knee - hip) / np.linalg.norm(knee - hip)
    c = (ankle - knee) / np.linalg.norm(ankle - knee)
    a = np.array([1.0, 0, 0]) - t[0] * t
    return side * np.arcsin(a @ c / np.linalg.norm(a))


def test_knee_angle_rows_are_the_linearised_angle_scaled_by_the_calf(monkeypatch):
    rng = np.random.default_rng(3)
    Jm = np.nan_to_num(_legs(0.04, -0.02, flex_left=0.2))
    Jb = 0.01 * rng.normal(size=(5, len(NAMES), 3))
    monkeypatch.setattr(init_mod, "_model_kinect_joints", lambda model, version: (Jm, Jb))
    c0 = np.array([0.3, -0.2, 0.5, 0.1, -0.4])
    A, b = init_mod.knee_angle_rows(None, c0, 0.05, weight=400.0)
    assert A.shape == (2, 5) and b.shape == (2,)
    for row, (side, leg) in enumerate(((1, ("HipLeft", "KneeLeft", "AnkleLeft")),
                                       (-1, ("HipRight", "KneeRight", "AnkleRight")))):
        idx = [IX[n] for n in leg]

        def k(c, idx=idx, side=side):
            P = Jm + np.tensordot(c, Jb, axes=1)
            return _angle(*P[idx], side)

        h = 1e-6
        g = np.array([(k(c0 + h * e) - k(c0 - h * e)) / (2 * h) for e in np.eye(5)])
        P0 = Jm + np.tensordot(c0, Jb, axes=1)
        L = np.linalg.norm(P0[idx[2]] - P0[idx[1]])
        np.testing.assert_allclose(A[row], 20.0 * L * g, rtol=1e-3, atol=1e-9)
        assert b[row] == pytest.approx(20.0 * L * (0.05 - k(c0) + g @ c0), rel=1e-3, abs=1e-9)
    # the default weight is KNEE_HINGE_WEIGHT
    A2, _ = init_mod.knee_angle_rows(None, c0, 0.05)
    np.testing.assert_allclose(A2, A * np.sqrt(init_mod.KNEE_HINGE_WEIGHT) / 20.0, rtol=1e-12)


# --- the first run's survivors ---


def test_sdk_knee_angle_goes_on_past_skipped_frames_and_takes_a_straight_leg():
    lost = _legs(0.2, 0.2)
    tracked = np.isfinite(lost).all(axis=1)
    tracked[IX["KneeRight"]] = False
    straight = _legs(0.0, 0.03)  # a left leg whose thigh . calf rounds to 1.0000000000000002: clipped, 0 degrees
    t = np.array([-0.535669373161111, 0.36159505490948474, 1.3040000451301372])
    c = np.array([-0.8539881348987823, 0.5764710509926761, 2.0788953452331893])
    assert t @ c / (np.linalg.norm(t) * np.linalg.norm(c)) > 1.0
    straight[IX["KneeLeft"]] = straight[IX["HipLeft"]] + t
    straight[IX["AnkleLeft"]] = straight[IX["KneeLeft"]] + c
    obs = [_obs(_legs(0.5, 0.5), version="v1"), _obs(lost, tracked=tracked), _obs(_legs(0.04, 0.06)), _obs(straight)]
    mean, _ = init_mod.sdk_knee_angle(obs, "v2")
    assert mean == pytest.approx(np.mean([0.04, 0.06, 0.0, 0.03]), abs=1e-9)


def test_sdk_knee_angle_of_tilted_thighs_against_the_docstrings_angle():
    rng = np.random.default_rng(7)
    legs = ((1, "HipLeft", "KneeLeft", "AnkleLeft"), (-1, "HipRight", "KneeRight", "AnkleRight"))
    frames, want = [], []
    for _ in range(4):
        K = np.full((len(NAMES), 3), np.nan)
        for side, h, k, a in legs:
            K[IX[h]] = [0.1 * side, 0.0, 0.0] + 0.02 * rng.normal(size=3)
            K[IX[k]] = K[IX[h]] + [0.08 * side, -0.4, 0.1] + 0.02 * rng.normal(size=3)  # a thigh out and forward
            K[IX[a]] = K[IX[k]] + 0.9 * (K[IX[k]] - K[IX[h]]) + [0.03 * side, 0.0, 0.0]
        lateral = K[IX["HipLeft"]] - K[IX["HipRight"]]
        for side, h, k, a in legs:
            t = (K[IX[k]] - K[IX[h]]) / np.linalg.norm(K[IX[k]] - K[IX[h]])
            c = (K[IX[a]] - K[IX[k]]) / np.linalg.norm(K[IX[a]] - K[IX[k]])
            n = lateral - (lateral @ t) * t
            want.append(side * np.arcsin(n @ c / np.linalg.norm(n)))
        frames.append(_obs(K))
    mean, _ = init_mod.sdk_knee_angle(frames, "v2")
    assert mean == pytest.approx(np.mean(want), abs=1e-12)
    assert abs(np.mean(want)) > 0.01


def test_sdk_knee_angle_flexion_limit_is_strict():
    K = _legs(0.0, 0.0, flex_left=np.radians(25))
    t, c = K[IX["KneeLeft"]] - K[IX["HipLeft"]], K[IX["AnkleLeft"]] - K[IX["KneeLeft"]]
    flexion = np.degrees(np.arccos(np.clip(t @ c / (np.linalg.norm(t) * np.linalg.norm(c)), -1, 1)))
    K[IX["AnkleRight"]] = K[IX["KneeRight"]] + [-0.4 * np.sin(0.05), -0.4 * np.cos(0.05), 0.0]
    mean, _ = init_mod.sdk_knee_angle([_obs(K)], "v2", max_flexion_deg=flexion)
    assert mean == pytest.approx(0.05, abs=1e-12)  # the leg bent exactly to the limit is left out


def test_knee_joint_frames_edges():
    K0 = np.zeros((4, 3))
    K0[:, 1] = [0.0, 0.5, 1.0, 1.5]
    obs = [_obs(K0, version="a", frame=10), _obs(K0 + [1.0, 0, 0], version="b", frame=12),
           _obs(K0 + [2.0, 0, 0], version="c", frame=14)]
    nulls = {"player": 3, "positions": [[None, None, None]] + (K0[1:] + [0.0625, 0, 0]).tolist(),
             "tracked": [1, 1, 0, 1]}
    frames = {10: [_body(np.zeros((3, 3)), 4), nulls], 11: [], 12: [_body(K0, dx=1.0)],
              13: [_body(K0, dx=1.5)], 14: [_body(K0, dx=2.0)]}
    session = SimpleNamespace(frame_ids=[10, 11, 12, 13, 14],
                              frame=lambda i: SimpleNamespace(kinect_bodies=frames[int(i)]))
    out = init_mod.knee_joint_frames(session, obs)
    assert [f.frame for f in out] == [10, 12, 14]  # 13 is 0.5 m off both 12's and 14's joints
    assert out[0].tracked.dtype == bool
    np.testing.assert_array_equal(out[0].tracked, [False, True, False, True])
    assert np.isnan(out[0].joints[0]).all() and out[0].joints.dtype == np.float64
    assert [f.version for f in out] == ["a", "b", "c"]


def test_knee_angle_rows_read_the_models_joints_of_the_version(monkeypatch):
    seen = []
    Jm = np.nan_to_num(_legs(0.04, -0.02))
    monkeypatch.setattr(init_mod, "_model_kinect_joints", lambda model, version: seen.append((model, version))
                        or (Jm, np.zeros((2, len(NAMES), 3))))
    model = object()
    init_mod.knee_angle_rows(model, [0.0, 0.0], 0.0, version="v2")
    assert seen == [(model, "v2")]
