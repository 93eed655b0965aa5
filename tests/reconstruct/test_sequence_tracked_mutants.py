"""The tracked path of :func:`bodystudio.reconstruct.sequence.reconstruct_frames` on stand-ins (issue 17).

The per-frame loop's tracking branch (lost-track check, tracking fit, energy check, re-initialisation), the warm
mesh and the tracked frame's outer count, the warm start's running rest shape and the joint smoothing, with every
heavy step (template, posing, fits, deformation, self-check, file writing) replaced by a stand-in whose result is
known in closed form: a tetrahedron "template" posed by a translation ``T`` and a scale, a silhouette energy that is
the posed centroid's distance to the frame's true position, a clock that ticks 1 s per read. So each frame's track
reason, check figures, start mesh, solver settings and timings are exact numbers. Each test < 1 s.
"""
from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.body
import bodystudio.reconstruct.sequence as seq
from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError
from bodystudio.reconstruct.articulated_fit import REFINE_BONES, REFINE_BONES_WITH_HEAD, PoseRefineParams
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams

NAMES = kinect_joint_names("v2")
FRAMES = [10, 11, 12, 13, 14, 15, 16, 17]
#: the silhouettes' true motion along x (m) and the tracker's (frame 13: a 0.5 m glitch)
TRUE_X = dict(zip(FRAMES, [0.0, 0.02, 0.12, 0.14, 0.16, 0.18, 0.20, 0.22], strict=True))
JOINT_X = dict(zip(FRAMES, [0.0, 0.02, 0.12, 0.64, 0.16, 0.18, 0.20, 0.22], strict=True))
#: where the tracking fit lands off the truth (frame 15: 0.1 m, an energy jump; frame 17: 0.02 m, just within)
FIT_BIAS = {15: 0.1, 17: 0.02}
OUTSIDE_PX = 2.5
TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
SK = np.random.default_rng(7).uniform(-0.3, 0.3, (25, 3)) + [0.0, 1.0, 0.0]


def _body(scale):
    return NS(vertices=TET * scale, faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
              weights=np.ones((4, 1)))


BODIES = {"2k": _body(0.5), "6k": _body(0.8)}


def _joints(fid):
    return SK + [JOINT_X[fid], 0.0, 0.0]


def _truth(fid):
    """The frame's true bone transform (a translation): the tracker's root without its glitch."""
    return SK[0] + [TRUE_X[fid], 0.0, 0.0]


class Clock:
    """``time.perf_counter`` ticking 1 s per read."""

    def __init__(self):
        self.t = 0.0

    def perf_counter(self):
        self.t += 1.0
        return self.t


class Fields:
    def __init__(self, cameras, masks):
        self.cameras, self.masks = cameras, masks
        self.fid = int(masks["c0"][0, 0])


class Rec:
    """The stand-ins and what they were called with."""

    def __init__(self):
        self.calls = {k: [] for k in ("init", "pose", "track", "refine", "deform", "smooth", "seq_lengths",
                                      "with_lengths", "hull_fit", "unpose", "build", "fields")}
        self.committed = None
        self.frames_json = None

    # posing: a translation T and a scale of the template's (or the given rest) vertices
    def initialise_pose(self, body, joints, version="v2", rest_vertices=None):
        J = np.asarray(joints, float)
        T = J[0].copy()
        scale = 1.0 + 0.5 * (J[0, 0] - SK[0, 0])
        rest = body.vertices if rest_vertices is None else rest_vertices
        self.calls["init"].append((body, J.copy(), rest))
        return NS(bone_transforms=T, global_scale=scale, vertices=rest * scale + T, joints=J)

    def pose_template(self, body, bone_transforms, global_scale=1.0, version="v2", rest_vertices=None):
        rest = body.vertices if rest_vertices is None else rest_vertices
        T = np.asarray(bone_transforms, float)
        self.calls["pose"].append((body, T.copy(), global_scale, rest_vertices))
        return NS(bone_transforms=T, global_scale=global_scale, vertices=rest * global_scale + T, joints=None)

    def outside_fraction(self, V, fields, outside_px=2.0):
        """0.1 + the posed fit body's centroid's distance to the frame's truth over 0.1 px-metres, at most 1."""
        target = BODIES["2k"].vertices.mean(0) + _truth(fields.fid)
        return min(1.0, 0.1 + float(np.linalg.norm(np.mean(V, 0) - target)) / (0.1 * outside_px))

    def track_bone_transforms(self, body, previous, fields, params=None, joint_transforms=None):
        self.calls["track"].append((body, np.array(previous), fields.fid, params,
                                    None if joint_transforms is None else np.array(joint_transforms)))
        return _truth(fields.fid) + [FIT_BIAS.get(fields.fid, 0.0), 0.0, 0.0]

    def refine_bone_transforms(self, body, T, hull, params=None, data_term=None, anchors=None):
        assert body is BODIES["2k"]  # the refinement's 2.5K template
        self.calls["refine"].append((body, np.array(T), hull, params, data_term))
        return np.asarray(T) + [0.0, 0.005, 0.0]

    def deform_to_observations(self, V, F, cameras, masks, params, depth=None, delta=None, smooth_reference=None,
                               fields=None):
        k = len(self.calls["deform"])
        self.calls["deform"].append(dict(V=np.array(V), params=params, masks=masks, delta=delta,
                                         reference=np.array(smooth_reference), fields=fields))
        return NS(vertices=np.asarray(V) + [0.0, 0.0, 0.001 * (k + 1)], solver_s=0.25, matching_s=0.125,
                  n_silhouette=7, n_depth=0)

    def unpose(self, V, weights, T):
        assert weights is BODIES["6k"].weights
        self.calls["unpose"].append(np.array(T))
        return np.asarray(V) - T

    def smooth_joint_track(self, frames, joint_frames, half_window, break_m=0.25):
        self.calls["smooth"].append((np.array(frames), np.array(joint_frames), half_window))
        return np.asarray(joint_frames) + [0.0, 0.0, 0.01 * half_window]

    def sequence_bone_lengths(self, joint_frames, version="v2"):
        self.calls["seq_lengths"].append(np.array(joint_frames))
        return np.full(25, 0.3)

    def with_bone_lengths(self, joints, lengths, version="v2"):
        self.calls["with_lengths"].append((np.array(joints), np.array(lengths)))
        return np.asarray(joints) + [0.0, 0.002, 0.0]

    def build_body(self, resolution="13k"):
        self.calls["build"].append(resolution)
        return BODIES[resolution]

    def fields(self, cameras, masks):
        assert [c.name for c in cameras] == ["c0"]
        self.calls["fields"].append(int(masks["c0"][0, 0]))
        return Fields(cameras, masks)

    def fit_body_to_hull(self, body, hull, previous_pose=None):
        assert body is BODIES["2k"]
        self.calls["hull_fit"].append((body, hull, previous_pose))
        return NS(joints=_joints(hull), pose=("pose", hull))


class Writer:
    def __init__(self, root: Path):
        self.layout = NS(root=root)
        (root / "meshes").mkdir(parents=True, exist_ok=True)
        self.saved = {}
        self.json = {}
        self.meta = None

    def path_for(self, rel):
        return self.layout.root / rel

    def write_json(self, name, obj):
        self.json[name] = obj

    def commit(self, meta, deletes=()):
        self.meta = meta


def _session(depth=False):
    def frame(fid):
        return NS(frame_id=fid, masks={"c0": np.full((2, 2), fid, np.uint8)},
                  kinect_joints={"names": list(NAMES), "positions": _joints(fid).tolist(), "tracked": [True] * 25},
                  kinect_depth_m=np.full((2, 2), 2.0) if depth else None, gt_mesh=None)

    return NS(path=Path("/stand-in/session"), streams={"mask"}, frame=frame)


def _stand_ins(monkeypatch):
    """Every heavy step of the run replaced (a fresh record per test: the direct mutant recheck calls the tests
    without pytest's fixtures)."""
    r = Rec()
    for name in ("initialise_pose", "pose_template", "outside_fraction", "track_bone_transforms",
                 "refine_bone_transforms", "deform_to_observations", "unpose", "smooth_joint_track",
                 "sequence_bone_lengths", "with_bone_lengths", "fit_body_to_hull"):
        monkeypatch.setattr(seq, name, getattr(r, name))
    monkeypatch.setattr(seq, "SilhouetteFields", r.fields)
    monkeypatch.setattr(seq, "silhouette_data_term", lambda fields, params: ("data", fields.fid, params))
    monkeypatch.setattr(seq, "visual_hull", lambda cameras, masks: int(masks["c0"][0, 0]))
    monkeypatch.setattr(seq, "cotangent_weights", lambda V, F: ("cot", float(np.sum(V))))
    monkeypatch.setattr(seq, "depth_observation", lambda image, cam: ("depth", float(image.sum())))
    monkeypatch.setattr(seq, "frame_plausibility", lambda *a, **k: {"ok": True})
    monkeypatch.setattr(seq, "run_plausibility", lambda frames, path: {"ok": True, "warnings": [], "problems": []})
    monkeypatch.setattr(seq, "save_mesh", lambda path, mesh: r.__dict__.setdefault("saved", {}).update(
        {Path(path).name: np.array(mesh.vertices)}))
    monkeypatch.setattr(seq, "time", Clock())
    monkeypatch.setattr(bodystudio.body, "build_body", r.build_body)
    return r


def _run(rec, tmp_path, frames=FRAMES, tracking=True, track=None, refine_pose=False, warm_start=False,
         joints="tracker", bone_lengths="frame", joint_smoothing=0, params=None, refine_params=None, depth=False,
         joints_path=None):
    writer = Writer(tmp_path)
    params = params or RapidSkinParams(outer_iterations=5)
    track = track if track is not None else TrackParams(outside_px=OUTSIDE_PX)
    summary = seq.reconstruct_frames(_session(depth), writer, list(frames), [NS(name="c0")],
                                     NS(depth="depth-camera"), params, "gs", "6k", joints, joints_path, warm_start,
                                     refine_pose, False, False, tracking=tracking, track_params=track,
                                     refine_with="fields", rest_cotangents=True, refine_params=refine_params,
                                     bone_lengths=bone_lengths, joint_smoothing=joint_smoothing)
    return summary, writer.json["frames.json"]["frames"], writer.meta


EXPECTED_TRACK = ["first", "tracked", "silhouette", "joint_jump", "joint_jump", "energy_jump", "tracked", "tracked"]
EXPECTED_JUMP = [0.0, 0.02, 0.10, 0.52, 0.48, 0.02, 0.02, 0.02]
EXPECTED_PRIOR = [1.0, 0.18, 0.5, 0.18, 1.0, 0.18, 0.18, 0.18]
EXPECTED_ENERGY = [0.1, 0.1, 0.1, 1.0, 0.1, 0.1, 0.1, 0.18]


def test_lost_track_reasons_and_check_figures_frame_by_frame(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    summary, frames, meta = _run(rec, tmp_path)
    assert [f["frame"] for f in frames] == FRAMES
    assert [f["track"] for f in frames] == EXPECTED_TRACK
    assert summary["n_tracked"] == 3
    for f, jump, prior, energy in zip(frames, EXPECTED_JUMP, EXPECTED_PRIOR, EXPECTED_ENERGY, strict=True):
        assert set(f["track_check"]) == {"joint_jump_m", "prior_outside", "energy"}
        assert all(type(v) is float for v in f["track_check"].values())
        assert f["track_check"]["joint_jump_m"] == pytest.approx(jump, abs=1e-9)
        assert f["track_check"]["prior_outside"] == pytest.approx(prior, abs=1e-9)
        assert f["track_check"]["energy"] == pytest.approx(energy, abs=1e-9)
    assert meta["tracking"] is True
    assert meta["track_params"] == asdict(TrackParams(outside_px=OUTSIDE_PX))
    # the tracking fit runs where the check keeps the track, from the previous frame's pose, on this frame's fields
    fits = rec.calls["track"]
    assert [c[2] for c in fits] == [11, 15, 16, 17]
    prev_x = [0.0, 0.16, 0.18, 0.20]
    for (body, previous, _fid, params, T_joints), x in zip(fits, prev_x, strict=True):
        assert body is BODIES["2k"]
        np.testing.assert_allclose(previous, SK[0] + [x, 0, 0], atol=1e-12)
        assert params.outside_px == OUTSIDE_PX
        assert T_joints is None  # joint_weight 0: no joint anchors
    assert rec.calls["build"] == ["6k", "2k"]
    assert rec.calls["fields"] == FRAMES


def test_tracked_frames_pose_the_template_with_the_fit_and_the_previous_scale(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _summary, frames, _meta = _run(rec, tmp_path)
    deform = rec.calls["deform"]
    body = BODIES["6k"]
    # the scale each frame's init carries: from its joints when (re-)initialised, the previous one's when tracked
    scales = {}
    prev = None
    for fid, track in zip(FRAMES, EXPECTED_TRACK, strict=True):
        scales[fid] = prev if track == "tracked" else 1.0 + 0.5 * JOINT_X[fid]
        prev = scales[fid]
    assert scales[16] == pytest.approx(1.09) and scales[17] == pytest.approx(1.09)
    for k, (fid, track) in enumerate(zip(FRAMES, EXPECTED_TRACK, strict=True)):
        if track == "tracked":
            T = _truth(fid) + [FIT_BIAS.get(fid, 0.0), 0, 0]
        else:
            T = _joints(fid)[0]
        np.testing.assert_allclose(deform[k]["V"], body.vertices * scales[fid] + T, atol=1e-12)
        np.testing.assert_allclose(deform[k]["reference"], deform[k]["V"], atol=1e-12)
        assert deform[k]["fields"].fid == fid
        assert deform[k]["masks"]["c0"][0, 0] == fid
        assert deform[k]["delta"] == ("cot", float(np.sum(body.vertices)))
        # outer count: the tracked frame's min(run, tracking), the others the run's own settings object
        if track == "tracked":
            assert deform[k]["params"].outer_iterations == 3
            assert deform[k]["params"] == replace(deform[0]["params"], outer_iterations=3)
        else:
            assert deform[k]["params"] is deform[0]["params"]
            assert deform[k]["params"].outer_iterations == 5
    # the results written are the deformation's
    for k, fid in enumerate(FRAMES):
        np.testing.assert_allclose(rec.saved[f"{fid:05d}.ply"], deform[k]["V"] + [0, 0, 0.001 * (k + 1)])


def test_tracked_frame_timings_are_the_steps_between_clock_reads(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    summary, frames, _meta = _run(rec, tmp_path)
    # clock reads per frame: lost-track check 2 s (+1 s for the energy of an initialised frame), fields 1 s
    for f, track in zip(frames, EXPECTED_TRACK, strict=True):
        assert f["track_ms"] == (1000.0 if track == "tracked" else 2000.0)
        assert f["fields_ms"] == 1000.0
        assert f["refine_ms"] == 0.0
    assert summary["track_ms"] == pytest.approx(1000 * (3 * 1 + 5 * 2) / 8)
    _summary, frames, _meta = _run(rec, tmp_path / "off", tracking=False, frames=FRAMES[:3])
    for f in frames:
        assert f["track_ms"] == 0.0
        assert f["track"] == "per_frame"
        assert "track_check" not in f
        assert f["fields_ms"] == 1000.0


def test_warm_mesh_carries_the_previous_result_and_the_outer_count_is_capped(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    track = TrackParams(outside_px=OUTSIDE_PX, warm_mesh=True, outer_iterations=7)
    _s, frames, meta = _run(rec, tmp_path, track=track)
    assert [f["track"] for f in frames] == EXPECTED_TRACK
    assert meta["track_params"]["warm_mesh"] is True
    deform = rec.calls["deform"]
    body = BODIES["6k"]
    posed = {}
    result = {}
    for k, (fid, track_k) in enumerate(zip(FRAMES, EXPECTED_TRACK, strict=True)):
        scale = 1.09 if fid in (16, 17) else (1.0 + 0.5 * JOINT_X[fid] if track_k != "tracked" else 1.0)
        T = _truth(fid) + [FIT_BIAS.get(fid, 0.0), 0, 0] if track_k == "tracked" else _joints(fid)[0]
        posed[fid] = body.vertices * scale + T
        if track_k == "tracked":
            prev = FRAMES[k - 1]
            expected = result[prev] + (posed[fid] - posed[prev])
            # min(run's 5, tracking's 7)
            assert deform[k]["params"].outer_iterations == 5
        else:
            expected = posed[fid]
            assert deform[k]["params"].outer_iterations == 5
        np.testing.assert_allclose(deform[k]["V"], expected, atol=1e-12)
        np.testing.assert_allclose(deform[k]["reference"], posed[fid], atol=1e-12)
        result[fid] = deform[k]["V"] + [0, 0, 0.001 * (k + 1)]
    # the carried start differs from the posed template by the previous result's offsets
    assert not np.allclose(deform[1]["V"], posed[11])


def test_outer_count_zero_keeps_the_runs_settings_and_no_warm_mesh_starts_from_the_pose(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    track = TrackParams(outside_px=OUTSIDE_PX, warm_mesh=False, outer_iterations=0)
    _run(rec, tmp_path, track=track)
    deform = rec.calls["deform"]
    assert all(d["params"] is deform[0]["params"] for d in deform)
    assert all(d["params"].outer_iterations == 5 for d in deform)


def test_energy_after_a_refined_initialisation_is_of_the_refined_pose(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, frames, meta = _run(rec, tmp_path, refine_pose=True, frames=FRAMES[:3])
    # the refinement moves the pose 5 mm up: the energy of an initialised frame is of that pose
    assert frames[0]["track_check"]["energy"] == pytest.approx(0.1 + 0.005 / (0.1 * OUTSIDE_PX))
    assert [f["track"] for f in frames] == ["first", "tracked", "silhouette"]
    for body, _T, hull, params, data in rec.calls["refine"]:
        assert body is BODIES["2k"] and hull is None and params is None
        assert data[0] == "data" and data[2].outside_px == OUTSIDE_PX
    assert [c[4][1] for c in rec.calls["refine"]] == [10, 12]
    assert frames[0]["refine_ms"] == 1000.0 and frames[1]["refine_ms"] == 0.0
    assert meta["refine_bones"] == list(REFINE_BONES)
    # frame 11 is tracked from frame 10's refined pose
    np.testing.assert_allclose(rec.calls["track"][0][1], SK[0] + [0, 0.005, 0], atol=1e-12)


def test_joint_anchors_come_from_this_frames_joints(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    track = TrackParams(outside_px=OUTSIDE_PX, joint_weight=0.5)
    _run(rec, tmp_path, track=track, frames=FRAMES[:2])
    (body, _prev, fid, params, T_joints), = rec.calls["track"]
    assert fid == 11 and params.joint_weight == 0.5
    np.testing.assert_allclose(T_joints, _joints(11)[0], atol=1e-12)
    # the anchor's pose is the fit body's: the second init call poses the 2k body with frame 11's joints
    inits = [(b, J) for b, J, _r in rec.calls["init"]]
    assert inits[1][0] is BODIES["2k"]
    np.testing.assert_allclose(inits[1][1], _joints(11), atol=1e-12)


def test_tracking_without_silhouette_constraints_still_reads_the_masks(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=5, constraints=("depth",))
    _s, frames, _meta = _run(rec, tmp_path, params=params, frames=FRAMES[:3], depth=True)
    assert [f["track"] for f in frames] == ["first", "tracked", "silhouette"]
    assert rec.calls["fields"] == FRAMES[:3]
    assert all(d["masks"] is None for d in rec.calls["deform"])
    assert [d["fields"].fid for d in rec.calls["deform"]] == FRAMES[:3]


def test_per_frame_run_builds_no_fit_body_and_no_fields(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=5, constraints=("depth",))
    _s, frames, meta = _run(rec, tmp_path, params=params, frames=FRAMES[:2], depth=True, tracking=False)
    assert rec.calls["build"] == ["6k"]
    assert rec.calls["fields"] == []
    assert all(d["fields"] is None for d in rec.calls["deform"])
    assert meta["tracking"] is False and meta["track_params"] is None
    assert all(f["track"] == "per_frame" for f in frames)
    assert rec.calls["track"] == []


def test_warm_start_poses_the_running_mean_of_the_unposed_results(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, _frames, meta = _run(rec, tmp_path, tracking=False, warm_start=True, frames=FRAMES[:4])
    assert meta["warm_start"] is True
    body = BODIES["6k"]
    deform = rec.calls["deform"]
    inits = rec.calls["init"]
    shape_sum, n = body.vertices.copy(), 1
    for k, fid in enumerate(FRAMES[:4]):
        rest = shape_sum / n
        np.testing.assert_allclose(inits[k][2], rest if k else body.vertices, atol=1e-12)
        if k == 0:
            assert inits[k][2] is body.vertices
        T, scale = _joints(fid)[0], 1.0 + 0.5 * JOINT_X[fid]
        np.testing.assert_allclose(deform[k]["V"], rest * scale + T, atol=1e-12)
        # the smoothness reference: the generic template posed once the rest shape is no longer the template's
        np.testing.assert_allclose(deform[k]["reference"], body.vertices + T if k else rest * scale + T, atol=1e-12)
        V = deform[k]["V"] + [0, 0, 0.001 * (k + 1)]
        np.testing.assert_allclose(rec.calls["unpose"][k], T, atol=1e-12)
        shape_sum = shape_sum + (V - T)
        n += 1
    assert len(rec.calls["unpose"]) == 4


def test_no_warm_start_keeps_the_template_rest_shape(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _run(rec, tmp_path, tracking=False, warm_start=False, frames=FRAMES[:3])
    assert rec.calls["unpose"] == []
    assert all(r is BODIES["6k"].vertices for _b, _J, r in rec.calls["init"])


def test_warm_start_with_tracking_poses_the_tracked_frame_on_the_running_mean(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, frames, _meta = _run(rec, tmp_path, warm_start=True, frames=FRAMES[:2])
    assert [f["track"] for f in frames] == ["first", "tracked"]
    body = BODIES["6k"]
    V0 = rec.calls["deform"][0]["V"] + [0, 0, 0.001]
    rest = (body.vertices + (V0 - _joints(10)[0])) / 2
    T = _truth(11)
    np.testing.assert_allclose(rec.calls["deform"][1]["V"], rest * 1.0 + T, atol=1e-12)
    np.testing.assert_allclose(rec.calls["deform"][1]["reference"], body.vertices + T, atol=1e-12)


def test_joint_smoothing_feeds_the_smoothed_track_and_its_lengths(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, _frames, meta = _run(rec, tmp_path, tracking=False, refine_pose=True, joint_smoothing=3,
                             bone_lengths="sequence", frames=FRAMES[:4])
    (frames_arg, raw, half), = rec.calls["smooth"]
    assert half == 3
    np.testing.assert_array_equal(frames_arg, FRAMES[:4])
    np.testing.assert_allclose(raw, [_joints(f) for f in FRAMES[:4]], atol=1e-12)
    smoothed = [_joints(f) + [0, 0, 0.03] for f in FRAMES[:4]]
    (lengths_of,), = [rec.calls["seq_lengths"]]
    np.testing.assert_allclose(lengths_of, smoothed, atol=1e-12)
    for k, fid in enumerate(FRAMES[:4]):
        J, L = rec.calls["with_lengths"][k]
        np.testing.assert_allclose(J, _joints(fid) + [0, 0, 0.03], atol=1e-12)
        np.testing.assert_allclose(L, 0.3)
        np.testing.assert_allclose(rec.calls["init"][k][1], J + [0, 0.002, 0], atol=1e-12)
    # with steadier joints the refinement fits the head too
    assert all(c[3] == PoseRefineParams(bones=REFINE_BONES_WITH_HEAD) for c in rec.calls["refine"])
    assert meta["refine_bones"] == list(REFINE_BONES_WITH_HEAD)
    assert meta["joint_smoothing"] == 3 and type(meta["joint_smoothing"]) is int


def test_joint_smoothing_with_frame_lengths_and_given_refinement(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    mine = PoseRefineParams(iterations=4)
    _s, _f, meta = _run(rec, tmp_path, tracking=False, refine_pose=True, joint_smoothing=2, bone_lengths="frame",
                        refine_params=mine, frames=FRAMES[:2])
    assert rec.calls["seq_lengths"] == [] and rec.calls["with_lengths"] == []
    assert all(c[3] is mine for c in rec.calls["refine"])
    assert meta["refine_bones"] == list(REFINE_BONES)
    np.testing.assert_allclose(rec.calls["init"][1][1], _joints(11) + [0, 0, 0.02], atol=1e-12)


def test_no_smoothing_reads_each_frames_joints_and_the_runs_lengths(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, _f, meta = _run(rec, tmp_path, tracking=False, refine_pose=True, joint_smoothing=0,
                        bone_lengths="sequence", frames=FRAMES[:3])
    assert rec.calls["smooth"] == []
    (lengths_of,), = [rec.calls["seq_lengths"]]
    np.testing.assert_allclose(lengths_of, [_joints(f) for f in FRAMES[:3]], atol=1e-12)
    assert all(c[3] is None for c in rec.calls["refine"])
    assert meta["refine_bones"] == list(REFINE_BONES)
    for k, fid in enumerate(FRAMES[:3]):
        np.testing.assert_allclose(rec.calls["with_lengths"][k][0], _joints(fid), atol=1e-12)


def test_hull_joints_are_never_smoothed(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, _f, meta = _run(rec, tmp_path, tracking=False, refine_pose=True, joint_smoothing=3, joints="hull",
                        bone_lengths="sequence", frames=FRAMES[:3])
    assert rec.calls["smooth"] == [] and rec.calls["seq_lengths"] == [] and rec.calls["with_lengths"] == []
    assert all(c[3] is None for c in rec.calls["refine"])
    assert [c[2] for c in rec.calls["hull_fit"]] == [None, ("pose", 10), ("pose", 11)]
    np.testing.assert_allclose(rec.calls["init"][2][1], _joints(12), atol=1e-12)


@pytest.mark.parametrize("k, ok", [(-1, False), (0, True), (50, True), (51, False)])
def test_joint_smoothing_range(monkeypatch, tmp_path, k, ok):
    rec = _stand_ins(monkeypatch)
    if ok:
        _run(rec, tmp_path, tracking=False, joint_smoothing=k, frames=FRAMES[:1])
    else:
        with pytest.raises(InputError, match=f"--joint-smoothing {k}: give a half window of 0..50 frames"):
            _run(rec, tmp_path, tracking=False, joint_smoothing=k, frames=FRAMES[:1])


def test_run_joints_reads_the_selected_frames_and_smooths_them(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    out = seq.run_joints(_session(), [11, 13], "tracker", None, 4)
    (frames_arg, raw, half), = rec.calls["smooth"]
    np.testing.assert_array_equal(frames_arg, [11, 13])
    assert half == 4
    np.testing.assert_allclose(raw, [_joints(11), _joints(13)], atol=1e-12)
    np.testing.assert_allclose(out, raw + [0, 0, 0.04], atol=1e-12)
    # joints from files: the folder given
    d = tmp_path / "j"
    d.mkdir()
    import json

    (d / "00012.json").write_text(json.dumps({"names": list(NAMES), "positions": (_joints(12) + 0.1).tolist()}))
    out = seq.run_joints(_session(), [12], "file", str(d), 0)
    np.testing.assert_allclose(out, [_joints(12) + 0.1], atol=1e-12)
    assert rec.calls["smooth"][-1][2] == 0


def _joints_files(folder: Path, shift=0.05):
    """Per-frame joint files 5 cm off the session's tracker joints (so the source read is told apart)."""
    import json

    folder.mkdir()
    for fid in FRAMES:
        (folder / f"{fid:05d}.json").write_text(json.dumps({"names": list(NAMES),
                                                            "positions": (_joints(fid) + shift).tolist()}))
    return folder


@pytest.mark.parametrize("smoothing, lengths", [(0, "frame"), (0, "sequence"), (2, "frame")])
def test_joints_files_are_read_from_the_folder_given(monkeypatch, tmp_path, smoothing, lengths):
    rec = _stand_ins(monkeypatch)
    d = _joints_files(tmp_path / "joints")
    _run(rec, tmp_path / "run", tracking=False, joints="file", joints_path=str(d), joint_smoothing=smoothing,
         bone_lengths=lengths, frames=FRAMES[:2])
    extra = np.array([0, 0, 0.01 * smoothing]) + ([0, 0.002, 0] if lengths == "sequence" else [0, 0, 0])
    for k, fid in enumerate(FRAMES[:2]):
        np.testing.assert_allclose(rec.calls["init"][k][1], _joints(fid) + 0.05 + extra, atol=1e-12)
    if lengths == "sequence":
        np.testing.assert_allclose(rec.calls["seq_lengths"][0], [_joints(f) + 0.05 for f in FRAMES[:2]])


def test_per_frame_run_without_refinement_deforms_to_the_frames_masks(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _s, _f, meta = _run(rec, tmp_path, tracking=False, refine_pose=False, frames=FRAMES[:2])
    assert [d["masks"]["c0"][0, 0] for d in rec.calls["deform"]] == FRAMES[:2]
    assert rec.calls["build"] == ["6k"]
    assert meta["refine_bones"] == [] and meta["refine_pose"] is False


@pytest.mark.parametrize("constraints", [("depth",), ("silhouette",)])
def test_hull_joints_without_refinement_read_the_masks_and_fit_the_2k_body(monkeypatch, tmp_path, constraints):
    rec = _stand_ins(monkeypatch)
    params = RapidSkinParams(outer_iterations=5, constraints=constraints)
    _run(rec, tmp_path, tracking=False, refine_pose=False, joints="hull", params=params, frames=FRAMES[:2],
         depth=True)
    assert [c[1] for c in rec.calls["hull_fit"]] == FRAMES[:2]
    assert rec.calls["build"] == ["6k", "2k"]


def test_template_poses_are_of_the_template_body(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _run(rec, tmp_path)
    inits = [b for b, _J, _r in rec.calls["init"]]
    poses = [b for b, *_ in rec.calls["pose"]]
    # per frame: the template's init from the joints, or its pose by the tracking fit; the 2k body for the checks
    assert sum(b is BODIES["6k"] for b in inits) == 5 and sum(b is BODIES["6k"] for b in poses) == 3
    assert set(map(id, inits + poses)) == {id(BODIES["6k"]), id(BODIES["2k"])}


def test_refined_pose_with_warm_start_poses_the_running_rest_shape_at_the_joints_scale(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    frames = [12, 13]
    _run(rec, tmp_path, tracking=False, refine_pose=True, warm_start=True, frames=frames)
    body = BODIES["6k"]
    deform = rec.calls["deform"]
    V0 = deform[0]["V"] + [0, 0, 0.001]
    T0 = _joints(12)[0] + [0, 0.005, 0]
    np.testing.assert_allclose(deform[0]["V"], body.vertices * (1 + 0.5 * 0.12) + T0, atol=1e-12)
    rest = (body.vertices + (V0 - T0)) / 2
    T1 = _joints(13)[0] + [0, 0.005, 0]
    np.testing.assert_allclose(deform[1]["V"], rest * (1 + 0.5 * 0.64) + T1, atol=1e-12)
    np.testing.assert_allclose(rec.calls["unpose"][1], T1, atol=1e-12)
    # the refined pose and the smoothness reference pose the template, not the refinement's 2k body
    assert len(rec.calls["pose"]) == 3 and all(b is body for b, *_ in rec.calls["pose"])


def test_run_joints_default_is_as_tracked(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    seq.run_joints(_session(), [11], "tracker", None)
    assert rec.calls["smooth"][0][2] == 0
