"""Issue 17's standard on mir12i's refined unposing (mutN): what :func:`refined_init_pose` hands the pose
refinement, that :func:`transform_to_default_pose` unposes by a given pose, and which passes / frames of
:func:`initialise_from_observations` refine (stand-in refinement and Eq. 2 fit on the 2K model; fast)."""

import functools
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body import Pose
from bodystudio.body.kinect import kinect_joint_names
from bodystudio.mirror import init as init_mod
from bodystudio.mirror import refine as refine_mod
from bodystudio.mirror.init import (
    UNPOSE_REFINE_STEPS,
    InitObservation,
    _vertex_normals,
    initialise_from_observations,
    refined_init_pose,
    transform_to_default_pose,
)
from bodystudio.mirror.track import ik_pose, posed_kinect_joints, skin_vertices


@functools.lru_cache(maxsize=1)
def _model_2k():
    """Loaded once per process (a module-level cache, so mutation-testing forks inherit it)."""
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.fixture(scope="module")
def model():
    return _model_2k()


def _frame(model, pose, eye, frame=0, mask=True, version="v2"):
    """Noise-free depth of the mean body in ``pose`` (its vertices facing ``eye``) and its Kinect joints; with
    ``mask`` stand-in SDK player / other-player masks (distinct arrays, to check which is handed on)."""
    body = model.body(np.zeros(model.n_components))
    V = skin_vertices(body.vertices, body.weights, body.skeleton, pose)
    N = _vertex_normals(V, body.faces)
    facing = np.einsum("nd,nd->n", N, eye - V) > 0.3 * np.linalg.norm(eye - V, axis=1)
    K = posed_kinect_joints(body.skeleton, pose, version)
    player = np.zeros((4, 5), bool) if mask else None
    others = np.ones((4, 5), bool) if mask else None
    if mask:
        player[1, frame % 5] = True
    return InitObservation(frame, V[facing], K, np.ones(len(K), bool), version, player_mask=player,
                           others_depth=others)


def _pose(n_bones, seed):
    rng = np.random.default_rng(seed)
    return Pose(rng.normal(0.0, 0.08, (n_bones, 3)), np.array([0.05 * seed, 0.0, 0.1]))


def test_refined_init_pose_refines_the_ik_of_the_frame(monkeypatch, model):
    body = model.body(np.zeros(model.n_components))
    eye = np.array([0.0, 1.0, 3.0])
    obs = _frame(model, _pose(body.skeleton.n_bones, 1), eye)
    elbow = kinect_joint_names("v2").index("ElbowLeft")  # lost by the tracker, and far off
    obs.tracked[elbow] = False
    obs.joints[elbow] += 0.3
    ik = ik_pose(body.skeleton, obs.joints, obs.tracked, obs.version)
    asked = []

    def spy_ik(*args):
        asked.append(args)
        return ik_pose(*args)

    monkeypatch.setattr(init_mod, "ik_pose", spy_ik)
    got = {}

    def refine_pose(plan, skeleton, pose, camera, foreground, *args, **kw):
        got.update(plan=plan, skeleton=skeleton, pose=pose, camera=camera, foreground=foreground, args=args, kw=kw)
        return "refined"

    monkeypatch.setattr(refine_mod, "refine_pose", refine_pose)
    points = obs.points[::2]
    assert refined_init_pose("plan", body, obs, points, "depth-cam", 3) == "refined"
    assert got["plan"] == "plan" and got["skeleton"] is body.skeleton and got["camera"] == "depth-cam"
    assert got["foreground"] is obs.player_mask
    np.testing.assert_array_equal(got["pose"].rotations, ik.rotations)
    np.testing.assert_array_equal(got["pose"].translation, ik.translation)
    joints, tracked, pts, others, version = got["args"]
    assert joints is obs.joints and tracked is obs.tracked and pts is points and others is obs.others_depth
    assert version == "v2" and got["kw"] == {"iterations": 3, "posture": None}  # E_trunk at rest (mir12v: None)
    assert len(asked) == 1 and asked[0][0] is body.skeleton and asked[0][1] is obs.joints
    assert asked[0][2] is obs.tracked and asked[0][3] == "v2"
    refined_init_pose("plan", body, obs, points, "depth-cam")
    assert got["kw"] == {"iterations": UNPOSE_REFINE_STEPS, "posture": None}
    posture = np.ones((body.skeleton.n_bones, 3))  # the subject's posture is handed on as it is (mir12v)
    refined_init_pose("plan", body, obs, points, "depth-cam", 2, posture=posture)
    assert got["kw"]["iterations"] == 2 and got["kw"]["posture"] is posture
    v1 = _frame(model, _pose(body.skeleton.n_bones, 1), eye, version="v1")  # the IK reads the frame's joint set
    refined_init_pose("plan", body, v1, v1.points, "depth-cam")
    np.testing.assert_array_equal(got["pose"].translation, ik_pose(body.skeleton, v1.joints, v1.tracked,
                                                                   "v1").translation)
    assert got["args"][-1] == "v1"


def test_transform_to_default_pose_unposes_by_a_given_pose(model):
    """``pose``: the body is posed (and the cloud unposed) by it, not by the IK on the joints; the IK's own pose
    handed in is the default path, bit for bit."""
    body = model.body(np.zeros(model.n_components))
    eye = np.array([0.0, 1.0, 3.0])
    truth = _pose(body.skeleton.n_bones, 2)
    obs = _frame(model, truth, eye)
    kw = dict(view_point=eye, scale_bones=False, details=True)
    by_ik = transform_to_default_pose(obs.points, obs.joints, body, obs.tracked, "v2", **kw)
    ik = ik_pose(body.skeleton, obs.joints, obs.tracked, "v2")
    same = transform_to_default_pose(obs.points, obs.joints, body, obs.tracked, "v2", pose=ik, **kw)
    np.testing.assert_array_equal(same.points, by_ik.points)
    exact = transform_to_default_pose(obs.points, obs.joints, body, obs.tracked, "v2", pose=truth, **kw)
    assert exact.pose is truth
    ok = exact.correspondence >= 0
    assert ok.mean() > 0.9
    # unposed by the true pose, the noise-free cloud lies on the rest surface (the IK's pose is off)
    d_truth = np.linalg.norm(exact.points[ok] - body.vertices[exact.correspondence[ok]], axis=1)
    ok_ik = by_ik.correspondence >= 0
    d_ik = np.linalg.norm(by_ik.points[ok_ik] - body.vertices[by_ik.correspondence[ok_ik]], axis=1)
    assert np.median(d_truth) < 0.5 * np.median(d_ik)


def _wired(monkeypatch, model, passes=3, **kw):
    """initialise_from_observations on two frames (one with player masks), a stand-in plan, refinement and Eq. 2
    fit; the calls recorded."""
    eye = np.array([0.0, 1.0, 3.0])
    n_bones = model.body(np.zeros(model.n_components)).skeleton.n_bones
    obs = [_frame(model, _pose(n_bones, 3), eye, frame=0, mask=True),
           _frame(model, _pose(n_bones, 4), eye, frame=1, mask=False)]
    calls = SimpleNamespace(plan=[], refined=[], tdp=[], fit=[])

    def plan(V, F, W, skeleton, version):
        calls.plan.append(SimpleNamespace(V=V, F=F, W=W, skeleton=skeleton, version=version))
        return f"plan{len(calls.plan)}"

    def refined(plan, body, o, P, camera, steps):
        pose = ik_pose(body.skeleton, o.joints, o.tracked, o.version)
        calls.refined.append(SimpleNamespace(plan=plan, body=body, o=o, P=P, camera=camera, steps=steps, pose=pose))
        return pose

    real_tdp = init_mod.transform_to_default_pose

    def tdp(P, joints, body, tracked, version, **kw):
        calls.tdp.append(SimpleNamespace(P=P, body=body, kw=kw))
        return real_tdp(P, joints, body, tracked, version, **kw)

    def fit(P0, m, coeffs, **kw):
        calls.fit.append(kw)
        return np.full(m.n_components, 0.1 * len(calls.fit)) * m.stddev, 0.004

    monkeypatch.setattr(refine_mod, "refine_plan", plan)
    monkeypatch.setattr(init_mod, "refined_init_pose", refined)
    monkeypatch.setattr(init_mod, "transform_to_default_pose", tdp)
    monkeypatch.setattr(init_mod, "fit_shape", fit)
    kw.setdefault("unpose_posture_bones", ())  # the posture (default since mir12y): test_init_unpose_posture.py
    initialise_from_observations(obs, model, view_point=eye, passes=passes, **kw)
    return obs, calls


def test_passes_after_the_first_unpose_masked_frames_by_the_refined_pose(monkeypatch, model):
    obs, calls = _wired(monkeypatch, model, passes=3, depth_camera="depth-cam", unpose_refine_steps=2,
                        point_sigma_m=0.02)
    assert len(calls.fit) == 3 and len(calls.tdp) == 6
    assert all(f["point_sigma_m"] == 0.02 for f in calls.fit)
    assert [p.version for p in calls.plan] == ["v2", "v2"]  # passes 1 and 2, not the first
    for i, p in enumerate(calls.plan):  # the plan of the shape the previous pass fitted
        c = np.full(model.n_components, 0.1 * (i + 1)) * model.stddev
        np.testing.assert_allclose(p.V, model.vertices(c), atol=1e-12)
        np.testing.assert_array_equal(p.F, model.faces)
        assert p.W is model.weights
        np.testing.assert_allclose(p.skeleton.heads, calls.tdp[2 * (i + 1)].body.skeleton.heads, atol=0)
    assert [(r.plan, r.camera, r.steps) for r in calls.refined] == [("plan1", "depth-cam", 2),
                                                                     ("plan2", "depth-cam", 2)]
    for i, r in enumerate(calls.refined):  # the masked frame only, with its points and the pass's body
        assert r.o is obs[0]
        t = calls.tdp[2 * (i + 1)]
        assert r.body is t.body and r.P is t.P and t.kw["pose"] is r.pose
    assert [t.kw["pose"] is None for t in calls.tdp] == [True, True, False, True, False, True]


@pytest.mark.parametrize("kw", [{"depth_camera": None}, {"depth_camera": "depth-cam", "unpose_refine_steps": 0}])
def test_without_a_depth_camera_or_steps_the_ik_pose_unposes(monkeypatch, model, kw):
    _, calls = _wired(monkeypatch, model, passes=2, **kw)
    assert calls.plan == [] and calls.refined == []
    assert len(calls.tdp) == 4 and all(t.kw["pose"] is None for t in calls.tdp)
    assert all(f["point_sigma_m"] == init_mod.POINT_SIGMA_M for f in calls.fit)


def test_one_refinement_step_pass_by_default(monkeypatch, model):
    _, calls = _wired(monkeypatch, model, passes=2, depth_camera="depth-cam")
    assert [r.steps for r in calls.refined] == [UNPOSE_REFINE_STEPS] and UNPOSE_REFINE_STEPS == 1
