"""The neck posed from the tracked Neck joint (issue 15's worst regions, rec15l): Eq. 11 places the neck bone by the
spine's transform, so on a subject whose SpineShoulder -> Neck span differs from the template's the neck's base lands
centimetres from the Neck joint; :func:`neck_at_joint` moves it there and keeps the head; the tracked run poses the
deformed template with it and keeps the tracker's own pose. 2.5K templates and subjects, < 2 s."""

from types import SimpleNamespace as NS

import numpy as np
import pytest

from bodystudio.body import build_body
from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.body.population import sample_subject
from bodystudio.reconstruct.evaluate import point_to_surface_mm
from bodystudio.reconstruct.pose_init import initialise_pose, neck_at_joint, pose_template

NECK = kinect_joint_names("v2").index("Neck")


@pytest.fixture(scope="module")
def template():
    return build_body(resolution="2k")


def _dominant(body, bone):
    return np.argmax(body.weights, axis=1) == body.skeleton.index(bone)


@pytest.mark.parametrize("seed", [58, 3])
def test_the_subjects_neck_from_its_true_joints(template, seed):
    """A hidden subject (the benchmark's walk 58, turn 3) at rest, the template posed to its exact Kinect joints: the
    neck's base lands 62-74 mm from the subject's; placed on the Neck joint, the template's neck vertices come 2-3x
    closer to the subject's surface and the head's vertices (none of the neck's weight) do not move."""
    phenotype, local = sample_subject(seed)
    subject = build_body(phenotype, local, resolution="2k")
    sk = subject.skeleton
    J = kinect_joints(sk, sk.heads, sk.tails, "v2")
    init = initialise_pose(template, J)
    placed = neck_at_joint(template, init.bone_transforms, J[NECK])
    posed = pose_template(template, placed, init.global_scale)
    neck = _dominant(template, "neck_01")
    head = _dominant(template, "head") & (template.weights[:, template.skeleton.index("neck_01")] == 0)
    before = np.percentile(point_to_surface_mm(init.vertices[neck], subject.vertices, subject.faces), 90)
    after = np.percentile(point_to_surface_mm(posed.vertices[neck], subject.vertices, subject.faces), 90)
    assert 1000 * np.linalg.norm(init.joints[NECK] - J[NECK]) > 25.0  # measured 74 / 62 mm (seeds 58 / 3)
    assert np.linalg.norm(posed.joints[NECK] - J[NECK]) < 1e-9
    assert after < 0.6 * before  # measured 45.1 -> 18.1 and 39.1 -> 17.7 mm
    np.testing.assert_array_equal(posed.vertices[head], init.vertices[head])


def test_only_the_neck_bone_moves_its_base_on_the_joint_and_its_end_kept(template):
    rng = np.random.default_rng(5)
    J = kinect_joints(template.skeleton, template.skeleton.heads, template.skeleton.tails, "v2")
    T = initialise_pose(template, J + rng.normal(0.0, 0.02, J.shape)).bone_transforms
    target = J[NECK] + [0.01, 0.04, -0.03]
    out = neck_at_joint(template, T, target)
    b = template.skeleton.index("neck_01")
    other = np.arange(len(T)) != b
    np.testing.assert_array_equal(out[other], T[other])  # the head, the spine, everything else
    head0, tail0 = template.skeleton.heads[b], template.skeleton.tails[b]
    np.testing.assert_allclose(out[b, :3, :3] @ head0 + out[b, :3, 3], target, atol=1e-12)
    np.testing.assert_allclose(out[b, :3, :3] @ tail0 + out[b, :3, 3], T[b, :3, :3] @ tail0 + T[b, :3, 3], atol=1e-12)
    assert out is not T and not np.shares_memory(out, T)
    # an untracked Neck joint, or a template without the bone: the transforms as they are
    assert neck_at_joint(template, T, np.full(3, np.nan)) is T
    assert neck_at_joint(NS(skeleton=NS(bone_names=("root",))), T, target) is T


# --- reconstruct_frames' wiring: the deformed template's neck placed, the tracker's pose kept --------------------

def test_the_tracked_run_poses_the_deformation_with_the_neck_and_tracks_its_own_pose(monkeypatch, tmp_path):
    """Stand-ins of test_sequence_tracked_mutants (a translated tetrahedron): every frame's deformation starts from the
    template posed by the placed transforms (here the fit's + a known shift) and the next frame's tracking fit starts
    from the fit's own, unshifted; off, nothing is placed."""
    from dataclasses import replace

    import bodystudio.reconstruct.sequence as seq
    from bodystudio.reconstruct.tracking import TrackParams
    from tests.reconstruct.test_sequence_tracked_mutants import (
        BODIES,
        EXPECTED_TRACK,
        FIT_BIAS,
        FRAMES,
        JOINT_X,
        OUTSIDE_PX,
        _joints,
        _run,
        _stand_ins,
        _truth,
    )

    rec = _stand_ins(monkeypatch)
    shift = np.array([0.0, 0.0, 0.25])
    calls = []

    def place(body, T, neck, unstretch_head=False):
        calls.append((body, np.array(T), np.array(neck), unstretch_head))
        return np.asarray(T) + shift

    monkeypatch.setattr(seq, "neck_at_joint", place)
    track = TrackParams(outside_px=OUTSIDE_PX)
    assert track.neck_joint is True
    _run(rec, tmp_path, track=track)
    deform, fits = rec.calls["deform"], rec.calls["track"]
    assert len(calls) == len(FRAMES)  # every frame, tracked or (re-)initialised
    body, scale, fitted = BODIES["6k"], None, {}
    for k, (fid, t) in enumerate(zip(FRAMES, EXPECTED_TRACK, strict=True)):
        fit = _truth(fid) + [FIT_BIAS.get(fid, 0.0), 0, 0] if t == "tracked" else _joints(fid)[0]
        scale = scale if t == "tracked" else 1.0 + 0.5 * JOINT_X[fid]
        assert calls[k][0] is body
        np.testing.assert_allclose(calls[k][1], fit, atol=1e-12)
        np.testing.assert_allclose(calls[k][2], _joints(fid)[NECK], atol=1e-12)  # this frame's Neck joint
        assert calls[k][3] is True  # the head unstretched (rec15m's TrackParams.unstretch_head, on by default)
        np.testing.assert_allclose(deform[k]["V"], body.vertices * scale + fit + shift, atol=1e-12)
        fitted[fid] = fit
    assert [f[2] for f in fits] == [11, 15, 16, 17]  # the tracking fits (15: an energy jump, re-initialised)
    for _body, previous, fid, *_rest in fits:  # each from the previous frame's fit, not shifted
        np.testing.assert_allclose(previous, fitted[FRAMES[FRAMES.index(fid) - 1]], atol=1e-12)
    # off: nothing placed, the deformation starts from the fit's pose
    rec = _stand_ins(monkeypatch)
    calls.clear()
    monkeypatch.setattr(seq, "neck_at_joint", place)
    _run(rec, tmp_path / "off", track=replace(track, neck_joint=False))
    assert calls == []
    np.testing.assert_allclose(rec.calls["deform"][0]["V"], body.vertices * 1.0 + _joints(FRAMES[0])[0], atol=1e-12)
    # the head's stretch kept: the placement is asked without the unstretching
    rec = _stand_ins(monkeypatch)
    monkeypatch.setattr(seq, "neck_at_joint", place)
    _run(rec, tmp_path / "stretched", track=replace(track, unstretch_head=False))
    assert len(calls) == len(FRAMES) and all(c[3] is False for c in calls)
