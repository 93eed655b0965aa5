"""Rapid Skin as a tracker: the previous frame's pose as the prior, and the lost-track check."""

import json

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import (
    SilhouetteFields,
    TrackParams,
    energy_jumped,
    lost_track_reason,
    outside_fraction,
)

JUMP_FRAME = 5


@pytest.fixture(scope="module")
def jump_session(tmp_path_factory):
    """A 20 fps walk (4 cameras, 320x240, 2.5K subject) in which the person jumps 0.5 m sideways at frame 5."""
    import bodystudio.capture.motion as motion
    from bodystudio.body.pose import Pose
    from bodystudio.capture.synth import synth_session

    original = motion.motion_sequence

    def jumping(*args, **kwargs):
        poses = original(*args, **kwargs)
        return [p if k < JUMP_FRAME else Pose(p.rotations, p.translation + [0.5, 0.0, 0.0])
                for k, p in enumerate(poses)]

    mp = pytest.MonkeyPatch()
    mp.setattr(motion, "motion_sequence", jumping)
    try:
        return synth_session(tmp_path_factory.mktemp("track") / "jump", n_cameras=4, n_frames=7, motion="walk",
                             subject_seed=23, resolution=(320, 240), template="2k", fps=20.0)
    finally:
        mp.undo()


def _run(session, **kwargs):
    from bodystudio.reconstruct.sequence import reconstruct_session

    summary = reconstruct_session(session.path, template="2k", **kwargs)
    frames = json.loads((session.path / "reconstruct" / "frames.json").read_text())["frames"]
    return summary, frames


@pytest.fixture(scope="module")
def runs(jump_session):
    tracked = _run(jump_session, tracking=True)
    per_frame = _run(jump_session)
    return tracked, per_frame


def _medians(frames):
    return np.array([f["metrics"]["visible_median_mm"] for f in frames])


def _p90s(frames):
    return np.array([f["metrics"]["visible_p90_mm"] for f in frames])


def test_tracking_record_and_lost_track(runs):
    (_, frames), (_, per_frame) = runs
    track = [f["track"] for f in frames]
    # tracked from the previous frame except the first frame and the jump, where the check re-initialises
    assert track[0] == "first"
    assert track[JUMP_FRAME] in ("joint_jump", "silhouette")
    assert [t for k, t in enumerate(track) if k not in (0, JUMP_FRAME)] == ["tracked"] * 5
    assert all(f["track"] == "per_frame" for f in per_frame)
    # the tracked frames skip the hull and its articulated fit; the re-initialised ones run it
    assert all(f["refine_ms"] == 0 for f in frames if f["track"] == "tracked")
    assert frames[0]["refine_ms"] > 0 and frames[JUMP_FRAME]["refine_ms"] > 0
    # a tracked frame runs the fast path (TrackParams.outer_iterations re-matchings); a re-initialised one
    # TrackParams.initial_outer_iterations of the run's No (rec15m; 3)
    no, no_tracked = RapidSkinParams().outer_iterations, TrackParams().outer_iterations
    no_first = min(no, TrackParams().initial_outer_iterations)
    assert 0 < no_tracked < no and 0 < no_first < no
    assert [len(f["n_silhouette"]) for f in frames] == [no_first if f["track"] != "tracked" else no_tracked
                                                        for f in frames]
    # before the jump the previous pose lies inside the silhouettes; after it, mostly outside
    assert frames[1]["track_check"]["prior_outside"] < 0.05
    assert frames[JUMP_FRAME]["track_check"]["prior_outside"] > 0.5
    assert frames[JUMP_FRAME]["track_check"]["joint_jump_m"] > 0.4


def test_tracking_reaches_the_per_frame_accuracy(runs):
    (tracked, frames), (per_frame, pf_frames) = runs
    m_track, m_pf = _medians(frames), _medians(pf_frames)
    p90_track, p90_pf = _p90s(frames), _p90s(pf_frames)
    # Measured (4 cameras 320x240, 2.5K template, visible surface): per-frame initialisation medians
    # 3.33-4.20 mm, p90 12.2-16.7 mm; tracker 3.38-4.16 / 12.0-16.7 mm, the frame after the jump 3.74 / 14.6.
    # A tracker that never updates the pose (the previous frame's transforms kept) reaches 4.60 / 21.0 mm by
    # its 3rd frame, 6.17 / 29.8 by its 4th and 4.55 / 18.8 after the jump: the same bound for both paths
    # fails it.
    for medians, p90s in ((m_pf, p90_pf), (m_track, p90_track)):
        assert np.all(medians < 4.4), medians
        assert np.all(p90s < 18.0), p90s
    assert m_track.mean() < m_pf.mean() + 0.3, (m_track, m_pf)
    assert tracked["n_tracked"] == 5 and per_frame["n_tracked"] == 0


def test_silhouette_check_alone_catches_the_jump(jump_session):
    """Without the joints' jump test, the prior pose's silhouette check still re-initialises at the jump."""
    _, frames = _run(jump_session, tracking=True, track_params=TrackParams(joint_jump_m=10.0),
                     frames=f"{JUMP_FRAME - 1}:")
    assert [f["track"] for f in frames] == ["first", "silhouette", "tracked"]
    assert np.all(_medians(frames) < 4.4) and np.all(_p90s(frames) < 18.0)


def test_outside_fraction_and_rules(synthetic_capture):
    cap = synthetic_capture
    fields = SilhouetteFields(cap["rig"], cap["masks"])
    assert outside_fraction(cap["V"], fields) < 0.01
    assert outside_fraction(cap["V"] + [0.5, 0, 0], fields) > 0.9
    p = TrackParams()
    assert lost_track_reason(True, 0.0, 0.0, p) == "first"
    assert lost_track_reason(False, 0.3, 0.0, p) == "joint_jump"
    assert lost_track_reason(False, 0.0, 0.3, p) == "silhouette"
    assert lost_track_reason(False, 0.01, 0.01, p) is None
    assert energy_jumped(0.4, 0.1, p) and not energy_jumped(0.4, 0.3, p) and not energy_jumped(0.1, 0.01, p)
    with pytest.raises(InputError, match="joint_jump_m"):
        TrackParams(joint_jump_m=-1.0)
    with pytest.raises(InputError, match="no mask"):
        SilhouetteFields(cap["rig"], {})


def test_cli_tracking(jump_session, capsys):
    from bodystudio.cli.main import main

    path = str(jump_session.path)
    assert main(["reconstruct", path, "--template", "2k", "--frames", "0:2", "--outer", "2", "--no-score"]) == 0
    run = json.loads((jump_session.path / "reconstruct" / "run.json").read_text())
    frames = json.loads((jump_session.path / "reconstruct" / "frames.json").read_text())["frames"]
    assert run["tracking"] is False and [f["track"] for f in frames] == ["per_frame", "per_frame"]
    assert run["refine_with"] == "fields" and run["rest_cotangents"] is True
    assert main(["reconstruct", path, "--template", "2k", "--frames", "0:2", "--outer", "2", "--no-score",
                 "--tracking"]) == 0
    run = json.loads((jump_session.path / "reconstruct" / "run.json").read_text())
    frames = json.loads((jump_session.path / "reconstruct" / "frames.json").read_text())["frames"]
    assert run["tracking"] is True and [f["track"] for f in frames] == ["first", "tracked"]
    for key in ("read_ms", "init_ms", "fields_ms", "refine_ms", "track_ms", "matching_ms", "solver_ms", "other_ms",
                "frame_ms"):
        assert frames[1][key] >= 0.0, key


def test_fields_refinement_corrects_a_perturbed_tracker_pose(body_2k, synthetic_capture):
    """The pose refinement on the silhouettes' distance fields (the implicit hull, no carving) brings a
    perturbed tracker pose back as the carved hull's fit does (tests/reconstruct/test_pose_refine.py)."""
    from test_pose_refine import _limb_error_mm, _perturbed

    from bodystudio.reconstruct.articulated_fit import refine_bone_transforms
    from bodystudio.reconstruct.evaluate import point_to_surface_mm
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
    from bodystudio.reconstruct.tracking import silhouette_data_term

    cap = synthetic_capture
    fields = SilhouetteFields(cap["rig"], cap["masks"])
    init = initialise_pose(body_2k, _perturbed(cap["joints"]))
    term = silhouette_data_term(fields, TrackParams())
    T = refine_bone_transforms(body_2k, init.bone_transforms, None, data_term=term)
    refined = pose_template(body_2k, T, init.global_scale)
    d_init = point_to_surface_mm(init.vertices, cap["V"], cap["F"])
    d_refined = point_to_surface_mm(refined.vertices, cap["V"], cap["F"])
    # Measured (4 cameras, 2.5K template): limb joints 51.8 -> 11.7 mm, surface median 12.0 -> 3.1 mm, p90
    # 67.3 -> 10.8 mm (the carved hull's fit: 10.8 mm, 3.2 / 10.9 mm); 3 iterations instead of 10 leave
    # 12.0 mm, 3.7 / 11.3 mm, so the bounds hold the converged figures.
    assert _limb_error_mm(refined.joints, cap["joints"]) < 15.0 < 0.5 * _limb_error_mm(init.joints, cap["joints"])
    assert np.percentile(d_refined, 90) < 11.2 < 0.5 * np.percentile(d_init, 90)
    assert np.median(d_refined) < 3.5 < 0.5 * np.median(d_init)
    assert outside_fraction(refined.vertices, fields) < 0.01 < outside_fraction(init.vertices, fields)


def _implicit_hull_reference(fields, V):
    """Plain numpy ``max_c d_c z_c / f_c`` and its gradient, camera by camera (Camera.project, bilinear
    sampling of each field), against which the compiled pass is checked."""
    best, G = np.full(len(V), -np.inf), np.zeros((len(V), 3))
    for cam in fields.cameras:
        S, (x0, y0) = fields.sdf[cam.name], fields.offset[cam.name]
        Pc = cam.world_to_camera(V)
        z = Pc[:, 2]
        uv = cam.project(V)
        for i in range(len(V)):
            u, v = uv[i]
            if not (z[i] > 1e-6 and 0 <= u <= cam.width - 1 and 0 <= v <= cam.height - 1):
                continue
            uu, vv = u - x0, v - y0
            d, g = fields.margin_px, np.zeros(2)
            if 0 <= uu < S.shape[1] - 1 and 0 <= vv < S.shape[0] - 1:
                xi, yi = int(uu), int(vv)
                ax, ay = uu - xi, vv - yi
                s = S[yi:yi + 2, xi:xi + 2].astype(np.float64)
                d = (1 - ay) * ((1 - ax) * s[0, 0] + ax * s[0, 1]) + ay * ((1 - ax) * s[1, 0] + ax * s[1, 1])
                g = np.array([(1 - ay) * (s[0, 1] - s[0, 0]) + ay * (s[1, 1] - s[1, 0]),
                              (1 - ax) * (s[1, 0] - s[0, 0]) + ax * (s[1, 1] - s[0, 1])])
            f = 0.5 * (cam.fx + cam.fy)
            if d * z[i] / f > best[i]:
                best[i] = d * z[i] / f
                x, y = Pc[i, 0], Pc[i, 1]
                J = np.array([[cam.fx / z[i], 0, -cam.fx * x / z[i] ** 2], [0, cam.fy / z[i], -cam.fy * y / z[i] ** 2]])
                G[i] = (g @ J) * z[i] / f @ cam.R
    return best, G


def test_compiled_implicit_hull_equals_the_numpy_reference(synthetic_capture):
    from dataclasses import replace

    cap = synthetic_capture
    rng = np.random.default_rng(3)
    # lens distortion on two views, and points inside, outside, beyond the fields' margin and off-image
    rig = [replace(c, dist=np.array([-0.2, 0.05, 1e-3, -1e-3, 0.01])) if k % 2 else c
           for k, c in enumerate(cap["rig"])]
    fields = SilhouetteFields(rig, cap["masks"])
    V = np.concatenate([cap["V"][::7] + rng.normal(0, 0.03, (len(cap["V"][::7]), 3)),
                        rng.uniform([-2, -0.5, -2], [2, 2.5, 2], (300, 3))])
    best, G = fields.implicit_hull(V)
    ref_best, ref_G = _implicit_hull_reference(fields, V)
    assert np.array_equal(np.isfinite(best), np.isfinite(ref_best))
    ok = np.isfinite(best)
    assert ok.sum() > 0.8 * len(V) and (best[ok] < 0).sum() > 100 and (best[ok] > 0.05).sum() > 50
    assert np.allclose(best[ok], ref_best[ok], atol=1e-9)
    assert np.allclose(G, ref_G, atol=1e-9)
    # the field's gradient points outwards: a step along it raises the distance by about its length
    i = np.flatnonzero(ok & (np.abs(best) < 0.02) & (np.linalg.norm(G, axis=1) > 0.5))
    step = 1e-3 * G[i] / np.linalg.norm(G[i], axis=1, keepdims=True)
    gain = fields.implicit_hull(V[i] + step)[0] - best[i]
    assert np.median(gain / (1e-3 * np.linalg.norm(G[i], axis=1))) > 0.8
