"""reconstruct_session's ``smoothing_guard`` (issue 15's default): the time-smoothed joints of ``joint_smoothing``
are used for a frame only when the template they pose leaves at most ``1 + g`` times as much of itself outside the
silhouettes as the frame's own joints' pose; at a low frame rate (the benchmark's main session: six frames over one
walk cycle) the line through five frames is not the motion (frame 3: 213 mm Hausdorff)."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import bodystudio.reconstruct.sequence as sequence
from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def session_3(small_synth_session, tmp_path_factory):
    """A copy of the suite's shared small session (4 cameras, 3 frames, 320x240, Kinect v1)."""
    import shutil

    return shutil.copytree(small_synth_session, tmp_path_factory.mktemp("sgd") / "session")


@pytest.mark.parametrize(("e_smooth", "kept"), [(0.0104, "smoothed"), (0.0108, "raw"), (0.05, "raw")])
def test_guard_keeps_the_smoothed_joints_only_where_the_silhouettes_agree(monkeypatch, session_3, e_smooth, kept):
    real_run_joints = sequence.run_joints

    def run_joints(session, selected, joints, joints_path, smoothing=0, subject=None):
        return real_run_joints(session, selected, joints, joints_path, 0, subject) + np.array([0.5, 0.0, 0.0])

    starts = []

    def deform(V_start, F, cameras, masks, params, **kw):
        starts.append(np.asarray(V_start).mean(axis=0))
        return SimpleNamespace(vertices=np.asarray(V_start), solver_s=0.0, matching_s=0.0, n_silhouette=[0],
                               n_depth=[0])

    def outside(V, fields, outside_px=2.0):
        return e_smooth if np.asarray(V)[:, 0].mean() > 0.3 else 0.01

    monkeypatch.setattr(sequence, "run_joints", run_joints)
    monkeypatch.setattr(sequence, "refine_bone_transforms", lambda body, T, *a, **k: T)
    monkeypatch.setattr(sequence, "deform_to_observations", deform)
    monkeypatch.setattr(sequence, "outside_fraction", outside)
    sequence.reconstruct_session(session_3, template="2k", score=False, joint_smoothing=2, smoothing_guard=0.05,
                                 bone_lengths="frame", accept_implausible=True)
    frames = json.loads((Path(session_3) / "reconstruct" / "frames.json").read_text())["frames"]
    assert [f["smoothing_outside"] for f in frames] == [[0.01, e_smooth]] * 3
    assert [bool(s[0] > 0.3) for s in starts] == [kept == "smoothed"] * 3
    run = json.loads((Path(session_3) / "reconstruct" / "run.json").read_text())
    assert run["smoothing_guard"] == 0.05


def test_no_guard_no_check(monkeypatch, session_3):
    calls = []
    monkeypatch.setattr(sequence, "outside_fraction", lambda *a, **k: calls.append(1) or 0.0)
    monkeypatch.setattr(sequence, "refine_bone_transforms", lambda body, T, *a, **k: T)
    sequence.reconstruct_session(session_3, template="2k", score=False, joint_smoothing=2, accept_implausible=True,
                                 params=sequence.RapidSkinParams(outer_iterations=1, inner_iterations=1))
    frames = json.loads((Path(session_3) / "reconstruct" / "frames.json").read_text())["frames"]
    assert calls == [] and all("smoothing_outside" not in f for f in frames)


@pytest.mark.parametrize("name", ["smoothing_guard", "refine_depth_guard"])
@pytest.mark.parametrize("bad", [-0.1, float("nan"), 11.0])
def test_bad_guard_is_a_one_line_error(session_3, name, bad):
    with pytest.raises(InputError, match=name):
        sequence.reconstruct_session(session_3, template="2k", **{name: bad})
