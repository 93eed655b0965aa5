"""Fast tests of ``capture.sequence_stage``'s rest-shape stop (``CaptureOptions.body_rest_keep_best``: the rounds stop
when ``refine.depth_energy_mm`` on the frames the rest-shape fit does not use stops falling, and the previous round is
kept) and of its switch (``body_rest_fit_poses``: ``fit_body_rest_shape_and_poses`` instead of
``fit_body_rest_shape``), with every fit stubbed (issue 17, mutation testing of mus11d; branch mutL). Each test runs
in milliseconds."""

import logging
from types import SimpleNamespace

import numpy as np

from bodystudio.muscle import capture as cap
from bodystudio.muscle import model as mm
from bodystudio.muscle.arm import ArmPose
from bodystudio.muscle.capture import CaptureOptions

N_FRAMES = 11


class _Space:
    """Stand-in body shape space: a parameter vector ``x`` -> a rest mesh and joints that carry ``x``."""

    def __init__(self):
        self.calls = []

    def prior(self, shape, local_sigma=None):
        return np.array([0.5]), np.array([0.2])

    def rest_and_joints(self, x, anchor):
        self.calls.append((np.array(x), np.array(anchor)))
        return np.full((4, 3), float(x[0])), np.array(anchor) + float(x[0]) * np.ones((3, 3))


def _stage(monkeypatch, energies=None, **opts):
    """Run sequence_stage with the fits stubbed; returns the result and what each stub saw."""
    seen = SimpleNamespace(seq=[], held=[], joint=[], energy=[], correction=[])
    space = _Space()
    monkeypatch.setattr(mm, "body_shape_space", lambda template: space)
    monkeypatch.setattr(mm, "project_to_body_space", lambda s, base, J, mean, sigma: np.array([1.0]))

    def seq(model, shape, poses, frames, J, *args, rest=None, **kw):
        k = len(seen.seq)
        seen.seq.append(SimpleNamespace(poses=poses, J=J, rest=rest))
        out = [ArmPose(p.root.copy(), p.angles + 0.01 * (k + 1)) for p in poses]
        return out, J + 0.001 * (k + 1)

    def held(space_, model, poses, frames, x, anchor, mean, sigma, *args):
        seen.held.append(SimpleNamespace(poses=poses, frames=frames, x=x.copy(), anchor=anchor, args=args,
                                         space=space_, model=model, mean=mean, sigma=sigma))
        return x + 1.0, np.array([0.001, 0.0, -0.002]) * len(seen.held)

    def joint(space_, model, poses, frames, x, anchor, mean, sigma, *args):
        seen.joint.append(SimpleNamespace(poses=poses, frames=frames, x=x.copy(), anchor=anchor, args=args,
                                          mean=mean, sigma=sigma, space=space_, model=model))
        junk = [ArmPose(np.eye(4) * 7, p.angles * 0 + 9) for p in poses]  # the joint fit's poses are not used
        return x + 1.0, np.array([0.001, 0.0, -0.002]) * len(seen.joint), junk

    def energy(model, poses, frames, rest, joints, norm_limit, huber_m):
        seen.energy.append(SimpleNamespace(model=model, poses=poses, frames=frames, rest=rest, joints=joints,
                                           norm_limit=norm_limit, huber_m=huber_m))
        return energies[len(seen.energy) - 1]

    def correction(*args):
        seen.correction.append(args)
        return args[4] + 0.5

    monkeypatch.setattr(cap, "fit_arm_sequence_skeleton", seq)
    monkeypatch.setattr(cap, "fit_body_rest_shape", held)
    monkeypatch.setattr(cap, "fit_body_rest_shape_and_poses", joint)
    monkeypatch.setattr(cap, "depth_energy_mm", energy)
    monkeypatch.setattr(cap, "fit_rest_shape_correction", correction)
    # the held-pose fit unless a test asks for the joint fit (the default since the tenth pass)
    base = dict(mode="model", body_rest_shape=True, body_rest_rounds=3, body_rest_frame_stride=4,
                sequence_placement_prior_m=0.0, body_rest_fit_poses=False, sequence_min_facing_cos=0.0,
                body_rest_tracker_weight=None,  # None: the sequence fit's tracker weight, as these tests pin
                body_rest_population_locals=0.0, body_rest_local_sigma=0.25)  # the stand-in space has no targets
    base.update(opts)
    o = CaptureOptions(**base)
    poses = [ArmPose(np.eye(4), np.full((3, 3), 0.1 * k)) for k in range(N_FRAMES)]
    frames = [f"frame{k}" for k in range(N_FRAMES)]
    tracker = np.arange(N_FRAMES * 9, dtype=float).reshape(N_FRAMES, 3, 3)
    J = np.array([[0.0, 1.0, 0.0], [0.3, 1.0, 0.0], [0.55, 1.0, 0.0]])
    known = SimpleNamespace(arm_length_m=0.61)
    out = cap.sequence_stage("model", "template", "shape", poses, frames, tracker, np.zeros((4, 3)), J, o, known)
    seen.space = space
    return out, seen, o, poses, frames, tracker, J


def test_the_rounds_stop_at_the_first_energy_not_below_the_previous_and_keep_that_round(monkeypatch, caplog):
    with caplog.at_level(logging.INFO, logger=cap.__name__):
        (poses, base, J), seen, o, poses0, frames, _, _ = _stage(monkeypatch, energies=[3.0, 2.0, 2.5, 1.0])
    assert len(seen.seq) == 3 and len(seen.held) == 2 and len(seen.energy) == 3  # round 2 raised it: no round 3
    # round 1's poses, rest mesh and skeleton (the sequence fit's output), not round 2's
    r1 = seen.seq[1]
    np.testing.assert_array_equal(base, r1.rest)
    np.testing.assert_array_equal(J, r1.J + 0.002)
    np.testing.assert_allclose([p.angles for p in poses], [p.angles + 0.02 for p in r1.poses], atol=1e-12)
    assert not np.allclose(J, seen.seq[2].J + 0.003)
    # the energy: the held-out frames (stride 4: frames 2, 6, 10), the round's poses, rest mesh and skeleton
    for r, e in enumerate(seen.energy):
        assert e.frames == frames[2::4]
        assert len(e.poses) == 3
        np.testing.assert_allclose([p.angles for p in e.poses],
                                   [p.angles + 0.01 * (r + 1) for p in seen.seq[r].poses[2::4]], atol=1e-12)
        np.testing.assert_array_equal(e.rest, seen.seq[r].rest)
        np.testing.assert_array_equal(e.joints, seen.seq[r].J + 0.001 * (r + 1))
        assert (e.norm_limit, e.huber_m) == (o.norm_limit, o.sequence_huber_m)
    assert [r.getMessage() for r in caplog.records if r.name == cap.__name__ and "rest-shape" in r.getMessage()] \
        == ["rest-shape round 0: depth energy 3.000 mm", "rest-shape round 1: depth energy 2.000 mm",
            "rest-shape round 2: depth energy 2.500 mm"]
    assert all(e.model == "model" for e in seen.energy)
    # the rest-shape fit's frames are the others (0, 4, 8), its tracker joints theirs
    assert [h.frames for h in seen.held] == [frames[0::4]] * 2
    assert len(poses0) == N_FRAMES


def test_an_equal_energy_stops_too_and_a_falling_one_runs_every_round(monkeypatch):
    (poses, base, J), seen, *_ = _stage(monkeypatch, energies=[2.0, 2.0])
    assert len(seen.seq) == 2 and len(seen.energy) == 2
    np.testing.assert_array_equal(J, seen.seq[0].J + 0.001)  # round 0's
    np.testing.assert_array_equal(base, seen.seq[0].rest)
    (poses, base, J), seen, *_ = _stage(monkeypatch, energies=[3.0, 2.0, 1.0, 0.5])
    assert len(seen.seq) == 4 and len(seen.energy) == 4
    np.testing.assert_array_equal(J, seen.seq[3].J + 0.004)  # the last round's
    np.testing.assert_array_equal(base, seen.seq[3].rest)


def test_without_the_stop_or_the_body_rest_shape_no_energy_is_computed(monkeypatch):
    (poses, base, J), seen, *_ = _stage(monkeypatch, body_rest_keep_best=False)
    assert len(seen.seq) == 4 and seen.energy == []
    np.testing.assert_array_equal(J, seen.seq[3].J + 0.004)
    (poses, base, J), seen, *_ = _stage(monkeypatch, body_rest_shape=False, personal_rounds=1)
    assert len(seen.seq) == 2 and seen.energy == [] and seen.held == [] and len(seen.correction) == 1


def test_a_stride_of_one_scores_every_frame(monkeypatch):
    _, seen, _, _, frames, _, _ = _stage(monkeypatch, energies=[3.0, 4.0], body_rest_frame_stride=1)
    assert [e.frames for e in seen.energy] == [frames, frames]
    assert seen.held[0].frames == frames
    _, seen, _, _, frames, _, _ = _stage(monkeypatch, energies=[3.0, 4.0], body_rest_frame_stride=2)
    assert seen.energy[0].frames == frames[1::2] and seen.held[0].frames == frames[0::2]


def test_the_switch_calls_the_joint_fit_with_the_held_pose_fits_arguments_and_its_damping(monkeypatch):
    (poses, base, J), seen, o, poses0, frames, tracker, J0 = _stage(
        monkeypatch, energies=[3.0, 2.0, 1.0, 0.5], body_rest_fit_poses=True, body_rest_prior_weight=7.0,
        body_rest_iterations=2, body_rest_arm_length_weight=40.0, sequence_tracker_weight=0.25,
        body_rest_angle_damping=0.3)
    assert seen.held == [] and len(seen.joint) == 3
    first = seen.joint[0]
    assert first.frames == frames[0::4]
    assert first.args[:6] == (7.0, o.norm_limit, o.sequence_huber_m, 2, 0.61, 40.0)
    np.testing.assert_array_equal(first.args[6], tracker[0::4])
    assert first.args[7:] == (0.25, 0.3)
    assert first.space is seen.space and first.model == "model"
    assert len(first.poses) == 3
    np.testing.assert_array_equal(first.x, [1.0])
    np.testing.assert_array_equal(first.anchor, J0[0])
    np.testing.assert_array_equal(first.mean, [1.0])  # the projection is the prior's mean
    np.testing.assert_array_equal(first.sigma, [0.2])
    np.testing.assert_array_equal(seen.joint[1].x, [2.0])  # the rounds go on from the last fit
    # the next sequence fit starts from the previous round's poses shifted by the placement (every frame), not from
    # the joint fit's own poses, on the fitted rest mesh and skeleton
    prev = [ArmPose(p.root, p.angles + 0.01) for p in seen.seq[0].poses]
    for p, q in zip(seen.seq[1].poses, prev, strict=True):
        np.testing.assert_allclose(p.angles, q.angles, atol=1e-12)
        np.testing.assert_allclose(p.root[:3, 3], q.root[:3, 3] + [0.001, 0.0, -0.002], atol=1e-12)
    assert len(seen.seq[1].poses) == N_FRAMES
    np.testing.assert_array_equal(seen.seq[1].rest, np.full((4, 3), 2.0))
    np.testing.assert_array_equal(seen.seq[1].J, J0[0] + 2.0 * np.ones((3, 3)))


def test_the_held_pose_fit_gets_the_placement_switch(monkeypatch):
    _, seen, o, _, frames, tracker, _ = _stage(monkeypatch, energies=[3.0, 2.0, 2.5], body_rest_prior_weight=7.0,
                                               body_rest_fit_placement=False)
    assert seen.joint == [] and len(seen.held) == 2
    h = seen.held[0]
    assert h.space is seen.space and h.model == "model" and len(h.poses) == 3 and h.frames == frames[0::4]
    np.testing.assert_array_equal(h.anchor, np.array([[0.0, 1.0, 0.0]])[0])
    np.testing.assert_array_equal(h.mean, [1.0])
    np.testing.assert_array_equal(h.sigma, [0.2])
    a = h.args
    assert a[:7] == (7.0, o.norm_limit, o.sequence_huber_m, o.body_rest_iterations, False, 0.61,
                     o.body_rest_arm_length_weight)
    np.testing.assert_array_equal(a[7], tracker[0::4])
    assert a[8:] == (o.sequence_tracker_weight,)


def test_one_rest_shape_round_is_also_stopped(monkeypatch):
    (poses, base, J), seen, *_ = _stage(monkeypatch, energies=[2.0, 3.0], body_rest_rounds=1)
    assert len(seen.seq) == 2 and len(seen.energy) == 2
    np.testing.assert_array_equal(J, seen.seq[0].J + 0.001)  # round 0's: round 1 raised the energy
