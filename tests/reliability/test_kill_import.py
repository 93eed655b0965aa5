"""`bodystudio capture import` SIGKILLed while writing a new session: never a session that opens with
missing or mixed frames; `bodystudio recover` finishes it (after the commit point) or discards it."""

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import kill_points, read_events, run_child  # noqa: E402

from bodystudio.capture.session import open_session  # noqa: E402
from bodystudio.cli.main import main  # noqa: E402
from bodystudio.errors import BodyStudioError  # noqa: E402

N_FRAMES = 3


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Image folders of 2 cameras x 3 frames (64x48) and their cameras.json."""
    from bodystudio.geometry.camera import ring_rig, save_cameras_json

    root = tmp_path_factory.mktemp("kill_import")
    save_cameras_json(root / "cameras.json", ring_rig(2, width=64, height=48))
    rng = np.random.default_rng(16)
    for cam in ("cam_00", "cam_01"):
        (root / "images" / cam).mkdir(parents=True)
        for f in range(N_FRAMES):
            cv2.imwrite(str(root / "images" / cam / f"{f:05d}.png"), rng.integers(0, 255, (48, 64, 3), np.uint8))
    return root


def import_args(root: Path, out: Path) -> list[str]:
    return ["capture", "import", str(out), "--cameras", str(root / "cameras.json"), "--images", str(root / "images")]


def reader_state(out: Path) -> str:
    """'complete' (every frame, checksums verified), 'absent' or 'refused' (one line)."""
    if not out.exists():
        return "absent"
    try:
        s = open_session(out)
    except BodyStudioError as exc:
        msg = str(exc)
        assert "\n" not in msg and ("recover" in msg or "never completed" in msg), msg
        return "refused"
    assert s.frame_ids == list(range(N_FRAMES)) and s.verify() == 1 + 2 * N_FRAMES
    return "complete"


def _recover_and_check(out: Path) -> str:
    if out.exists():
        assert main(["recover", str(out)]) == 0
    state = reader_state(out)
    if state == "refused":  # discarded before the commit point: nothing was ever complete
        assert not (out / "session.json").exists() and not (out / ".staging").exists()
        state = "absent"
    assert state in ("complete", "absent")
    return state


@pytest.mark.parametrize("offset, expected, after_recover", [
    (0, "refused", "absent"),  # every frame staged, no commit record
    (3, "refused", "complete"),  # the commit record and two files in place, no manifest
])
def test_import_killed_around_the_commit_point(recording, tmp_path, offset, expected, after_recover):
    out = tmp_path / "session"
    proc = run_child(import_args(recording, out), tmp_path, after_match="commit.json", offset=offset)
    assert proc.returncode == -9, proc.stderr
    assert reader_state(out) == expected
    assert _recover_and_check(out) == after_recover
    if after_recover == "absent":  # the import can simply be run again
        assert main(import_args(recording, out)) == 0 and reader_state(out) == "complete"


@pytest.mark.slow
def test_import_killed_at_seeded_points(recording, tmp_path):
    log = tmp_path / "events.json"
    assert run_child(import_args(recording, tmp_path / "probe"), tmp_path, event_log=log).returncode == 0
    for k in kill_points(read_events(log), seed=16, n=5):
        out = tmp_path / f"k{k}"
        assert run_child(import_args(recording, out), tmp_path, kill_at=k).returncode == -9
        assert reader_state(out) in ("refused", "absent")
        _recover_and_check(out)
