"""Mutation survivors of mir12v's posture lines (docs/mutation/mirror-init.md, "mir12v's posture lines"): what
``refined_init_pose`` hands the refinement (the frame's own joints, flags, points, others' pixels, version, steps and
the posture), the depth points the initialisation hands ``refined_init_pose`` (each frame's own, with or without a
posture) and the refusal's list of the posture bones. Stand-ins for the IK and the refinement (fast)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import InitObservation, initialise_from_observations, refined_init_pose
from tests.mirror.test_init_pass_settle import frames  # noqa: F401  (the module fixture: 2k model, two frames)


class _Body:
    skeleton = "skeleton"


def test_refined_init_pose_hands_the_refinement_the_frames_own_inputs(monkeypatch):
    from bodystudio.mirror import refine as refine_mod

    J = 25
    obs = InitObservation(7, np.full((5, 3), 2.0), np.arange(3 * J, dtype=float).reshape(J, 3),
                          np.arange(J) % 2 == 0, "v2", player_mask=np.eye(4, dtype=bool),
                          others_depth=np.ones((4, 4), bool))
    points = np.full((9, 3), 3.0)
    posture = np.full((3, 3), 0.5)
    seen = {}

    def refine(*args, **kw):
        seen["args"], seen["kw"] = args, kw
        return "refined"

    monkeypatch.setattr(init_mod, "ik_pose", lambda sk, j, t, v: ("ik", sk, j is obs.joints, t is obs.tracked, v))
    monkeypatch.setattr(refine_mod, "refine_pose", refine)
    assert refined_init_pose("plan", _Body(), obs, points, "cam", 5, posture=posture) == "refined"
    a = seen["args"]
    assert a[0] == "plan" and a[1] == "skeleton" and a[2] == ("ik", "skeleton", True, True, "v2") and a[3] == "cam"
    assert a[4] is obs.player_mask and a[5] is obs.joints and a[6] is obs.tracked and a[7] is points
    assert a[8] is obs.others_depth and a[9] == "v2"
    assert seen["kw"]["iterations"] == 5 and seen["kw"]["posture"] is posture
    refined_init_pose("plan", _Body(), obs, points, "cam")
    assert seen["kw"]["iterations"] == init_mod.UNPOSE_REFINE_STEPS and seen["kw"]["posture"] is None


@pytest.mark.parametrize("bones", [("spine_02",), ()])
def test_the_init_hands_each_frame_its_own_points(monkeypatch, frames, bones):  # noqa: F811
    """Three passes on the two frames, with and without a posture: every call of ``refined_init_pose`` gets its
    frame's depth points (the frames' clouds are under MAX_POINTS, so unchanged)."""
    from bodystudio.mirror import refine as refine_mod
    from bodystudio.mirror.track import ik_pose

    model, eye, obs = frames
    calls = []

    def refined(plan, body, o, P, camera, steps, **kw):
        calls.append((o, P))
        return ik_pose(body.skeleton, o.joints, o.tracked, o.version)

    monkeypatch.setattr(refine_mod, "refine_plan", lambda *args: "plan")
    monkeypatch.setattr(init_mod, "refined_init_pose", refined)
    monkeypatch.setattr(init_mod, "fit_shape", lambda P0, m, c, **kw: (np.zeros(m.n_components), 0.004))
    initialise_from_observations(obs, model, view_point=eye, passes=3, depth_camera="cam", floor_y=None,
                                 unpose_posture_bones=bones)
    assert len(calls) == 4
    for o, P in calls:
        np.testing.assert_array_equal(P, o.points)


def test_the_refusal_lists_the_posture_bones(frames):  # noqa: F811
    with pytest.raises(InputError, match=r"use trunk bones such as spine_02, neck_01, head$"):
        initialise_from_observations([], frames[0], unpose_posture_bones=("spine_9",))
