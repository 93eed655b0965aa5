"""`bodystudio calibrate` SIGKILLed while re-calibrating: cameras.json, the EasyMocap / COLMAP exports and
the report (the manifest, written last) stay one run, or the reader says "interrupted, run recover"."""

import json
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import kill_points, read_events, run_child, snapshot  # noqa: E402

from bodystudio.calib.io import check_calibration_outputs  # noqa: E402
from bodystudio.cli.main import main  # noqa: E402
from bodystudio.errors import BodyStudioError  # noqa: E402

# The children killed at a file event replay the detection and bundle adjustment of the re-calibration, recorded
# once in this process (same capture and options: the same rig to ~1e-9 relative, BLAS threading aside), instead
# of repeating them: every file event comes after them, so the events (16, checked against a real child) and the
# kill points are the same. The time-based kill runs them for real.
REPLAY_CALIBRATION = """
import pickle
import bodystudio.calib.calibrate as calibrate
import bodystudio.calib.observations as observations

obs, quality, result = pickle.loads(open({path!r}, "rb").read())
observations.detect_capture = lambda folder, spec, progress=None: (obs, quality)
calibrate.calibrate_cameras = lambda observations, spec, options=None: result
"""


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A 4-camera, 12-pose synthetic capture and a complete calibration of it (cameras.json + EasyMocap), and
    the setup that replays the re-calibration of ``new_run`` (``root/replay.py``).

    Four cameras and 12 poses are too few for the 2 mm centre-sigma verdict: the runs accept it.
    """
    import pickle

    import bodystudio.calib.calibrate as calibrate
    import bodystudio.calib.observations as observations
    from bodystudio.calib.synthetic import write_synthetic_calibration

    root = tmp_path_factory.mktemp("kill_cal")
    write_synthetic_calibration(root / "cap", 4, 12, 0, 640, 480)
    work = root / "w"
    assert main(["calibrate", str(root / "cap"), "--out", str(work / "cameras.json"),
                 "--easymocap", str(work / "emc"), "--accept-uncertain"]) == 0
    run_id = json.loads((work / "cameras.report.json").read_text())["run"]["run_id"]
    recorded = {}
    with pytest.MonkeyPatch.context() as mp:
        real_detect, real_calibrate = observations.detect_capture, calibrate.calibrate_cameras
        mp.setattr(observations, "detect_capture",
                   lambda *a, **k: recorded.setdefault("detect", real_detect(*a, **k)))
        mp.setattr(calibrate, "calibrate_cameras",
                   lambda *a, **k: recorded.setdefault("result", real_calibrate(*a, **k)))
        assert main(new_run(root, root / "recording")) == 0
    (root / "calibration.pkl").write_bytes(pickle.dumps((*recorded["detect"], recorded["result"])))
    (root / "replay.py").write_text(REPLAY_CALIBRATION.format(path=str(root / "calibration.pkl")))
    return root, run_id, snapshot(work)


def _copy(calibrated, tmp_path):
    root, run_id, snap = calibrated
    work = tmp_path / "w"
    shutil.copytree(root / "w", work)
    return work, run_id, snap


def new_run(root: Path, work: Path) -> list[str]:
    return ["calibrate", str(root / "cap"), "--out", str(work / "cameras.json"), "--distortion-terms", "5",
            "--easymocap", str(work / "emc"), "--colmap", str(work / "colmap"), "--accept-uncertain"]


def reader_state(work: Path, previous_id: str, previous: dict) -> str:
    """What `eval calib` reads: 'previous', 'new' (checked file by file) or 'refused' (one line, recover)."""
    try:
        report = check_calibration_outputs(work / "cameras.json")
    except BodyStudioError as exc:
        msg = str(exc)
        assert "\n" not in msg and "recover" in msg, msg
        return "refused"
    visible = snapshot(work)
    if report["run"]["run_id"] == previous_id:
        assert visible == previous
        return "previous"
    assert {"cameras.json", "emc/intri.yml", "emc/extri.yml", "colmap/cameras.txt"} <= set(report["run"]["files"])
    assert json.loads((work / "cameras.json").read_bytes())  # the new rig, whole
    return "new"


def _recover_and_check(work, previous_id, previous) -> str:
    assert main(["recover", str(work / "cameras.json")]) == 0
    state = reader_state(work, previous_id, previous)
    assert state in ("previous", "new")
    assert not any(p.name.startswith(".cameras.json.") for p in work.iterdir())
    return state


@pytest.mark.parametrize("offset, expected, after_recover", [
    (0, "previous", "previous"),
    (2, "refused", "new"),  # cameras.json moved, the exports and the report not yet
])
def test_calibrate_killed_around_the_commit_point(calibrated, tmp_path, offset, expected, after_recover):
    work, previous_id, previous = _copy(calibrated, tmp_path)
    proc = run_child(new_run(calibrated[0], work), tmp_path, after_match="commit.json", offset=offset,
                     setup=calibrated[0] / "replay.py")
    assert proc.returncode == -9, proc.stderr
    assert reader_state(work, previous_id, previous) == expected
    assert _recover_and_check(work, previous_id, previous) == after_recover


@pytest.mark.slow
def test_calibrate_killed_at_seeded_points(calibrated, tmp_path):
    work, previous_id, previous = _copy(calibrated, tmp_path / "probe")
    log = tmp_path / "events.json"
    replay = calibrated[0] / "replay.py"
    assert run_child(new_run(calibrated[0], work), tmp_path, event_log=log, setup=replay).returncode == 0
    seen = set()
    for k in kill_points(read_events(log), seed=16, n=4):
        work, previous_id, previous = _copy(calibrated, tmp_path / f"k{k}")
        assert run_child(new_run(calibrated[0], work), tmp_path, kill_at=k, setup=replay).returncode == -9
        seen.add(reader_state(work, previous_id, previous))
        _recover_and_check(work, previous_id, previous)
    work, previous_id, previous = _copy(calibrated, tmp_path / "t")
    run_child(new_run(calibrated[0], work), tmp_path, kill_after_s=3.0)
    seen.add(reader_state(work, previous_id, previous))
    _recover_and_check(work, previous_id, previous)
    assert {"previous", "refused"} <= seen
