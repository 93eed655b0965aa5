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
    """``time.perf_counter`` ticking ``step`` (1 s) per read."""

    def __init__(self, step=1.0):
        self.t, self.step = 0.0, step

    def perf_counter(self):
        self.t += self.step
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

    def neck_at_joint(self, body, bone_transforms, neck, unstretch_head=False):
        """The neck's placement (rec15l; the head unstretched, rec15m) as the identity: the same transforms object, so
        nothing is posed again."""
        self.calls.setdefault("neck", []).append((body, np.array(bone_transforms), np.array(neck), unstretch_head))
        return bone_transforms

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
        assert F is BODIES["6k"].faces and [c.name for c in cameras] == ["c0"]
        k = len(self.calls["deform"])
        self.calls["deform"].append(dict(V=np.array(V), params=params, masks=masks, delta=delta,
                                         reference=np.array(smooth_reference), fields=fields))
        return NS(vertices=np.asarray(V) + [0.0, 0.0, 0.001 * (k + 1)], solver_s=0.25, matching_s=0.125,
                  n_silhouette=7, n_depth=0, silhouette_vertices=np.array([k]))

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

    def fields(self, cameras, masks, **kw):
        assert [c.name for c in cameras] == ["c0"]
        self.calls["fields"].append(int(masks["c0"][0, 0]))
        self.calls.setdefault("fields_kw", []).append(kw)
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
        self.deletes = list(deletes)


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
    for name in ("initialise_pose", "pose_template", "neck_at_joint", "outside_fraction", "track_bone_transforms",
                 "refine_bone_transforms", "deform_to_observations", "unpose", "smooth_joint_track",
                 "sequence_bone_lengths", "with_bone_lengths", "fit_body_to_hull"):
        monkeypatch.setattr(seq, name, getattr(r, name))
    monkeypatch.setattr(seq, "SilhouetteFields", r.fields)
    monkeypatch.setattr(seq, "silhouette_data_term", lambda fields, params: ("data", fields.fid, params))
    def hull(cameras, masks):
        assert [c.name for c in cameras] == ["c0"]
        return int(masks["c0"][0, 0])

    def cot(V, F):
        assert F is BODIES["6k"].faces
        return ("cot", float(np.sum(V)))

    def depth(image, cam):
        assert cam == "depth-camera"
        return ("depth", float(image.sum()))

    monkeypatch.setattr(seq, "visual_hull", hull)
    monkeypatch.setattr(seq, "cotangent_weights", cot)
    monkeypatch.setattr(seq, "depth_observation", depth)
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
                                     bone_lengths=bone_lengths, joint_smoothing=joint_smoothing,
                                     shape_prior="off")  # the stand-in body has no shape space: the tracked
    # default's carried prior (TRACKED_SHAPE_PRIOR) is tested in test_tracked_shape_prior_default.py
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
    # a tracked run's fields by the tracker's transform (TrackParams.exact_fields, default the chamfer one)
    assert rec.calls["fields_kw"] == [{"exact": False}] * len(FRAMES)


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
            assert deform[k]["params"].outer_iterations == TrackParams().outer_iterations == 2
            assert deform[k]["params"] == replace(deform[0]["params"], outer_iterations=2,
                                                  matching=TrackParams().matching, tau_px=TrackParams().tau_px,
                                                  inner_iterations=TrackParams().inner_iterations)
        else:  # a re-initialised frame: the tracker's first-frame settings (rec15n), the same for each
            assert deform[k]["params"] == deform[0]["params"] == replace(
                deform[0]["params"], outer_iterations=TrackParams().initial_outer_iterations,
                inner_iterations=TrackParams().initial_inner_iterations)
            assert deform[k]["params"].outer_iterations == 3
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
    track = TrackParams(outside_px=OUTSIDE_PX, warm_mesh=True, outer_iterations=7, initial_outer_iterations=0,
                        initial_inner_iterations=0)
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
    track = TrackParams(outside_px=OUTSIDE_PX, warm_mesh=False, outer_iterations=0, inner_iterations=0,
                        initial_outer_iterations=0, initial_inner_iterations=0)
    _run(rec, tmp_path, track=track)
    deform = rec.calls["deform"]
    # the run's settings but, on a tracked frame, the tracker's matching schedule
    for d, t in zip(deform, EXPECTED_TRACK, strict=True):
        assert d["params"] == (replace(deform[0]["params"], matching=track.matching, tau_px=track.tau_px)
                               if t == "tracked" else deform[0]["params"])
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


# --- the rest of the run's record on the same stand-ins: timings, self-check, scores, files, run.json, summary -------

def _recording(monkeypatch, verdict=None):
    """:func:`_stand_ins` plus recorders of the self-check, the scores, the progress bar and the files."""
    import bodystudio.capture.session as session_mod

    rec = _stand_ins(monkeypatch)
    rec.plaus, rec.scores, rec.run_checks, rec.bar, rec.meshes = [], [], [], [], []

    def plausibility(V, F, cameras, masks, depth, depth_cam, coherence=False):
        rec.plaus.append(dict(V=np.array(V), F=F, cameras=cameras, masks=masks, depth=depth, depth_cam=depth_cam,
                              coherence=coherence))
        return {"frame_check": len(rec.plaus)}

    def run_check(frames, path):
        rec.run_checks.append((frames, path))
        return verdict or {"ok": True, "warnings": [], "problems": []}

    def score(V, F, frame, cameras, regions=None, joints=None):
        assert [c.name for c in cameras] == ["c0"]
        rec.scores.append(dict(V=np.array(V), F=F, fid=frame.frame_id, cameras=cameras, regions=regions,
                               joints=joints))
        return {"visible_median_mm": 1.0 + frame.frame_id, "visible_p90_mm": 2.0, "hausdorff_mm": 3.0,
                "pct_under_10mm": 4.0, "iou_min": 0.5, "median_mm": 5.0, "p90_mm": 6.0}

    class Bar:
        def __init__(self, enabled):
            rec.bar.append(("enabled", enabled))

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def add_task(self, text, total):
            rec.bar.append(("task", text, total))
            return "task-id"

        def advance(self, task):
            rec.bar.append(("advance", task))

    monkeypatch.setattr(seq, "frame_plausibility", plausibility)
    monkeypatch.setattr(seq, "run_plausibility", run_check)
    monkeypatch.setattr(seq, "score_frame", score)
    monkeypatch.setattr(seq, "vertex_regions", lambda body: ("regions", id(body)))
    monkeypatch.setattr(seq, "save_mesh", lambda path, mesh: rec.meshes.append((path, np.array(mesh.vertices),
                                                                                 mesh.faces)))
    monkeypatch.setattr(session_mod, "progress_bar", Bar)
    return rec


def _run_all(rec, tmp_path, frames=(10, 11, 12), score=False, params=None, depth=False, streams=("mask",),
             **kw):
    writer = Writer(tmp_path)
    (tmp_path / "meshes" / "00003.ply").write_text("old")
    session = _session(depth)
    session.streams = set(streams)
    params = params or RapidSkinParams(outer_iterations=5)
    summary = seq.reconstruct_frames(session, writer, list(frames), [NS(name="c0")], NS(depth="depth-camera"),
                                     params, "gs", "6k", kw.pop("joints", "tracker"), None, False,
                                     kw.pop("refine_pose", False), score, True,
                                     **{"shape_prior": "off", **kw})
    return summary, writer


def _no_residual(frame: int) -> dict:
    """rel5's figure of a frame whose fitted limb joints are the tracker's (the stand-ins pose on the joints)."""
    return {"max_mm": 0.0, "median_mm": 0.0, "joint": "ElbowLeft", "frame": frame, "tracked": False}


def test_frame_record_timings_and_counts_on_the_ticking_clock(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    summary, writer = _run_all(rec, tmp_path, bone_lengths="frame")
    frames = writer.json["frames.json"]["frames"]
    assert set(writer.json) == {"frames.json"}
    for k, f in enumerate(frames):
        # reads: start, read, t0, t1, fields, init, frame: read 1 s, fields 1 s, init 3 s, frame 6 s
        assert f == {"frame": 10 + k, "track": "per_frame", "solver_ms": 250.0, "matching_ms": 125.0,
                     "init_ms": 3000.0, "refine_ms": 0.0, "track_ms": 0.0, "fields_ms": 1000.0, "read_ms": 1000.0,
                     "frame_ms": 6000.0, "other_ms": 1000 * (6 - 1 - 3 - 0.25 - 0.125), "n_silhouette": 7,
                     "n_depth": 0, "ms_per_frame": 3375.0,
                     "plausibility": {"frame_check": k + 1, "tracker_joint_residual": _no_residual(10 + k)}}
    assert summary == {"frames": 3, "ms_per_frame": 3375.0, "solver_ms": 250.0, "matching_ms": 125.0,
                       "init_ms": 3000.0, "refine_ms": 0.0, "frame_ms": 6000.0, "read_ms": 1000.0,
                       "fields_ms": 1000.0, "track_ms": 0.0, "other_ms": 1625.0, "n_tracked": 0}
    # on a clock of 0.5 s per read every figure halves (a product, not a quotient, of the clock)
    rec2 = _recording(monkeypatch)
    monkeypatch.setattr(seq, "time", Clock(0.5))
    _s2, writer2 = _run_all(rec2, tmp_path / "half", frames=(10,), bone_lengths="frame")
    f = writer2.json["frames.json"]["frames"][0]
    assert (f["read_ms"], f["fields_ms"], f["init_ms"], f["frame_ms"]) == (500.0, 500.0, 1500.0, 3000.0)
    # the progress bar: enabled as asked, one task of the frames, advanced once per frame
    assert rec.bar == [("enabled", True), ("task", "rapid skin gs 6k", 3)] + [("advance", "task-id")] * 3


def test_self_check_inputs_per_frame_and_the_runs_verdict(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    _summary, writer = _run_all(rec, tmp_path, frames=(10, 11, 12, 13, 14), bone_lengths="frame")
    body = BODIES["6k"]
    assert [p["coherence"] for p in rec.plaus] == [True, False, True, False, True]  # first, middle, last
    for k, p in enumerate(rec.plaus):
        np.testing.assert_array_equal(p["V"], rec.calls["deform"][k]["V"] + [0, 0, 0.001 * (k + 1)])
        assert p["F"] is body.faces and [c.name for c in p["cameras"]] == ["c0"]
        assert p["masks"]["c0"][0, 0] == 10 + k and p["depth"] is None and p["depth_cam"] is None
    (checks, path), = rec.run_checks
    assert checks == [{"frame_check": k + 1, "tracker_joint_residual": _no_residual(10 + k)} for k in range(5)]
    assert path == Path("/stand-in/session")
    assert writer.meta["plausibility"] == {"ok": True, "warnings": [], "problems": []}


def test_depth_frames_check_their_depth_and_a_mask_stream_supplies_the_masks(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    params = RapidSkinParams(outer_iterations=5, constraints=("depth",))
    _run_all(rec, tmp_path, frames=(10, 11), params=params, depth=True, bone_lengths="frame")
    for k, p in enumerate(rec.plaus):
        assert p["masks"]["c0"][0, 0] == 10 + k  # not fitted, but the session has masks: the check reads them
        assert p["depth"].sum() == 8.0 and p["depth_cam"] == "depth-camera"
    assert all(d["masks"] is None for d in rec.calls["deform"])
    rec2 = _recording(monkeypatch)
    _run_all(rec2, tmp_path / "b", frames=(10,), params=params, depth=True, streams=(), bone_lengths="frame")
    assert rec2.plaus[0]["masks"] is None
    rec3 = _recording(monkeypatch)
    _run_all(rec3, tmp_path / "c", frames=(10,), streams=(), bone_lengths="frame")
    assert rec3.plaus[0]["masks"]["c0"][0, 0] == 10


def test_depth_constraints_feed_the_depth_observation_and_a_missing_image_is_refused(monkeypatch, tmp_path):
    from bodystudio.errors import SessionError

    rec = _recording(monkeypatch)
    seen = []

    def deform(V, F, cameras, masks, params, depth=None, **kw):
        seen.append(depth)
        return NS(vertices=np.asarray(V), solver_s=0.0, matching_s=0.0, n_silhouette=1, n_depth=3)

    monkeypatch.setattr(seq, "deform_to_observations", deform)
    params = RapidSkinParams(outer_iterations=5, constraints=("silhouette", "depth"))
    _s, writer = _run_all(rec, tmp_path, frames=(10,), params=params, depth=True, bone_lengths="frame")
    assert seen == [("depth", 8.0)]
    assert writer.json["frames.json"]["frames"][0]["n_depth"] == 3
    with pytest.raises(SessionError, match=r"^/stand-in/session frame 10: no Kinect depth image; use --constraints "
                                           r"silhouette$"):
        _run_all(rec, tmp_path / "b", frames=(10,), params=params, depth=False, bone_lengths="frame")


def test_meshes_scores_and_run_json(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    summary, writer = _run_all(rec, tmp_path, frames=(10, 12), score=True, bone_lengths="sequence")
    body = BODIES["6k"]
    assert [p.relative_to(tmp_path).as_posix() for p, _V, _F in rec.meshes] == ["meshes/00010.ply",
                                                                              "meshes/00012.ply"]
    for k, (_p, V, F) in enumerate(rec.meshes):
        np.testing.assert_array_equal(V, rec.calls["deform"][k]["V"] + [0, 0, 0.001 * (k + 1)])
        np.testing.assert_array_equal(F, body.faces)
    for k, s in enumerate(rec.scores):
        np.testing.assert_array_equal(s["V"], rec.meshes[k][1])
        assert s["F"] is body.faces and s["fid"] == (10, 12)[k] and s["regions"] == ("regions", id(body))
        np.testing.assert_array_equal(s["joints"], _joints((10, 12)[k]) + [0, 0.002, 0])
    frames = writer.json["frames.json"]["frames"]
    assert [f["metrics"]["visible_median_mm"] for f in frames] == [11.0, 13.0]
    meta = writer.meta
    assert meta["solver"] == "gs" and meta["template"] == "6k" and meta["joints"] == "tracker"
    assert meta["constraints"] == ["silhouette"] and type(meta["constraints"]) is list
    assert meta["frames"] == [10, 12] and meta["refine_pose"] is False and meta["refine_with"] == "fields"
    assert meta["rest_cotangents"] is True and meta["bone_lengths"] == "sequence"
    assert meta["params"] == asdict(RapidSkinParams(outer_iterations=5))
    assert meta["n_vertices"] == 4 and type(meta["n_vertices"]) is int
    assert writer.deletes == ["meshes/00003.ply"]
    assert summary["frames"] == 2 and summary["median_mm"] == 12.0 and "init_joint_error_mm" not in summary


def test_scores_off_need_no_regions(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    monkeypatch.setattr(seq, "vertex_regions", lambda body: pytest.fail("regions without scores"))
    _s, writer = _run_all(rec, tmp_path, frames=(10,), score=False, bone_lengths="frame")
    assert rec.scores == [] and "metrics" not in writer.json["frames.json"]["frames"][0]


def test_an_implausible_run_is_refused_unless_accepted(monkeypatch, tmp_path):
    from bodystudio.errors import ImplausibleResultError

    bad = {"ok": False, "warnings": ["w1"], "problems": ["camera c0 moved", "p2"]}
    rec = _recording(monkeypatch, verdict=bad)
    with pytest.raises(ImplausibleResultError, match=r"^/stand-in/session: reconstruction not written, camera c0 "
                                                     r"moved; or pass --accept-implausible$"):
        _run_all(rec, tmp_path, frames=(10,), bone_lengths="frame", accept_implausible=False)
    _s, writer = _run_all(rec, tmp_path / "b", frames=(10,), bone_lengths="frame")  # a chunk's default: accepted
    assert writer.meta["plausibility"] is bad


def test_refinement_to_the_carved_hull(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    hulls = []
    monkeypatch.setattr(seq, "visual_hull", lambda cameras, masks: hulls.append((cameras[0].name,
                                                                                 int(masks["c0"][0, 0]))) or
                        int(masks["c0"][0, 0]))
    mine = PoseRefineParams(iterations=3)
    _s, writer = _run_all(rec, tmp_path, frames=(10, 11), refine_pose=True, refine_with="hull",
                          bone_lengths="frame", refine_params=mine)
    assert [c[2] for c in rec.calls["refine"]] == [10, 11] and all(c[4] is None for c in rec.calls["refine"])
    assert all(c[3] is mine for c in rec.calls["refine"])
    assert hulls == [("c0", 10), ("c0", 11)] and writer.meta["refine_with"] == "hull"
    # joints from the hull: its hull is the refinement's (carved once per frame)
    hulls.clear()
    rec2 = _recording(monkeypatch)
    monkeypatch.setattr(seq, "visual_hull", lambda cameras, masks: hulls.append((cameras[0].name,
                                                                                 int(masks["c0"][0, 0]))) or
                        int(masks["c0"][0, 0]))
    _run_all(rec2, tmp_path / "b", frames=(10, 11), refine_pose=True, refine_with="hull", joints="hull",
             bone_lengths="frame")
    assert hulls == [("c0", 10), ("c0", 11)] and [c[2] for c in rec2.calls["refine"]] == [10, 11]
    # the refined pose poses the template at the joints' scale
    body = BODIES["6k"]
    T = _joints(11)[0] + [0, 0.005, 0]
    np.testing.assert_allclose(rec.calls["deform"][1]["V"], body.vertices * (1 + 0.5 * 0.02) + T, atol=1e-12)
    assert writer.json["frames.json"]["frames"][0]["refine_ms"] == 1000.0


def test_given_bone_lengths_and_bad_settings(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    L = np.linspace(0.1, 0.5, 25)
    _s, writer = _run_all(rec, tmp_path, frames=(10,), bone_lengths=list(L))
    np.testing.assert_array_equal(rec.calls["with_lengths"][0][1], L)
    assert writer.meta["bone_lengths"] == "given" and rec.calls["seq_lengths"] == []
    with pytest.raises(InputError, match=r"^bone lengths: need one per Kinect v2 joint \(25\), got shape \(24,\)$"):
        _run_all(rec, tmp_path / "b", frames=(10,), bone_lengths=np.ones(24))
    with pytest.raises(InputError, match=r"^unknown bone lengths 'median'; valid: frame, sequence$"):
        _run_all(rec, tmp_path / "c", frames=(10,), bone_lengths="median")
    with pytest.raises(InputError, match=r"^unknown pose refinement data 'depth'; valid: fields, hull$"):
        _run_all(rec, tmp_path / "d", frames=(10,), refine_with="depth")


def test_posed_cotangents_per_frame(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    _s, writer = _run_all(rec, tmp_path, frames=(10, 11), rest_cotangents=False, bone_lengths="frame")
    for d in rec.calls["deform"]:
        assert d["delta"] == ("cot", float(np.sum(d["reference"])))
    assert writer.meta["rest_cotangents"] is False


def test_the_frames_defaults(monkeypatch, tmp_path):
    """Positional call (a batch chunk's): no tracking, the run's bone lengths, rest cotangents, verdicts accepted."""
    rec = _recording(monkeypatch, verdict={"ok": False, "warnings": [], "problems": ["p"]})
    writer = Writer(tmp_path)
    seq.reconstruct_frames(_session(), writer, [10, 11], [NS(name="c0")], NS(depth="d"),
                           RapidSkinParams(outer_iterations=5), "gs", "6k", "tracker", None, False, False, False,
                           False)
    assert writer.meta["tracking"] is False and writer.meta["track_params"] is None
    assert writer.meta["bone_lengths"] == "sequence" and len(rec.calls["seq_lengths"]) == 1
    assert writer.meta["rest_cotangents"] is True and writer.meta["refine_with"] == "fields"
    assert writer.meta["joint_smoothing"] == 0 and rec.calls["smooth"] == []
    assert rec.calls["fields"] == [] and rec.calls["build"] == ["6k"]


def test_summary_of_scored_records():
    records = [
        {"ms_per_frame": 10.0, "solver_ms": 4.0, "matching_ms": 2.0, "init_ms": 1.0, "refine_ms": 3.0, "frame_ms": 20.0,
         "read_ms": 1.0, "fields_ms": 2.0, "track_ms": 3.0, "other_ms": 4.0, "track": "tracked",
         "metrics": {"visible_median_mm": 2.0, "visible_p90_mm": 6.0, "hausdorff_mm": 30.0, "pct_under_10mm": 90.0,
                     "iou_min": 0.9, "median_mm": 3.0, "p90_mm": 8.0, "joint_error_mm": 40.0}},
        {"ms_per_frame": 20.0, "solver_ms": 6.0, "matching_ms": 4.0, "frame_ms": 30.0, "read_ms": 3.0,
         "fields_ms": 4.0, "track_ms": 5.0, "other_ms": 6.0, "track": "first",
         "metrics": {"visible_median_mm": 4.0, "visible_p90_mm": 10.0, "hausdorff_mm": 50.0, "pct_under_10mm": 70.0,
                     "iou_min": 0.8, "median_mm": 5.0, "p90_mm": 12.0}},
        {"ms_per_frame": 30.0, "solver_ms": 8.0, "matching_ms": 6.0, "init_ms": 5.0, "refine_ms": 6.0,
         "frame_ms": 40.0, "fields_ms": 6.0, "track_ms": 7.0, "other_ms": 8.0, "track": "tracked", "metrics": None},
    ]
    out = seq.summarize(records)
    assert out == {"frames": 3, "ms_per_frame": 20.0, "solver_ms": 6.0, "matching_ms": 4.0, "init_ms": 2.0,
                   "refine_ms": 3.0, "frame_ms": 30.0, "fields_ms": 4.0, "track_ms": 5.0, "other_ms": 6.0,
                   "n_tracked": 2, "median_mm": 3.0, "p90_mm": 8.0, "hausdorff_mm": 50.0, "pct_under_10mm": 80.0,
                   "iou_min": 0.8, "median_all_mm": 4.0, "p90_all_mm": 10.0, "init_joint_error_mm": 40.0}
    assert all(type(v) is float for k, v in out.items() if k not in ("frames", "n_tracked"))
    # read_ms is missing in one record: left out; no joint errors: no init_joint_error_mm
    records[1]["metrics"].pop("visible_median_mm")
    records[0]["metrics"].pop("joint_error_mm")
    with pytest.raises(KeyError):
        seq.summarize(records)
    records[1]["metrics"]["visible_median_mm"] = 4.0
    assert "init_joint_error_mm" not in seq.summarize(records)


def test_tracking_with_hull_joints_checks_no_joint_jump(monkeypatch, tmp_path):
    rec = _recording(monkeypatch)
    _s, writer = _run_all(rec, tmp_path, frames=(10, 11), joints="hull", tracking=True,
                          track_params=TrackParams(outside_px=OUTSIDE_PX), bone_lengths="frame")
    frames = writer.json["frames.json"]["frames"]
    assert [f["track"] for f in frames] == ["first", "tracked"]
    assert [f["track_check"]["joint_jump_m"] for f in frames] == [0.0, 0.0]


def test_refinement_fields_without_tracking_are_exact(monkeypatch, tmp_path):
    rec = _stand_ins(monkeypatch)
    _run(rec, tmp_path, tracking=False, refine_pose=True, frames=FRAMES[:2])
    assert rec.calls["fields_kw"] in ([{}, {}], [{"exact": True}, {"exact": True}])
