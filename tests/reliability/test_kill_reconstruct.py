"""`bodystudio reconstruct` SIGKILLed while re-running over a complete result (issue 16, whole-run atomicity).

After every kill the reader behind `eval reconstruct`, `view` and `report` must accept exactly the previous
run or exactly the complete new one, or refuse with the one-line "interrupted, run recover" state; and
`bodystudio recover` must leave one of the two complete runs. Never a mix that a reader accepts.
"""

import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import kill_points, read_events, run_child, snapshot  # noqa: E402

from bodystudio.cli.main import main  # noqa: E402
from bodystudio.errors import BodyStudioError  # noqa: E402
from bodystudio.reconstruct.rapid_skin import RapidSkinParams  # noqa: E402
from bodystudio.reconstruct.sequence import evaluate_session, read_reconstruction, reconstruct_session  # noqa: E402

NEW_RUN = ["--template", "2k", "--frames", "0:1", "--outer", "1", "--inner", "2", "--no-refine-pose", "--no-score"]


@pytest.fixture(scope="module")
def reconstructed(tmp_path_factory):
    """A 2-camera, 2-frame session with a complete 2k reconstruction of both frames (read-only)."""
    from bodystudio.capture.synth import synth_session

    path = tmp_path_factory.mktemp("kill_rec") / "s"
    synth_session(path, n_cameras=2, n_frames=2, motion="walk", subject_seed=7, kinect="v2", resolution=(160, 120),
                  noise=False, template="2k")
    reconstruct_session(path, template="2k", refine_pose=False, score=False,
                        params=RapidSkinParams(outer_iterations=2, inner_iterations=4))
    run, _ = read_reconstruction(path)
    return path, run["run"]["run_id"], snapshot(path / "reconstruct")


def _copy(reconstructed, tmp_path):
    src, run_id, snap = reconstructed
    dst = tmp_path / "s"
    shutil.copytree(src, dst)
    return dst, run_id, snap


def reader_state(session: Path, previous_id: str, previous: dict) -> str:
    """'previous', 'new' (each checked file by file) or 'refused' (one line naming recover)."""
    try:
        run, meshes = read_reconstruction(session)
    except BodyStudioError as exc:
        msg = str(exc)
        assert "\n" not in msg and "recover" in msg, msg
        return "refused"
    visible = snapshot(session / "reconstruct")
    if run["run"]["run_id"] == previous_id:
        assert visible == previous, "the previous run id, but its files changed"
        return "previous"
    assert run["frames"] == [0] and set(meshes) == {0}
    assert set(visible) == {"run.json", "frames.json", "meshes/00000.ply"}, sorted(visible)
    return "new"


def _recover_and_check(session, previous_id, previous) -> str:
    assert main(["recover", str(session)]) == 0
    state = reader_state(session, previous_id, previous)
    assert state in ("previous", "new")
    rec = session / "reconstruct"
    assert not (rec / ".staging").exists() and not (rec / ".lock").exists()
    return state


@pytest.mark.parametrize("offset, expected, after_recover", [
    (0, "previous", "previous"),  # killed just before the commit record lands
    (1, "refused", "new"),  # killed after the commit point, before the first move
])
def test_reconstruct_killed_around_the_commit_point(reconstructed, tmp_path, offset, expected, after_recover):
    session, previous_id, previous = _copy(reconstructed, tmp_path)
    proc = run_child(["reconstruct", str(session), *NEW_RUN], tmp_path, after_match="commit.json", offset=offset)
    assert proc.returncode == -9, proc.stderr
    assert reader_state(session, previous_id, previous) == expected
    if expected == "previous":
        assert evaluate_session(session)["frames"] == 2  # `eval reconstruct` scores the previous run
    else:
        with pytest.raises(BodyStudioError, match=r"interrupted.*bodystudio recover"):
            evaluate_session(session)
    assert _recover_and_check(session, previous_id, previous) == after_recover


@pytest.mark.slow
def test_reconstruct_killed_at_seeded_points(reconstructed, tmp_path):
    """Every step of the write protocol (seeded sample of file events, plus time-based kills)."""
    session, previous_id, previous = _copy(reconstructed, tmp_path / "probe")
    log = tmp_path / "events.json"
    assert run_child(["reconstruct", str(session), *NEW_RUN], tmp_path, event_log=log).returncode == 0
    events = read_events(log)
    seen = set()
    for k in kill_points(events, seed=16, n=4):
        session, previous_id, previous = _copy(reconstructed, tmp_path / f"k{k}")
        proc = run_child(["reconstruct", str(session), *NEW_RUN], tmp_path, kill_at=k)
        assert proc.returncode == -9, proc.stderr
        seen.add(reader_state(session, previous_id, previous))
        _recover_and_check(session, previous_id, previous)
    for t in (2.0, 4.0):
        session, previous_id, previous = _copy(reconstructed, tmp_path / f"t{t}")
        run_child(["reconstruct", str(session), *NEW_RUN], tmp_path, kill_after_s=t)
        seen.add(reader_state(session, previous_id, previous))
        _recover_and_check(session, previous_id, previous)
        # after recovery the command runs again (no stale lock, no leftover staging)
        assert run_child(["reconstruct", str(session), *NEW_RUN], tmp_path).returncode == 0
        assert reader_state(session, previous_id, previous) == "new"
    assert {"previous", "refused"} <= seen
