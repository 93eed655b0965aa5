"""rel7a's bad-frame skipping in ``muscle/capture.py`` against hand-written expectations (mutOO; no capture runs).

``read_arm_frames`` on a stand-in session (20 frames numbered from 100, five bad for five reasons, a frame with
exactly ``min_pixels`` arm pixels), ``check_skipped_frames``' two bounds at their edges and at other frame rates
(the first frames that keep within them found by a brute-force loop written here), ``longest_run``,
``_frame_ranges``, ``ids_at``, ``_frame_problem``, ``every_nth_frame`` with recorded numbers, and the recorded
numbers ``capture_arm_sequence`` hands on (a spy for ``capture_arm_frames``): a planted bug that counts the captured
frames instead of the recorded ones fails here. Runs in well under a second.
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import SessionError

H, W = 20, 30  # 600 pixels; DepthCleanupOptions().min_pixels is 200
IDS = list(range(100, 120))
SIDE = "left"
NAMES = ["ShoulderLeft", "ElbowLeft", "WristLeft", "Head"]


def _arm(fid):
    return np.array([[0.1, 0.2, 0.9], [0.3, 0.1, 0.9], [0.5, 0.0, 0.9]]) + 0.001 * (fid - 100)


def _depth(fid, far=False):
    d = np.full((H, W), 0.9)
    if far or fid == 107:  # the arm out of the 0.5-1.3 m window
        d[:] = 3.0
    elif fid == 113:  # exactly min_pixels (200) in the window: good
        d[:] = 3.0
        d.flat[:200] = 0.9
    elif fid == 105:
        d = np.full((H + 1, W), 0.9)
    return d


class _Frame:
    def __init__(self, session, fid):
        self.session, self.fid = session, fid

    @property
    def kinect_depth_m(self):
        if self.fid == 103:
            raise SessionError(f"{self.session.path}/kinect/depth/00103.png: truncated PNG")
        if self.fid == 111:
            return None
        return self.session.depths.setdefault(self.fid, _depth(self.fid, self.session.far))

    @property
    def kinect_joints(self):
        if not self.session.tracked:
            return None
        positions = np.vstack([_arm(self.fid), [[0.0, 0.5, 1.0]]]).tolist()
        if self.fid == 109:
            positions[1] = [None, None, None]
        return {"names": NAMES, "positions": positions, "tracked": [True] * 4}


class _Session:
    def __init__(self, path="S", tracked=True, height=True, frame_ids=IDS, far=False, fps=None):
        self.path, self.tracked, self.depths, self.far = path, tracked, {}, far
        depth = SimpleNamespace(width=W, height=H) if height else SimpleNamespace()
        self.kinect = SimpleNamespace(depth=depth)
        self.frame_ids = np.asarray(frame_ids)
        self.metadata = {} if fps is None else {"fps": fps}

    def frame(self, fid):
        return _Frame(self, int(fid))


BAD = {103: "truncated PNG", 105: f"depth map is {W}x{H + 1} but the depth camera is {W}x{H}",
       107: "no arm in the 0.5-1.3 m depth window", 109: "the body tracker's ShoulderLeft, ElbowLeft, WristLeft are "
       "missing or null", 111: "no Kinect depth image in this frame"}


def test_read_arm_frames_skips_each_kind_of_bad_frame_and_keeps_the_rest_in_order(caplog):
    from bodystudio.muscle.capture import read_arm_frames

    s = _Session()
    with caplog.at_level(logging.WARNING, logger="bodystudio.muscle.capture"):
        good, depths, tracker, skipped = read_arm_frames(s, IDS, SIDE)
    want_good = [f for f in IDS if f not in BAD]
    assert good == want_good  # 5 of 20 = 25 %: within the bound
    assert len(depths) == len(want_good) and all(d is s.depths[f] for d, f in zip(depths, want_good, strict=True))
    assert tracker.shape == (15, 3, 3)
    np.testing.assert_allclose(tracker, np.stack([_arm(f) for f in want_good]), atol=0)
    joints_file = {109}
    assert skipped == [{"frame": f, "position": f - 100,
                        "file": f"S/kinect/{'joints' if f in joints_file else 'depth'}/{f:05d}."
                                f"{'json' if f in joints_file else 'png'}", "why": BAD[f]} for f in sorted(BAD)]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warned == [f"{s['file']}: frame {s['frame']} skipped: {s['why']}" for s in skipped]


def test_read_arm_frames_without_any_joints_captures_from_the_depth_alone():
    from bodystudio.muscle.capture import read_arm_frames

    good, _, tracker, skipped = read_arm_frames(_Session(tracked=False), IDS, SIDE)
    assert tracker is None
    assert [s["frame"] for s in skipped] == [103, 105, 107, 111]  # 109's null elbow is no problem here
    assert good == [f for f in IDS if f not in (103, 105, 107, 111)]


def test_read_arm_frames_of_a_camera_without_a_size_checks_no_size():
    from bodystudio.muscle.capture import read_arm_frames

    good, _, _, skipped = read_arm_frames(_Session(height=False), IDS, SIDE)
    assert 105 in good and [s["frame"] for s in skipped] == [103, 107, 109, 111]


def test_read_arm_frames_refuses_beyond_the_bounds_without_a_warning(caplog):
    from bodystudio.muscle.capture import read_arm_frames

    with caplog.at_level(logging.WARNING), pytest.raises(SessionError, match=r"bad frames: 5 of 19, more than"):
        read_arm_frames(_Session(), IDS[:19], SIDE)
    assert not [r for r in caplog.records if "skipped" in r.getMessage()]


def _skipped(positions, first_id=0):
    return [{"frame": first_id + p, "position": p, "file": f"S/kinect/depth/{first_id + p:05d}.png", "why": "no arm"}
            for p in positions]


def _brute_keep(positions, n_frames, max_run):
    """The largest n < n_frames whose first n frames end on a good frame, skip <= 25 % and no run > max_run."""
    for n in range(n_frames - 1, 0, -1):
        head = [p for p in positions if p < n]
        run = best = 0
        for k in range(n):
            run = run + 1 if k in head else 0
            best = max(best, run)
        if (n - 1) not in head and 4 * len(head) <= n and best <= max_run:
            return n
    return 0


@pytest.mark.parametrize("fps, max_run", [(30.0, 5), (60.0, 10), (20.0, 3), (24.0, 4), (3.0, 1)])
def test_the_run_bound_at_its_edge_at_each_rate(fps, max_run):
    from bodystudio.muscle.capture import check_skipped_frames

    check_skipped_frames(_skipped(range(20, 20 + max_run)), 60, fps, "S")
    bad = list(range(20, 21 + max_run))
    keep = _brute_keep(bad, 60, max_run)
    assert keep == 20
    with pytest.raises(SessionError) as e:
        check_skipped_frames(_skipped(bad), 60, fps, "S")
    ms = 1000 * 5 / 30
    assert str(e.value) == (
        f"S/kinect/depth/00020.png: frame 20 cannot be captured (no arm), nor {max_run} more of the 60 frames (frames "
        f"20-{20 + max_run}); {max_run + 1} bad frames in a row from frame 20, more than the {max_run} ({ms:.0f} ms) "
        f"the temporal filters bridge: capture the first 20 frames (--frames 20), or re-export the bad frames")


def test_the_share_bound_at_its_edge_and_the_frames_that_keep_within_it():
    from bodystudio.muscle.capture import NoGoodFrameError, check_skipped_frames

    ten = [0, 4, 8, 12, 16, 20, 24, 28, 32, 36]
    check_skipped_frames(_skipped(ten), 40, 30.0, "S")  # 25 % exactly
    eleven = sorted(ten + [39])
    with pytest.raises(SessionError) as e:
        check_skipped_frames(_skipped(eleven, 1000), 40, 30.0, "S")
    assert not isinstance(e.value, NoGoodFrameError)
    keep = _brute_keep(eleven, 40, 5)
    assert keep == 36
    assert str(e.value) == (
        "S/kinect/depth/01000.png: frame 1000 cannot be captured (no arm), nor 10 more of the 40 frames (frames "
        "1000, 1004, 1008, 1012, 1016, 1020, 1024, 1028, 1032, 1036, 1039); bad frames: 11 of 40, more than the 25% "
        "the capture skips: capture the first 36 frames (--frames 36), or re-export the bad frames")
    # a run that starts at the first frame: no first frames keep within the bounds
    with pytest.raises(SessionError) as e:
        check_skipped_frames(_skipped(range(6), 1000), 40, 30.0, "P")
    assert _brute_keep(list(range(6)), 40, 5) == 0
    assert str(e.value).endswith("6 bad frames in a row from frame 1000, more than the 5 (167 ms) the temporal "
                                 "filters bridge: re-export the bad frames")


def test_a_single_bad_frame_is_named_alone_and_every_frame_bad_is_no_good_frame():
    from bodystudio.muscle.capture import NoGoodFrameError, check_skipped_frames

    check_skipped_frames([], 3, 30.0, "S")
    with pytest.raises(SessionError) as e:  # 1 of 2 bad: over 25 %
        check_skipped_frames(_skipped([1], 7), 2, 30.0, "S")
    assert str(e.value) == ("S/kinect/depth/00008.png: frame 8 cannot be captured (no arm); bad frames: 1 of 2, more "
                            "than the 25% the capture skips: capture the first 1 frames (--frames 1), or re-export "
                            "the bad frames")
    with pytest.raises(NoGoodFrameError) as e:
        check_skipped_frames(_skipped([0, 1]), 2, 30.0, "T")
    assert str(e.value) == ("S/kinect/depth/00000.png: frame 0 cannot be captured (no arm), nor 1 more of the 2 "
                            "frames (frames 0-1): no frame of T can be captured")


def test_longest_run_frame_ranges_ids_at_and_frame_problem_by_hand():
    from bodystudio.muscle.capture import _frame_problem, _frame_ranges, ids_at, longest_run

    assert longest_run([]) == (0, -1)
    assert longest_run([7]) == (1, 7)
    assert longest_run([1, 2, 3, 7, 8]) == (3, 1)
    assert longest_run([1, 3, 4, 5, 6, 9, 10]) == (4, 3)
    assert longest_run([1, 2, 5, 6]) == (2, 1)  # a tie: the first
    assert longest_run([2, 4, 6]) == (1, 2)
    assert _frame_ranges([3, 4, 5, 9]) == "3-5, 9"
    assert _frame_ranges([1]) == "1"
    assert _frame_ranges([1, 2, 4, 5, 6]) == "1-2, 4-6"
    assert _frame_ranges([]) == ""
    recs = [{"frame": 40, "position": 4}, {"frame": 71, "position": 7}, {"frame": 90, "position": 9}]
    assert ids_at(recs, 7) == 71 and ids_at(recs, 4) == 40
    p = Path("S/kinect/depth/00001.png")
    assert _frame_problem(SessionError(f"{p}: truncated"), p) == "truncated"
    assert _frame_problem(SessionError(f"{p}truncated"), p) == f"{p}truncated"
    assert _frame_problem(SessionError("other: truncated"), p) == "other: truncated"


def test_every_nth_frame_samples_recorded_numbers():
    from bodystudio.muscle.capture import every_nth_frame

    assert every_nth_frame(10, 4) == slice(0, None, 4)
    assert every_nth_frame(10, 4, 2) == slice(2, None, 4)
    positions = np.array([0, 1, 3, 4, 5, 8, 9, 10, 12])
    assert every_nth_frame(9, 4, 0, positions) == [0, 3, 5, 8]
    assert every_nth_frame(9, 4, 2, positions) == [7]
    assert every_nth_frame(9, 2, 1, positions) == [1, 2, 4, 6]


def test_capture_arm_sequence_hands_on_the_recorded_numbers(monkeypatch):
    import bodystudio.capture.session as session_module
    import bodystudio.muscle.capture as capture

    seen = {}

    def spy(depths, camera, template, model, options, tracker, frame_ids, known_shape, fps, depth_sources=None,
            **kw):
        seen.update(depths=depths, frame_ids=frame_ids, fps=fps, sources=depth_sources, tracker=tracker, **kw)
        return SimpleNamespace()

    monkeypatch.setattr(capture, "capture_arm_frames", spy)
    monkeypatch.setattr(session_module, "stream_fingerprint", lambda s, stream, ids: ("fp", stream, list(ids)))
    template = SimpleNamespace(side=SIDE)
    s = _Session()
    out = capture.capture_arm_sequence(s, None, template)
    good = [f for f in IDS if f not in BAD]
    assert seen["frame_ids"] == good
    assert seen["frame_positions"] == [f - 100 for f in good]  # recorded, not captured, numbers
    assert seen["fps"] == 30.0
    assert [str(p) for p in seen["sources"]] == [f"S/kinect/depth/{f:05d}.png" for f in good]
    assert all(d is s.depths[f] for d, f in zip(seen["depths"], good, strict=True))
    np.testing.assert_allclose(seen["tracker"], np.stack([_arm(f) for f in good]), atol=0)
    assert [r["frame"] for r in out.skipped] == sorted(BAD)
    assert out.source_fingerprint == ("fp", "kinect_depth", good)
    assert out.session_path == str(Path("S").resolve())
    # a slice of the frames: positions within the slice
    seen.clear()
    capture.capture_arm_sequence(_Session(), None, template, frames=slice(4, 20))
    assert seen["frame_positions"] == [f - 104 for f in good if f >= 104]
    # a clean stretch: no positions handed on at all (the capture as before, bit for bit)
    seen.clear()
    out = capture.capture_arm_sequence(_Session(), None, template, frames=slice(0, 3))
    assert "frame_positions" not in seen and seen["frame_ids"] == [100, 101, 102] and out.skipped == []


def _spy_capture(monkeypatch):
    import bodystudio.capture.session as session_module
    import bodystudio.muscle.capture as capture

    seen = {}

    def spy(depths, camera, template, model, options, tracker, frame_ids, known_shape, fps, depth_sources=None,
            **kw):
        seen.update(depths=depths, camera=camera, template=template, model=model, options=options, tracker=tracker,
                    frame_ids=frame_ids, known_shape=known_shape, fps=fps, **kw)
        return SimpleNamespace()

    monkeypatch.setattr(capture, "capture_arm_frames", spy)
    monkeypatch.setattr(session_module, "stream_fingerprint", lambda s, stream, ids: (s, stream, list(ids)))
    return capture, seen


def test_capture_arm_sequence_hands_on_its_inputs_the_rate_and_refuses_without_a_kinect(monkeypatch):
    from bodystudio.muscle.capture import CaptureOptions

    capture, seen = _spy_capture(monkeypatch)
    template, model, options, shape = SimpleNamespace(side=SIDE), object(), CaptureOptions(), object()
    s = _Session(fps=60.0)
    rates = []
    real = capture.read_arm_frames
    monkeypatch.setattr(capture, "read_arm_frames", lambda *a, **k: rates.append(a[1:] + tuple(k.values()))
                        or real(*a, **k))
    out = capture.capture_arm_sequence(s, model, template, options, known_shape=shape)
    assert seen["fps"] == 60.0 and rates == [(IDS, SIDE, options.depth, 60.0)]
    assert seen["camera"] is s.kinect.depth and seen["template"] is template and seen["model"] is model
    assert seen["options"] is options and seen["known_shape"] is shape
    assert out.source_fingerprint[0] is s
    none = _Session()
    none.kinect = None
    with pytest.raises(SessionError) as e:
        capture.capture_arm_sequence(none, None, template)
    assert str(e.value) == "S: no Kinect calibration; the arm capture needs a depth session"


def test_capture_arm_sequence_without_skipping_reads_every_frame_and_the_tracker(monkeypatch):
    capture, seen = _spy_capture(monkeypatch)
    template = SimpleNamespace(side=SIDE)
    s = _Session(frame_ids=[100, 101, 102, 104])
    out = capture.capture_arm_sequence(s, None, template, skip_bad_frames=False)
    assert seen["frame_ids"] == [100, 101, 102, 104] and "frame_positions" not in seen and out.skipped == []
    assert all(d is s.depths[f] for d, f in zip(seen["depths"], [100, 101, 102, 104], strict=True))
    np.testing.assert_allclose(seen["tracker"], np.stack([_arm(f) for f in (100, 101, 102, 104)]), atol=0)
    # frames 106-111, half bad by the skip's checks: not skipped, refused at the first without depth
    with pytest.raises(SessionError) as e:
        capture.capture_arm_sequence(_Session(), None, template, frames=slice(6, 12), skip_bad_frames=False)
    assert str(e.value) == "S: frame 111 has no Kinect depth image"


def test_capture_arm_sequence_with_no_good_frame_runs_as_without_skipping(monkeypatch):
    """Every frame shows no arm in the window: nothing to skip to, so the capture runs on every frame as it did
    before skipping (its own refusal comes from the capture's steps, with the advice on the distance)."""
    capture, seen = _spy_capture(monkeypatch)
    s = _Session(far=True, frame_ids=[100, 101, 102])
    out = capture.capture_arm_sequence(s, None, SimpleNamespace(side=SIDE))
    assert seen["frame_ids"] == [100, 101, 102] and "frame_positions" not in seen and out.skipped == []
    assert all(d is s.depths[f] for d, f in zip(seen["depths"], [100, 101, 102], strict=True))
    np.testing.assert_allclose(seen["tracker"], np.stack([_arm(f) for f in (100, 101, 102)]), atol=0)


def test_read_arm_frames_with_no_good_frame_names_the_session():
    from bodystudio.muscle.capture import NoGoodFrameError, read_arm_frames

    with pytest.raises(NoGoodFrameError, match=r"no frame of Sx can be captured$"):
        read_arm_frames(_Session(path="Sx", far=True, frame_ids=[100, 101]), [100, 101], SIDE)


def test_the_first_frames_that_keep_within_the_bounds_edge_cases(monkeypatch):
    import bodystudio.muscle.capture as capture

    # a run of exactly 5 kept in the first frames, a run of 6 later: keep the frames up to the second run
    bad = list(range(10, 15)) + list(range(30, 36))
    assert _brute_keep(bad, 60, 5) == 30
    with pytest.raises(SessionError, match=r"capture the first 30 frames \(--frames 30\)"):
        capture.check_skipped_frames(_skipped(bad), 60, 30.0, "S")
    # 11 bad of 43 (over 25 %): the first frames kept are fewer than the recording's
    bad = list(range(0, 41, 4))
    keep = _brute_keep(bad, 43, 5)
    assert keep == 40
    with pytest.raises(SessionError, match=rf"bad frames: 11 of 43, .* capture the first {keep} frames"):
        capture.check_skipped_frames(_skipped(bad), 43, 30.0, "S")
    # the bound in milliseconds as the constant says (2 s at 3 fps: 6 frames)
    monkeypatch.setattr(capture, "MAX_SKIPPED_RUN_S", 2.0)
    with pytest.raises(SessionError, match=r"7 bad frames in a row from frame 20, more than the 6 \(2000 ms\)"):
        capture.check_skipped_frames(_skipped(range(20, 27)), 60, 3.0, "S")
