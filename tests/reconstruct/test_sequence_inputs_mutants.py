"""``reconstruct.sequence``'s input readers and the run's verdict in closed form (issue 17).

``--frames`` parsing (every form, every refusal's exact line), Kinect v1 / v2 joint names to the v2 array, a frame's
joints from the tracker or a folder of files (each refusal's line, the person-size span check) and one set of bone
lengths per run; the self-check verdict refused, accepted and logged. Tiny inputs, < 1 s.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.reconstruct.sequence as seq
from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import FileFormatError, ImplausibleResultError, InputError, SessionError

V2 = kinect_joint_names("v2")
IDS = [3, 4, 5, 6, 7, 8]


@pytest.mark.parametrize("text, expected", [(None, IDS), ("", IDS), ("4:6", [4, 5]), (":5", [3, 4]), ("6:", [6, 7, 8]),
                                            ("5", [5]), ("3:9", IDS), (" 4 : 6 ", [4, 5]), ("8", [8]), ("3", [3])])
def test_parse_frames_selects(text, expected):
    got = seq.parse_frames(text, IDS)
    assert got == expected and type(got) is list
    assert got is not IDS


@pytest.mark.parametrize("text, message", [
    ("a:b", "--frames 'a:b' must be A:B (B exclusive) or a single frame number"),
    ("x", "--frames 'x' must be A:B (B exclusive) or a single frame number"),
    ("1:2:3", "--frames '1:2:3' must be A:B (B exclusive) or a single frame number"),
    ("5:5", "--frames '5:5': A must be below B (B exclusive), e.g. 3:9"),
    ("6:4", "--frames '6:4': A must be below B (B exclusive), e.g. 3:9"),
    ("2:5", "--frames '2:5' reaches outside the session, which has 6 frames (3:9); give a range within 3:9"),
    ("4:10", "--frames '4:10' reaches outside the session, which has 6 frames (3:9); give a range within 3:9"),
    ("9", "--frames '9' reaches outside the session, which has 6 frames (3:9); give a range within 3:9"),
    ("2", "--frames '2' reaches outside the session, which has 6 frames (3:9); give a range within 3:9"),
])
def test_parse_frames_refuses(text, message):
    with pytest.raises(InputError) as err:
        seq.parse_frames(text, IDS)
    assert str(err.value) == message


def test_parse_frames_in_a_gap_selects_no_frame():
    with pytest.raises(InputError) as err:
        seq.parse_frames("5:7", [3, 4, 7, 8])
    assert str(err.value) == "--frames '5:7' selects no frame; the session has frames 3..8"
    assert seq.parse_frames("4:8", [3, 4, 7, 8]) == [4, 7]


def test_joints_v2_maps_v1_names_and_untracked_joints():
    names = ["HipCenter", "Spine", "ShoulderCenter", "Head", "HandLeft"]
    P = np.arange(15.0).reshape(5, 3) / 10
    flat = P.ravel().tolist()
    J = seq.joints_v2(names, flat, [True, True, True, False, True])
    assert J.shape == (25, 3) and J.dtype == np.float64
    for name, row in (("SpineBase", 0), ("SpineMid", 1), ("SpineShoulder", 2), ("HandLeft", 4)):
        np.testing.assert_array_equal(J[V2.index(name)], P[row])
    assert np.isnan(J[V2.index("Head")]).all()
    assert np.isnan(np.delete(J, [V2.index(n) for n in ("SpineBase", "SpineMid", "SpineShoulder", "HandLeft")],
                              axis=0)).all()
    # without tracked flags every joint given is kept; the input is not written to
    P2 = P.copy()
    J2 = seq.joints_v2(names, P2)
    np.testing.assert_array_equal(J2[V2.index("Head")], P[3])
    np.testing.assert_array_equal(P2, P)
    seq.joints_v2(names, P2, np.array([1, 1, 1, 0, 1]))
    np.testing.assert_array_equal(P2, P)
    # integer positions (a JSON of whole numbers) and 0 / 1 flags: read as floats and as booleans
    J3 = seq.joints_v2(names, [[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11], [1, 1, 1]], [1, 1, 1, 0, 1])
    assert np.isnan(J3[V2.index("Head")]).all()
    np.testing.assert_array_equal(J3[V2.index("HandLeft")], [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(J3[V2.index("SpineShoulder")], [6.0, 7.0, 8.0])


def _skeleton(scale=1.0):
    return (np.random.default_rng(1).uniform(-0.4, 0.4, (25, 3)) + [0, 1, 0]) * scale


def _frame(fid, joints=None):
    data = None if joints is None else {"names": list(V2), "positions": joints.tolist(), "tracked": [True] * 25}
    return NS(frame_id=fid, kinect_joints=data)


SESSION = NS(path=Path("/s"))


def test_frame_joints_from_the_tracker_and_its_refusals():
    S = _skeleton()
    np.testing.assert_array_equal(seq.frame_joints(SESSION, _frame(4, S), "tracker", None), S)
    untracked = _frame(4, S)
    untracked.kinect_joints["tracked"][5] = False
    J = seq.frame_joints(SESSION, untracked, "tracker", None)
    assert np.isnan(J[5]).all() and np.isfinite(np.delete(J, 5, axis=0)).all()
    with pytest.raises(SessionError) as err:
        seq.frame_joints(SESSION, _frame(4), "tracker", None)
    assert str(err.value) == "/s frame 4: no Kinect tracker joints; use --joints file --joints-path DIR"
    few = S.copy()
    few[2:] = np.nan
    with pytest.raises(InputError) as err:
        seq.frame_joints(SESSION, _frame(4, few), "tracker", None)
    assert str(err.value) == "/s frame 4: no valid joints (fewer than 3 tracked); check the tracker output"
    three = S.copy()
    three[3:] = np.nan
    np.testing.assert_array_equal(seq.frame_joints(SESSION, _frame(4, three), "tracker", None)[:3], S[:3])
    with pytest.raises(InputError) as err:
        seq.frame_joints(SESSION, _frame(4, S), "depth", None)
    assert str(err.value) == "unknown joint source 'depth'; valid: tracker, file, hull"


def test_frame_joints_span_of_a_person():
    line = np.full((25, 3), np.nan)
    line[0], line[1], line[2] = [0, 0, 0], [0, 3.5, 0], [0, 1.0, 0]
    np.testing.assert_array_equal(seq.frame_joints(SESSION, _frame(4, line), "tracker", None)[1], [0, 3.5, 0])
    line[1] = [0, 3.5001, 0]
    with pytest.raises(InputError) as err:
        seq.frame_joints(SESSION, _frame(4, line), "tracker", None)
    assert str(err.value) == ("/s frame 4: the joints span 3.5 m, more than a person (3.5 m); give positions in "
                              "metres in the studio's world frame")
    # the span is the largest distance between any two joints (not from the first one)
    line[0], line[1], line[2] = [0, 1.0, 0], [0, 2.9, 0], [0, -0.7, 0]
    with pytest.raises(InputError, match="the joints span 3.6 m"):
        seq.frame_joints(SESSION, _frame(4, line), "tracker", None)


def test_frame_joints_from_files_and_their_refusals(tmp_path):
    S = _skeleton()
    (tmp_path / "00007.json").write_text(json.dumps({"names": list(V2), "positions": S.tolist()}))
    np.testing.assert_allclose(seq.frame_joints(SESSION, _frame(7), "file", tmp_path), S, atol=1e-15)
    np.testing.assert_allclose(seq.frame_joints(SESSION, _frame(7), "file", str(tmp_path)), S, atol=1e-15)
    tracked = [True] * 24 + [False]
    (tmp_path / "00008.json").write_text(json.dumps({"names": list(V2), "positions": S.tolist(), "tracked": tracked}))
    J = seq.frame_joints(SESSION, _frame(8), "file", tmp_path)
    assert np.isnan(J[24]).all() and np.isfinite(J[:24]).all()
    with pytest.raises(InputError) as err:
        seq.frame_joints(SESSION, _frame(7), "file", None)
    assert str(err.value) == "--joints file needs --joints-path DIR with NNNNN.json files ({names, positions})"
    (tmp_path / "00009.json").write_text(json.dumps({"names": list(V2)}))
    with pytest.raises(InputError) as err:
        seq.frame_joints(SESSION, _frame(9), "file", tmp_path)
    assert str(err.value) == f"{tmp_path}/00009.json: needs names and positions ('positions')"
    (tmp_path / "00010.json").write_text(json.dumps({"names": list(V2), "positions": [[0, 1]] * 25}))
    with pytest.raises(InputError, match=r"^.*/00010\.json: needs names and positions \(cannot reshape"):
        seq.frame_joints(SESSION, _frame(10), "file", tmp_path)
    with pytest.raises(FileFormatError, match=r"00011\.json: joints file not found"):
        seq.frame_joints(SESSION, _frame(11), "file", tmp_path)
    (tmp_path / "00012.json").write_text(json.dumps({"names": list(V2), "positions": (S * 1000).tolist()}))
    with pytest.raises(InputError) as err:
        seq.frame_joints(SESSION, _frame(12), "file", tmp_path)
    assert str(err.value).startswith(f"{tmp_path}/00012.json: the joints span ")


def test_run_bone_lengths_are_the_sequences(monkeypatch, tmp_path):
    got = []
    monkeypatch.setattr(seq, "sequence_bone_lengths", lambda frames: got.append(frames) or "lengths")
    frames = {4: _skeleton(1.0), 5: _skeleton(1.1)}
    session = NS(path=Path("/s"), frame=lambda f: _frame(f, frames[f]))
    assert seq.run_bone_lengths(session, [4, 5], "tracker", None) == "lengths"
    (frames_of,) = got
    assert len(frames_of) == 2
    np.testing.assert_array_equal(frames_of[1], frames[5])
    for f in (4, 5):
        data = {"names": list(V2), "positions": (frames[f] + 0.1).tolist()}
        (tmp_path / f"{f:05d}.json").write_text(json.dumps(data))
    seq.run_bone_lengths(session, [5], "file", str(tmp_path))
    np.testing.assert_allclose(got[1][0], frames[5] + 0.1, atol=1e-15)


def test_judge_run_refuses_accepts_and_logs(monkeypatch, caplog):
    verdicts = []

    def run_check(frames, path):
        verdicts.append((frames, path))
        return dict(result)

    monkeypatch.setattr(seq, "run_plausibility", run_check)
    records = [{"plausibility": {"a": 1}}, {"plausibility": None}, {}, {"plausibility": {"b": 2}}]
    result = {"ok": True, "warnings": ["masks noisy"], "problems": []}
    with caplog.at_level(logging.WARNING, logger="bodystudio.reconstruct.sequence"):
        out = seq.judge_run(records, Path("/s"), False)
    assert out == result and verdicts[-1] == ([{"a": 1}, {"b": 2}], Path("/s"))
    assert [r.getMessage() for r in caplog.records] == ["/s: masks noisy"]
    assert all(r.levelno == logging.WARNING for r in caplog.records)
    result = {"ok": False, "warnings": ["w"], "problems": ["camera c1 moved", "second"]}
    with pytest.raises(ImplausibleResultError) as err:
        seq.judge_run(records, Path("/s"), False)
    assert str(err.value) == "/s: reconstruction not written, camera c1 moved; or pass --accept-implausible"
    caplog.records.clear()
    with caplog.at_level(logging.WARNING, logger="bodystudio.reconstruct.sequence"):
        assert seq.judge_run(records, Path("/s"), True) == result
    assert [r.getMessage() for r in caplog.records] == ["/s: w", "/s: camera c1 moved", "/s: second"]


# --- the session entry, the run folder's layout, the ground-truth joints and a frame's scores (stand-ins) -----------

def _session_stand_in(monkeypatch, cams=("c0", "c1"), manifest_cams=None, kinect="sensor", ids=(3, 4, 5)):
    import bodystudio.capture.session as session_mod

    calls = {}
    session = NS(path=Path("/s"), cameras=[NS(name=c) for c in cams],
                 camera_names=list(manifest_cams or cams), frame_ids=list(ids), kinect=kinect,
                 frame=lambda f: NS(kinect_joints=None))  # nobody tracked: rel5's run subject of no one

    def open_session(path):
        calls["open"] = path
        return session

    class Writer:
        def __init__(self, layout, command, meta):
            calls["writer"] = (layout, command, meta)

        def __enter__(self):
            return "writer"

        def __exit__(self, *exc):
            return False

    def frames(*args, **kw):
        calls["frames"] = (args, kw)
        return {"summary": 1}

    monkeypatch.setattr(session_mod, "open_session", open_session)
    monkeypatch.setattr(seq, "RunWriter", Writer)
    monkeypatch.setattr(seq, "reconstruct_frames", frames)
    return calls, session


def test_reconstruct_session_forwards_every_setting(monkeypatch):
    from bodystudio.reconstruct.articulated_fit import PoseRefineParams
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.tracking import TrackParams

    calls, session = _session_stand_in(monkeypatch)
    tp, rp = TrackParams(iterations=4), PoseRefineParams(iterations=2)
    out = seq.reconstruct_session("/in", solver="cg", template="2k", joints="file", constraints=("silhouette", "depth"),
                                  frames="4:6", joints_path="/j", warm_start=True, refine_pose=False, score=False,
                                  progress=True, tracking=True, track_params=tp, refine_with="hull",
                                  rest_cotangents=False, refine_params=rp, bone_lengths="frame", joint_smoothing=3,
                                  accept_implausible=True, refine_depth=2.0, refine_depth_bones="all",
                                  refine_depth_guard=0.1, smoothing_guard=0.2)
    assert out == {"summary": 1} and calls["open"] == "/in"
    layout, command, meta = calls["writer"]
    assert layout == seq.reconstruction_layout(Path("/s")) and command == "bodystudio reconstruct"
    assert meta == {"session": "/s", "template": "2k"}
    args, kw = calls["frames"]
    assert args[0] is session and args[1] == "writer" and args[2] == [4, 5]
    assert [c.name for c in args[3]] == ["c0", "c1"] and args[4] == "sensor"
    assert args[5] == RapidSkinParams(solver="cg", constraints=("silhouette", "depth"))
    assert args[6:] == ("cg", "2k", "file", "/j", True, False, False, True)
    newer = ("shape_prior", "refine_depth", "smoothing_guard", "subject")  # issue 15's later keywords, rel5's
    assert {k: v for k, v in kw.items() if not k.startswith(newer)} == dict(
        tracking=True, track_params=tp, refine_with="hull", rest_cotangents=False, refine_params=rp,
        bone_lengths="frame", joint_smoothing=3, accept_implausible=True)
    assert {k: v for k, v in kw.items() if k.startswith(("refine_depth", "smoothing_guard"))} == dict(
        refine_depth=2.0, refine_depth_bones="all", refine_depth_guard=0.1, smoothing_guard=0.2)


def test_reconstruct_session_defaults_and_given_params(monkeypatch):
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams

    calls, session = _session_stand_in(monkeypatch)
    seq.reconstruct_session("/in")
    args, kw = calls["frames"]
    assert args[2] == [3, 4, 5] and args[5] == RapidSkinParams(solver="gs", constraints=("silhouette",))
    assert args[6:] == ("gs", "13k", "tracker", None, False, True, True, False)
    newer = ("shape_prior", "refine_depth", "smoothing_guard", "subject")  # issue 15's later keywords, rel5's
    assert {k: v for k, v in kw.items() if not k.startswith(newer)} == dict(
        tracking=False, track_params=None, refine_with="fields", rest_cotangents=True, refine_params=None,
        bone_lengths="sequence", joint_smoothing=0, accept_implausible=False)
    assert {k: v for k, v in kw.items() if k.startswith(("refine_depth", "smoothing_guard"))} == dict(
        refine_depth=0.0, refine_depth_bones="neck", refine_depth_guard=0.0, smoothing_guard=0.0)
    assert {k: v for k, v in kw.items() if k.startswith("shape_prior")} in (
        {}, {"shape_prior": "auto", "shape_prior_outer": 0, "shape_prior_first_outer": 0, "shape_prior_region": None,
             "shape_prior_reach": None})
    assert calls["writer"][2] == {"session": "/s", "template": "13k"}
    mine = RapidSkinParams(outer_iterations=2)
    seq.reconstruct_session("/in", params=mine, solver="cg")
    assert calls["frames"][0][5] is mine and calls["frames"][0][6] == "cg"


@pytest.mark.parametrize("kw, error, message", [
    (dict(template="9k"), InputError, "unknown template '9k'; valid: 13k, 6k, 2k"),
    (dict(joints="imu"), InputError, "unknown joint source 'imu'; valid: tracker, file, hull"),
    (dict(joints="file"), InputError,
     "--joints file needs --joints-path DIR with NNNNN.json files ({names, positions})"),
    (dict(constraints=("silhouette", "depth"), kinect=None), SessionError,
     "/s: no Kinect calibration, so no depth constraints; use --constraints silhouette"),
    (dict(manifest_cams=("c0", "c2")), SessionError,
     "/s: the manifest lists cameras c0, c2 but calibration/cameras.json has c0, c1; camera/session mismatch"),
])
def test_reconstruct_session_refusals(monkeypatch, kw, error, message):
    kw = dict(kw)  # the case's own dict is not written to (the direct recheck runs each case twice)
    calls, _ = _session_stand_in(monkeypatch, manifest_cams=kw.pop("manifest_cams", None),
                                 kinect=kw.pop("kinect", "sensor"))
    with pytest.raises(error) as err:
        seq.reconstruct_session("/in", **kw)
    assert str(err.value) == message
    assert "frames" not in calls and "writer" not in calls


def test_every_template_name_and_the_file_source_with_a_folder(monkeypatch):
    calls, _ = _session_stand_in(monkeypatch)
    for t in ("13k", "6k", "2k", "full", "2.5k"):
        seq.reconstruct_session("/in", template=t)
        assert calls["frames"][0][7] == t
    seq.reconstruct_session("/in", joints="file", joints_path="/j")
    seq.reconstruct_session("/in", joints="hull")
    seq.reconstruct_session("/in", constraints=("depth",))
    assert calls["frames"][0][5].constraints == ("depth",)


def test_reconstruction_layout():
    from bodystudio.runfolder import RunLayout

    layout = seq.reconstruction_layout("/s")
    assert layout == RunLayout(Path("/s/reconstruct"), "run.json", ".", "/s/reconstruct")


def test_gt_kinect_joints_from_the_posed_skeleton(monkeypatch):
    from bodystudio.body.skeleton import Skeleton

    got = []

    def kj(sk, heads, tails, version):
        got.append((sk, heads, tails, version))
        return "joints"

    monkeypatch.setattr(seq, "kinect_joints", kj)
    heads, tails = np.zeros((2, 3)), np.ones((2, 3))
    frame = NS(gt_joints={"bone_names": ["pelvis", "spine_01"], "heads": heads, "tails": tails})
    assert seq.gt_kinect_joints(frame, None) == "joints"
    sk, h, t, version = got[0]
    assert isinstance(sk, Skeleton) and sk.bone_names == ("pelvis", "spine_01") and version == "v2"
    np.testing.assert_array_equal(sk.parents, [-1, -1])
    np.testing.assert_array_equal(sk.rolls, [0.0, 0.0])
    assert sk.heads is heads and sk.tails is tails and h is heads and t is tails
    assert seq.gt_kinect_joints(NS(gt_joints=None), None) is None

    def missing(*a):
        raise InputError("no such bone")

    monkeypatch.setattr(seq, "kinect_joints", missing)
    assert seq.gt_kinect_joints(frame, None) is None


def test_score_frame_against_the_ground_truth(monkeypatch):
    calls = {}
    gt = NS(vertices="GV", faces="GF")
    cams = [NS(name="c0"), NS(name="c1")]

    def visible(V, F, cameras):
        calls["visible"] = (V, F, cameras)
        return "vis"

    def surface(V, F, GV, GF, vis):
        calls["surface"] = (V, F, GV, GF, vis)
        return NS(as_dict=lambda: {"visible_median_mm": 1.0})

    def iou(V, F, cameras, masks):
        calls["iou"] = (V, F, cameras, masks)
        return {"c0": 0.9, "c1": 0.7}

    monkeypatch.setattr(seq, "visible_vertices", visible)
    monkeypatch.setattr(seq, "surface_error", surface)
    monkeypatch.setattr(seq, "silhouette_iou", iou)
    monkeypatch.setattr(seq, "region_errors", lambda V, GV, GF, regions: ("regions", V, GV, GF, regions))
    monkeypatch.setattr(seq, "gt_kinect_joints", lambda frame, names: None if frame.no_gt_joints else "GJ")
    monkeypatch.setattr(seq, "joint_error_mm", lambda J, gtj: ("je", J, gtj))
    frame = NS(gt_mesh=gt, session=NS(streams={"gt_mask", "mask"}), gt_masks={"c0": "g0", "c1": "g1", "c2": "g2"},
               masks={"c0": "m0", "c1": "m1"}, no_gt_joints=False)
    out = seq.score_frame("V", "F", frame, cams, regions="R", joints="J")
    assert out == {"visible_median_mm": 1.0, "iou": {"c0": 0.9, "c1": 0.7}, "iou_min": 0.7,
                   "regions": ("regions", "V", "GV", "GF", "R"), "joint_error_mm": ("je", "J", "GJ")}
    assert calls["visible"] == ("GV", "GF", cams) and calls["surface"] == ("V", "F", "GV", "GF", "vis")
    assert calls["iou"] == ("V", "F", cams, {"c0": "g0", "c1": "g1"})
    # without ground-truth masks the fitted masks; no regions, no joints, no GT joints: those keys left out
    frame.session.streams = {"mask"}
    frame.no_gt_joints = True
    out = seq.score_frame("V", "F", frame, cams, joints="J")
    assert calls["iou"][3] == {"c0": "m0", "c1": "m1"}
    assert set(out) == {"visible_median_mm", "iou", "iou_min"}
    assert seq.score_frame("V", "F", NS(gt_mesh=None), cams) is None


def _run_folder(tmp_path, run, frames=None):
    out = tmp_path / "reconstruct"
    (out / "meshes").mkdir(parents=True)
    if run is not None:
        (out / "run.json").write_text(json.dumps(run))
    if frames is not None:
        (out / "frames.json").write_text(json.dumps({"frames": frames}))
    return out


def _checks(monkeypatch):
    calls = {"readable": [], "verify": []}
    monkeypatch.setattr(seq, "check_readable", lambda layout: calls["readable"].append(layout))
    monkeypatch.setattr(seq, "verify_run_files", lambda layout, run, only: calls["verify"].append((layout, run, only)))
    return calls


def test_read_reconstruction_checks_the_folder_and_lists_the_meshes(monkeypatch, tmp_path):
    calls = _checks(monkeypatch)
    files = {"frames.json": "h", "meshes/00003.ply": "h", "meshes/00005.ply": "h"}
    run = {"frames": [3, "4", 5], "n_vertices": 4, "run": {"files": files}}
    out = _run_folder(tmp_path, run)
    got, meshes = seq.read_reconstruction(tmp_path)
    assert got == run and meshes == {3: out / "meshes/00003.ply", 5: out / "meshes/00005.ply"}
    layout = seq.reconstruction_layout(tmp_path)
    assert calls["readable"] == [layout] and calls["verify"] == [(layout, run["run"], None)]
    seq.read_reconstruction(tmp_path, frame=5)
    assert calls["verify"][-1] == (layout, run["run"], ("frames.json", "meshes/00005.ply"))
    seq.read_reconstruction(str(tmp_path), frame=0)
    assert calls["verify"][-1][2] == ("frames.json", "meshes/00000.ply")


@pytest.mark.parametrize("run, message", [
    (None, "{m}: missing (a reconstruction by an older bodystudio, or files copied in by hand); re-run "
           "`bodystudio reconstruct {s}`"),
    ([1, 2], "{m}: not a reconstruction run record; re-run reconstruct"),
    ({"frames": "3", "n_vertices": 4}, "{m}: not a reconstruction run record; re-run reconstruct"),
    ({"frames": [3]}, "{m}: not a reconstruction run record; re-run reconstruct"),
    ({"n_vertices": 4}, "{m}: not a reconstruction run record; re-run reconstruct"),
])
def test_read_reconstruction_refusals(monkeypatch, tmp_path, run, message):
    calls = _checks(monkeypatch)
    _run_folder(tmp_path, run)
    with pytest.raises(SessionError) as err:
        seq.read_reconstruction(tmp_path)
    assert str(err.value) == message.format(m=tmp_path / "reconstruct" / "run.json", s=tmp_path)
    assert len(calls["readable"]) == 1 and calls["verify"] == []


def _evaluate_stand_ins(monkeypatch, tmp_path, n_vertices=4, gt=True):
    import bodystudio.capture.session as session_mod

    calls = _checks(monkeypatch)
    calls["score"], calls["load"] = [], []
    session = NS(path=tmp_path, cameras=(NS(name="c0"),),
                 frame=lambda f: NS(frame_id=f, gt_mesh="GT" if gt else None))
    calls["opened"] = []
    monkeypatch.setattr(session_mod, "open_session", lambda path: calls["opened"].append(path) or session)
    monkeypatch.setattr(seq, "read_reconstruction", lambda path: calls.setdefault("read", path) and
                        ({"n_vertices": 4, "template": "2k"}, {}))

    def load(path):
        calls["load"].append(path)
        return NS(vertices=np.zeros((n_vertices, 3)), faces="F")

    def score(V, F, frame, cameras):
        calls["score"].append((len(V), F, frame.frame_id, cameras))
        return {"visible_median_mm": float(frame.frame_id), "visible_p90_mm": 2.0, "hausdorff_mm": 3.0,
                "pct_under_10mm": 4.0, "iou_min": 0.5, "median_mm": 5.0, "p90_mm": 6.0}

    monkeypatch.setattr(seq, "load_mesh", load)
    monkeypatch.setattr(seq, "score_frame", score)
    return calls


def _record(fid):
    return {"frame": fid, "ms_per_frame": 1.0, "solver_ms": 2.0, "matching_ms": 3.0, "track": "tracked"}


def test_evaluate_session_scores_each_recorded_mesh(monkeypatch, tmp_path):
    calls = _evaluate_stand_ins(monkeypatch, tmp_path)
    out_dir = _run_folder(tmp_path, {"frames": [3, 5]}, [_record(3), _record(5)])
    out = seq.evaluate_session("/in")
    assert calls["read"] == tmp_path
    assert calls["load"] == [out_dir / "meshes" / "00003.ply", out_dir / "meshes" / "00005.ply"]
    assert [(n, F, f) for n, F, f, _c in calls["score"]] == [(4, "F", 3), (4, "F", 5)]
    assert all(list(c) == [NS(name="c0")] and type(c) is list for *_, c in calls["score"])
    assert out["frames"] == 2 and out["median_mm"] == 4.0 and out["n_tracked"] == 2 and out["solver_ms"] == 2.0
    # frames.json alone (no run.json) is read too
    (out_dir / "run.json").unlink()
    assert seq.evaluate_session("/in")["frames"] == 2


def test_evaluate_session_refusals(monkeypatch, tmp_path):
    calls = _evaluate_stand_ins(monkeypatch, tmp_path)
    out_dir = tmp_path / "reconstruct"
    with pytest.raises(SessionError) as err:
        seq.evaluate_session("/in")
    assert str(err.value) == f"{out_dir}: no reconstruction yet; run `bodystudio reconstruct {tmp_path}` first"
    assert calls["readable"] == [seq.reconstruction_layout(tmp_path)]
    _run_folder(tmp_path, {"frames": [3]}, [_record(3)])
    _evaluate_stand_ins(monkeypatch, tmp_path, n_vertices=5)
    with pytest.raises(SessionError) as err:
        seq.evaluate_session("/in")
    assert str(err.value) == (f"{out_dir / 'meshes' / '00003.ply'}: 5 vertices but run.json says template 2k (4); "
                              "the folder mixes two runs, re-run reconstruct")
    _evaluate_stand_ins(monkeypatch, tmp_path, gt=False)
    with pytest.raises(SessionError) as err:
        seq.evaluate_session("/in")
    assert str(err.value) == f"{tmp_path}: frame 3 has no ground-truth mesh to score against"


def test_malformed_records_are_named_in_the_refusal(monkeypatch, tmp_path):
    _checks(monkeypatch)
    out = _run_folder(tmp_path, None)
    (out / "run.json").write_text("{not json")
    with pytest.raises(FileFormatError, match=r"run\.json: not a valid reconstruction run record \("):
        seq.read_reconstruction(tmp_path)
    calls = _evaluate_stand_ins(monkeypatch, tmp_path)
    (out / "frames.json").write_text("[broken")
    with pytest.raises(FileFormatError, match=r"frames\.json: not a valid reconstruction record \("):
        seq.evaluate_session("/in")
    assert calls["opened"] == ["/in"]
