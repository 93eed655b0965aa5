"""rec15g's smoothing guard in :func:`bodystudio.reconstruct.sequence.reconstruct_frames` on stand-ins (issue 17).

The stand-in run of ``test_sequence_tracked_mutants.py`` (every heavy step replaced by a closed-form one) with a
joints folder (``--joints file``), time smoothing (the stand-in smoothing lifts the joints 0.02 m in z), the run's
bone lengths (the stand-in adds 2 mm in y) and an outside fraction read from a table per frame. Three frames sit
on the switch's edges: smoothed outside share exactly ``(1 + g) e_raw + 1e-4`` (kept), exactly ``(1 + g) e_raw``
(kept) and far above (the frame's own joints). Also the guard's range, its error names and the run.json record.
Each test < 1 s.
"""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.reconstruct.sequence as seq
from bodystudio.errors import InputError
from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams
from tests.reconstruct.test_sequence_tracked_mutants import BODIES, NAMES, SK, Writer, _session, _stand_ins

FRAMES = [10, 11, 12]
GUARD = 0.5
E_RAW = 0.25
#: the smoothed joints' outside share per frame: on the strict edge, on the tolerance, far above
E_SMOOTH = {10: (1.0 + GUARD) * E_RAW + 1e-4, 11: (1.0 + GUARD) * E_RAW, 12: 0.5}
KEPT = {10: "smoothed", 11: "smoothed", 12: "raw"}
OUTSIDE_PX = 3.5


def _file_joints(fid):
    """The joints folder's frame (not the session's tracker joints): a per-frame lift in x."""
    return SK + [0.001 * fid, 0.0, 0.0]


def _joints_dir(tmp_path):
    d = tmp_path / "joints"
    d.mkdir(parents=True, exist_ok=True)
    for fid in FRAMES:
        (d / f"{fid:05d}.json").write_text(json.dumps({"names": list(NAMES), "positions": _file_joints(fid).tolist()}))
    return d


def _guard_stand_ins(monkeypatch):
    rec = _stand_ins(monkeypatch)
    rec.outside = []

    def outside_fraction(V, fields, outside_px=2.0):
        k = len(rec.outside)
        rec.outside.append((np.array(V), fields.fid, outside_px))
        return E_SMOOTH[fields.fid] if k % 2 == 0 else E_RAW  # the guard asks (smoothed, raw) per frame

    monkeypatch.setattr(seq, "outside_fraction", outside_fraction)
    return rec


def _run(rec, tmp_path, joints_path, **kw):
    writer = Writer(tmp_path)
    kw = {"joint_smoothing": 2, "bone_lengths": "sequence", **kw}
    seq.reconstruct_frames(_session(), writer, list(FRAMES), [NS(name="c0")], NS(depth="depth-camera"),
                           RapidSkinParams(outer_iterations=2), "gs", "6k", "file", joints_path, False, True, False,
                           False, tracking=False, track_params=TrackParams(outside_px=OUTSIDE_PX),
                           refine_with="fields", **kw)
    return writer.json["frames.json"]["frames"], writer.meta


def _posed(J):
    """The stand-in pose of the refinement's template from joints ``J`` (a translation and a scale)."""
    scale = 1.0 + 0.5 * (J[0, 0] - SK[0, 0])
    return BODIES["2k"].vertices * scale + J[0]


@pytest.mark.parametrize("path_type", [str, Path])
def test_guard_compares_the_smoothed_and_the_frames_own_joints_with_bone_lengths(monkeypatch, tmp_path, path_type):
    rec = _guard_stand_ins(monkeypatch)
    frames, meta = _run(rec, tmp_path, path_type(_joints_dir(tmp_path)), smoothing_guard=GUARD)
    lift_len = np.array([0.0, 0.002, 0.0])  # the stand-in's bone lengths
    lift_smooth = np.array([0.0, 0.0, 0.02])  # the stand-in's smoothing, half window 2
    assert [f["smoothing_outside"] for f in frames] == [[E_RAW, E_SMOOTH[fid]] for fid in FRAMES]
    assert len(rec.outside) == 2 * len(FRAMES)
    for k, fid in enumerate(FRAMES):
        raw = _file_joints(fid) + lift_len
        smooth = _file_joints(fid) + lift_smooth + lift_len
        (V_s, fid_s, px_s), (V_r, fid_r, px_r) = rec.outside[2 * k], rec.outside[2 * k + 1]
        assert fid_s == fid_r == fid and px_s == px_r == OUTSIDE_PX
        np.testing.assert_allclose(V_s, _posed(smooth), atol=1e-12)
        np.testing.assert_allclose(V_r, _posed(raw), atol=1e-12)
    # every bone-length call got the run's lengths (the smoothed joints' and the raw ones')
    assert rec.calls["with_lengths"]
    for _J, lengths in rec.calls["with_lengths"]:
        np.testing.assert_array_equal(lengths, np.full(25, 0.3))
    # the template is posed from the joints the switch kept
    starts = [J for body, J, _rest in rec.calls["init"] if body is BODIES["6k"]]
    assert len(starts) == len(FRAMES)
    for J, fid in zip(starts, FRAMES, strict=True):
        want = _file_joints(fid) + lift_len + (lift_smooth if KEPT[fid] == "smoothed" else 0.0)
        np.testing.assert_allclose(J, want, atol=1e-12)
    assert meta["smoothing_guard"] == GUARD and meta["refine_depth_guard"] == 0.0


def test_no_guard_by_default_and_both_guards_recorded(monkeypatch, tmp_path):
    rec = _guard_stand_ins(monkeypatch)
    frames, meta = _run(rec, tmp_path, _joints_dir(tmp_path))
    assert rec.outside == [] and all("smoothing_outside" not in f for f in frames)
    assert meta["smoothing_guard"] == 0.0 and meta["refine_depth_guard"] == 0.0
    rec = _guard_stand_ins(monkeypatch)
    _frames, meta = _run(rec, tmp_path / "b", _joints_dir(tmp_path), refine_depth_guard=0.25, smoothing_guard=10.0)
    assert meta["refine_depth_guard"] == 0.25 and meta["smoothing_guard"] == 10.0
    assert type(meta["refine_depth_guard"]) is float and type(meta["smoothing_guard"]) is float


@pytest.mark.parametrize("name", ["smoothing_guard", "refine_depth_guard"])
@pytest.mark.parametrize("bad", [-0.1, float("nan"), 10.5])
def test_bad_guard_names_itself(monkeypatch, tmp_path, name, bad):
    rec = _guard_stand_ins(monkeypatch)
    with pytest.raises(InputError, match=rf"^{name} .*give a relative tolerance in \[0, 10\]"):
        _run(rec, tmp_path, _joints_dir(tmp_path), **{name: bad})
