"""A tracked frame whose fitted limbs leave the tracker's joints is re-initialised from them (``limbs_far``, rec15r).

On the stand-ins of test_sequence_tracked_mutants (the run's wiring; the effect on the tiny and 320x240 sessions:
docs/reconstruct.md): the posed fit template's joints follow its translation, and the tracker's WristLeft of frame 16
is planted 0.3 m from where the tracking fit puts it, so that frame's limb joint lies 300 mm from the tracker's while
its torso, silhouettes and energy pass every other check. Each test < 1 s."""

from types import SimpleNamespace as NS

import numpy as np
import pytest

import tests.reconstruct.test_sequence_tracked_mutants as mut
from bodystudio.errors import InputError
from bodystudio.reconstruct.tracking import TrackParams, limbs_far
from tests.reconstruct.test_sequence_tracked_mutants import EXPECTED_TRACK, NAMES, OUTSIDE_PX, SK, _run, _stand_ins

WRIST = NAMES.index("WristLeft")
FAR_FRAME = 16
PLANTED = np.array([0.0, 0.3, 0.0])
TRACKER_JOINTS = mut._joints


def _planted(monkeypatch):
    rec = _stand_ins(monkeypatch)

    def tracker_joints(fid):
        J = TRACKER_JOINTS(fid)
        if fid == FAR_FRAME:
            J = J.copy()
            J[WRIST] += PLANTED
        return J

    def pose_template(body, bone_transforms, global_scale=1.0, version="v2", rest_vertices=None):
        posed = rec.pose_template(body, bone_transforms, global_scale, version, rest_vertices)
        return NS(**{**vars(posed), "joints": SK + (np.asarray(bone_transforms, float) - SK[0])})

    monkeypatch.setattr(mut, "_joints", tracker_joints)
    monkeypatch.setattr(mut.seq, "pose_template", pose_template)
    return rec


def test_the_frame_whose_limb_left_the_joint_is_reinitialised(monkeypatch, tmp_path):
    rec = _planted(monkeypatch)
    summary, frames, meta = _run(rec, tmp_path, track=TrackParams(outside_px=OUTSIDE_PX))
    expected = list(EXPECTED_TRACK)
    expected[mut.FRAMES.index(FAR_FRAME)] = "limbs_far"
    assert [f["track"] for f in frames] == expected
    assert summary["n_tracked"] == 2
    assert meta["track_params"]["limbs_far_mm"] == 80.0
    limb_mm = {f["frame"]: f["track_check"].get("limb_joint_mm") for f in frames}
    # only the tracking fit's pose is compared (the frames the check kept or re-initialised after the fit)
    assert limb_mm[FAR_FRAME] == pytest.approx(300.0, abs=1e-6)
    assert limb_mm[11] == pytest.approx(0.0, abs=1e-6) and limb_mm[17] == pytest.approx(20.0, abs=1e-6)
    assert limb_mm[15] == pytest.approx(100.0, abs=1e-6)  # the energy jump's fit, checked first
    assert all(limb_mm[f] is None for f in (10, 12, 13, 14))
    # re-initialised from the frame's joints: its deformation starts at their pose, the next frame tracks from it
    k = mut.FRAMES.index(FAR_FRAME)
    deform = rec.calls["deform"][k]
    np.testing.assert_allclose(deform["V"], mut.BODIES["6k"].vertices * (1.0 + 0.5 * mut.JOINT_X[FAR_FRAME])
                               + mut._joints(FAR_FRAME)[0], atol=1e-12)
    np.testing.assert_allclose(rec.calls["track"][-1][1], SK[0] + [mut.JOINT_X[FAR_FRAME], 0.0, 0.0], atol=1e-12)


def test_off_or_within_the_distance_the_frame_stays_tracked(monkeypatch, tmp_path):
    for far_mm in (0.0, 301.0):
        rec = _planted(monkeypatch)
        _summary, frames, meta = _run(rec, tmp_path, track=TrackParams(outside_px=OUTSIDE_PX, limbs_far_mm=far_mm))
        assert [f["track"] for f in frames] == EXPECTED_TRACK
        assert meta["track_params"]["limbs_far_mm"] == far_mm
    rec = _planted(monkeypatch)
    _summary, frames, _meta = _run(rec, tmp_path, track=TrackParams(outside_px=OUTSIDE_PX, limbs_far_mm=299.0))
    assert frames[mut.FRAMES.index(FAR_FRAME)]["track"] == "limbs_far"


def test_the_rule_and_its_range():
    p = TrackParams()
    assert p.limbs_far_mm == 80.0
    assert limbs_far(80.001, p) and not limbs_far(80.0, p) and not limbs_far(None, p)
    assert not limbs_far(1e6, TrackParams(limbs_far_mm=0.0))
    for bad in (-1.0, np.nan, np.inf, 1e5):
        with pytest.raises(InputError, match=r"^tracking limbs_far_mm \S+ is out of range; use a value in \[0, "):
            TrackParams(limbs_far_mm=bad)
