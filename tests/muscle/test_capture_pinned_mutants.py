"""Fast tests of the pinned-sequence switch of the arm capture and what it reaches (issue 17's mutation tests,
docs/mutation/muscle-capture.md "The pinned-sequence switch"): ``refine.tracker_mean_standard_error``, the placement
prior's weight built on it, ``capture.sequence_options``' gate at its boundaries, the option's check, which captures
ask the gate and that its options reach the sequence fit, and the capture's regressed joints (returned, written,
read back, checked). The tiny model's two frames of test_capture_mutants.py where the real pipeline must run.
"""

import json
from dataclasses import replace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle import capture as cap_mod
from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
from tests.muscle.test_capture_mutants import FAST, _scene, _tiny_capture


def _tracker(n_frames, sd=(0.004, 0.009, 0.002), seed=3):
    """(T, 3, 3) shoulder, elbow, wrist with per-coordinate shoulder scatter ``sd`` (m)."""
    rng = np.random.default_rng(seed)
    base = np.array([[0.2, 1.4, 2.0], [0.2, 1.1, 2.05], [0.25, 0.85, 2.0]])
    T = np.repeat(base[None], n_frames, axis=0)
    T[:, 0] += rng.normal(0.0, 1.0, (n_frames, 3)) * np.asarray(sd)
    T[:, 1:] += rng.normal(0.0, 0.03, (n_frames, 2, 3))
    return T


def _se_by_hand(T):
    S = np.asarray(T, float).reshape(len(T), -1, 3)[:, 0]
    var = [np.mean((S[:, c] - np.mean(S[:, c])) ** 2) for c in range(3)]
    return float(np.sqrt(sum(var) / 3 / len(S)))


def test_the_standard_error_is_the_shoulders_per_coordinate_scatter_mean_over_the_frames():
    from bodystudio.muscle.refine import tracker_mean_standard_error

    T = _tracker(7)
    assert tracker_mean_standard_error(T) == pytest.approx(_se_by_hand(T), rel=1e-12)
    # a flat (T, 9) track is the same; the elbow and wrist do not count
    assert tracker_mean_standard_error(T.reshape(7, 9)) == pytest.approx(_se_by_hand(T), rel=1e-12)
    moved = T.copy()
    moved[:, 1:] += np.random.default_rng(9).normal(0.0, 0.1, (7, 2, 3))
    assert tracker_mean_standard_error(moved) == pytest.approx(_se_by_hand(T), rel=1e-12)
    assert isinstance(tracker_mean_standard_error(T), float)


def test_the_placement_prior_weight_is_the_squared_length_over_the_squared_standard_error():
    from bodystudio.muscle.refine import tracker_mean_standard_error, tracker_placement_prior_weight

    T = _tracker(11)
    se = tracker_mean_standard_error(T)
    assert tracker_placement_prior_weight(T, 0.02) == pytest.approx(0.02 ** 2 / se ** 2, rel=1e-12)
    still = T.copy()
    still[:, 0] = [0.2, 1.4, 2.0]
    assert tracker_placement_prior_weight(still, 0.02) == pytest.approx(0.02 ** 2 / 1e-12, rel=1e-12)


def test_the_gate_pins_at_or_below_its_standard_error_from_its_frame_count_on():
    from bodystudio.muscle.refine import tracker_mean_standard_error

    n = cap_mod.PINNED_MIN_FRAMES
    T = _tracker(n)
    se = tracker_mean_standard_error(T)
    o = CaptureOptions(refine_data_weight=0.4, sequence_rounds=2, sequence_pinned_se_m=se)
    pinned = cap_mod.sequence_options(o, T)
    assert pinned == replace(o, **cap_mod.PINNED_SEQUENCE)  # at the gate's value exactly: pinned
    assert cap_mod.sequence_options(replace(o, sequence_pinned_se_m=se * (1 - 1e-9)), T).norm_limit == o.norm_limit
    assert cap_mod.sequence_options(o, T[:-1]) is o  # one frame short
    assert cap_mod.sequence_options(o, list(T)).norm_limit == 0.05  # any array-like track
    still = T.copy()
    still[:, 0] = [0.25, 1.5, 2.0]  # exactly representable: the mean is exact and the SE exactly 0
    assert tracker_mean_standard_error(still) == 0.0
    assert cap_mod.sequence_options(replace(o, sequence_pinned_se_m=1e-9), still).norm_limit == 0.05
    off = replace(o, sequence_pinned_se_m=0.0)
    assert cap_mod.sequence_options(off, still) is off  # 0 is off, even for a still tracker (SE 0)


def test_the_pinned_setting_gate_must_be_a_non_negative_number():
    for bad in (-0.001, float("nan")):
        with pytest.raises(InputError, match=rf"^sequence_pinned_se_m must be >= 0, got {bad}$"):
            CaptureOptions(sequence_pinned_se_m=bad)
    assert CaptureOptions(sequence_pinned_se_m=0.0).sequence_pinned_se_m == 0.0
    assert CaptureOptions(sequence_pinned_se_m=0.002).sequence_pinned_se_m == 0.002


class _Stop(Exception):
    pass


def test_a_capture_asks_the_gate_only_with_a_model_and_a_tracker_joint_set_for_every_frame(monkeypatch):
    asked = []

    def gate(options, tracker):
        asked.append((options, tracker))
        return options

    def stop():
        raise _Stop

    monkeypatch.setattr(cap_mod, "sequence_options", gate)
    monkeypatch.setattr(cap_mod, "_Timer", stop)
    template = type("T", (), {"key": "k"})()
    model = type("M", (), {"template_key": "k"})()
    depths = [np.zeros((4, 4))] * 3
    T = _tracker(3)
    o = CaptureOptions(mode="model", sequence_pinned_se_m=0.001)
    for m, tracker, mode, expected in ((model, T, "model", True), (model, None, "model", False),
                                       (model, T[:2], "model", False), (None, T, "nicp", False)):
        asked.clear()
        oo = replace(o, mode=mode)
        with pytest.raises(_Stop):
            capture_arm_frames(depths, "camera", template, m, oo, tracker_joints=tracker)
        assert bool(asked) == expected, (m, None if tracker is None else len(tracker), mode)
        if expected:
            assert asked[0][0] is oo and asked[0][1] is tracker


@pytest.mark.parametrize("se_m", [0.0, 1.0])
def test_the_gates_options_reach_the_sequence_fit(monkeypatch, se_m):
    """The tiny model's two frames with the gate opened to 2 frames and 1 m: the sequence fit gets the pinned norm
    limit, tracker weight, fitted placement and skeleton, Huber on the depth only and the chest pairs off; with the
    gate off the options as given."""
    scene = _scene()
    seen = {}

    def record(*args, **kwargs):
        seen.update(kwargs, norm_limit=args[5], tracker_weight=args[7], fit_root=args[12], fit_skeleton=args[13],
                    depth_huber_only=args[15])
        raise _Stop

    monkeypatch.setattr(cap_mod, "fit_arm_sequence_skeleton", record)
    monkeypatch.setattr(cap_mod, "PINNED_MIN_FRAMES", 2)
    o = CaptureOptions(mode="model", **FAST, sequence_pinned_se_m=se_m,
                       sequence_depth_huber_only=False)  # not the default: the pinned setting must set it
    with pytest.raises(_Stop):
        capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model, o, tracker_joints=scene.tracker,
                           known_shape=scene.shape)
    got = {k: seen[k] for k in ("norm_limit", "tracker_weight", "fit_root", "fit_skeleton", "depth_huber_only",
                                "torso_pair_weight")}
    assert got == ({"norm_limit": 0.05, "tracker_weight": 10.0, "fit_root": True, "fit_skeleton": True,
                    "depth_huber_only": True, "torso_pair_weight": 0.0} if se_m else
                   {"norm_limit": 0.2, "tracker_weight": o.sequence_tracker_weight, "fit_root": False,
                    "fit_skeleton": False, "depth_huber_only": False, "torso_pair_weight": 1.0})


def test_a_model_capture_returns_the_rest_joints_its_model_regresses_for_its_shape():
    from bodystudio.muscle.model import model_joints

    scene = _scene()
    c = capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model,
                           CaptureOptions(mode="model", **FAST), tracker_joints=scene.tracker, known_shape=scene.shape)
    assert c.regressed_joints.shape == (3, 3) and c.regressed_joints.dtype == np.float64
    np.testing.assert_allclose(c.regressed_joints, model_joints(scene.model, c.shape), atol=1e-12)
    # the default: the body model's skeleton fitted to the depth (body_rest_shape), not the regressed joints
    assert c.joints.shape == (3, 3) and c.joints.dtype == np.float64 and c.joints is not c.regressed_joints
    assert np.abs(c.joints - c.regressed_joints).max() > 1e-4
    # no skeleton fitted: the capture's joints are those same regressed ones, a copy of its own
    c = capture_arm_frames(scene.depths, scene.camera, scene.template, scene.model,
                           CaptureOptions(mode="model", body_rest_shape=False, **FAST), tracker_joints=scene.tracker,
                           known_shape=scene.shape)
    np.testing.assert_allclose(c.regressed_joints, model_joints(scene.model, c.shape), atol=1e-12)
    assert c.joints.shape == (3, 3) and c.joints.dtype == np.float64 and c.joints is not c.regressed_joints
    np.testing.assert_allclose(c.joints, c.regressed_joints, atol=1e-12)
    n = capture_arm_frames(scene.depths, scene.camera, scene.template, None,
                           CaptureOptions(mode="nicp", **FAST), tracker_joints=scene.tracker)
    assert n.regressed_joints is None and n.joints is None


def test_the_regressed_joints_round_trip_through_the_folder(tmp_path):
    R = (np.arange(9.0).reshape(3, 3) + 0.5) / 9
    cap_mod.write_arm_capture(tmp_path / "a", replace(_tiny_capture(joints=np.eye(3)), regressed_joints=R))
    params = json.loads((tmp_path / "a" / "params.json").read_text())
    assert params["regressed_joints"] == R.tolist()
    back = cap_mod.load_arm_capture(tmp_path / "a")
    np.testing.assert_array_equal(back.regressed_joints, R)
    assert back.regressed_joints.shape == (3, 3) and back.regressed_joints.dtype == np.float64
    np.testing.assert_array_equal(back.joints, np.eye(3))
    cap_mod.write_arm_capture(tmp_path / "b", _tiny_capture())
    params = json.loads((tmp_path / "b" / "params.json").read_text())
    assert "regressed_joints" in params and params["regressed_joints"] is None
    assert cap_mod.load_arm_capture(tmp_path / "b").regressed_joints is None
    # a folder written before the field: none; a flat list of 9: the (3, 3) joints
    del params["regressed_joints"]
    (tmp_path / "b" / "params.json").write_text(json.dumps(params))
    assert cap_mod.load_arm_capture(tmp_path / "b").regressed_joints is None
    params["regressed_joints"] = R.ravel().tolist()
    (tmp_path / "b" / "params.json").write_text(json.dumps(params))
    np.testing.assert_array_equal(cap_mod.load_arm_capture(tmp_path / "b").regressed_joints, R)
    # whole numbers in a hand-edited file are read as float64 too
    params["regressed_joints"] = [[0, 1, 2], [3, 4, 5], [6, 7, 8]]
    (tmp_path / "b" / "params.json").write_text(json.dumps(params))
    back = cap_mod.load_arm_capture(tmp_path / "b").regressed_joints
    assert back.dtype == np.float64 and back.tolist() == [[0, 1, 2], [3, 4, 5], [6, 7, 8]]


@pytest.mark.parametrize("value", [float("nan"), float("inf"), [1.0, 2.0]])
def test_bad_regressed_joints_are_refused(tmp_path, value):
    out = tmp_path / "out"
    cap_mod.write_arm_capture(out, replace(_tiny_capture(), regressed_joints=np.eye(3)))
    params = json.loads((out / "params.json").read_text())
    if isinstance(value, list):
        params["regressed_joints"] = value
        msg = r"not a readable arm capture folder \(ValueError"
    else:
        params["regressed_joints"][1][2] = value
        msg = r"params.json: regressed_joints is NaN or infinite; re-run bodystudio muscle capture$"
    (out / "params.json").write_text(json.dumps(params).replace("NaN", "NaN"))
    with pytest.raises(FileFormatError, match=msg):
        cap_mod.load_arm_capture(out)
