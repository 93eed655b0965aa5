"""``bodystudio mirror run`` SIGKILLed while re-running over a complete run (adversarial pass, round 2).

The run folder (frames, masks, run.json) and the videos beside it are one unit (runfolder.RunWriter). A kill
before the commit point leaves the previous run and videos byte for byte; one after it leaves a folder that
every reader refuses with one line naming ``bodystudio recover``, which then completes the new run. Before
this pass ``eval mirror`` refused such a folder but ``view`` and ``report`` showed it (old and new frames
mixed) with exit 0; so did they a folder whose frame was swapped for another run's.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from kill_harness import read_events, run_child, snapshot  # noqa: E402

from bodystudio.cli.main import main  # noqa: E402

from .conftest import assert_clean_error, run_inprocess  # noqa: E402


@pytest.fixture(scope="module")
def mirror_run(tmp_path_factory):
    """A 12-frame mirror session (the actor in the last two) with a source body, a complete run (taller
    0.1) and the file events of a second run (taller 0.05) over it."""
    root = tmp_path_factory.mktemp("adv2kill")
    s = root / "s"
    assert main(["synth", "mirror", str(s), "--subject-seed", "3", "--frames", "12", "--no-walk-in",
                 "--taller", "0.1"]) == 0
    assert main(["mirror", "init", str(s), "--resolution", "2k", "--frames", "1"]) == 0
    assert main(run_args(root, "0.1")) == 0
    log = root / "events.json"
    probe = root / "probe"
    shutil.copytree(root, probe, ignore=shutil.ignore_patterns("probe", "events.json"))
    _retarget(probe, root)
    assert run_child(run_args(probe, "0.05"), probe, event_log=log).returncode == 0
    return root, read_events(log)


def run_args(root: Path, taller: str) -> list[str]:
    return ["mirror", "run", str(root / "s"), "--taller", taller, "--ramp-frames", "0", "--no-refine-pose",
            "--out", str(root / "o.mp4")]


def _retarget(copy: Path, original: Path) -> None:
    """A copied run's run.json names the original session: point it at the copy's."""
    run_json = copy / "s" / "mirror" / "run" / "run.json"
    doc = json.loads(run_json.read_text())
    doc["session"] = str((copy / "s").resolve())
    run_json.write_text(json.dumps(doc))


def _copy(mirror_run, tmp_path) -> Path:
    root, _ = mirror_run
    work = tmp_path / "w"
    shutil.copytree(root, work, ignore=shutil.ignore_patterns("probe", "events.json"))
    _retarget(work, root)
    return work


def _readers_refuse(work: Path, capfd, phrase: str) -> None:
    s = work / "s"
    for args in (["eval", "mirror", s], ["view", s, "--screenshot", work / "v.png"],
                 ["view", s / "mirror" / "run", "--screenshot", work / "v.png"],
                 ["report", s, "--out", work / "r.html"]):
        assert_clean_error(run_inprocess(args, capfd), 2, phrase)
    assert not (work / "v.png").exists() and not (work / "r.html").exists()


@pytest.mark.slow
def test_mirror_run_killed_before_and_after_its_commit_point(mirror_run, tmp_path, capfd):
    _, events = mirror_run
    commit = next(k + 1 for k, e in enumerate(events) if e.endswith("commit.json"))
    for kill_at in (3, commit, commit + 1):
        work = _copy(mirror_run, tmp_path / str(kill_at))
        run_dir = work / "s" / "mirror" / "run"
        before, video = snapshot(run_dir), (work / "o.mp4").read_bytes()
        proc = run_child(run_args(work, "0.05"), work, kill_at=kill_at)
        assert proc.returncode == -9, proc.stderr[-500:]
        if kill_at <= commit:  # the previous run, whole, and readers take it
            assert snapshot(run_dir) == before and (work / "o.mp4").read_bytes() == video
            assert run_inprocess(["eval", "mirror", work / "s"], capfd).rc == 0
            assert run_inprocess(["view", work / "s", "--screenshot", work / "v.png"], capfd).rc == 0
        else:
            _readers_refuse(work, capfd, "bodystudio recover")
        assert run_inprocess(["recover", run_dir], capfd).rc == 0
        taller = json.loads((run_dir / "run.json").read_text())["edits"]["taller"]
        assert taller == (0.1 if kill_at <= commit else 0.05)
        assert run_inprocess(["view", work / "s", "--screenshot", work / "v2.png"], capfd).rc == 0


@pytest.mark.slow
def test_a_frame_of_another_run_is_refused_by_the_viewer(mirror_run, tmp_path, capfd):
    work = _copy(mirror_run, tmp_path)
    frames = work / "s" / "mirror" / "run" / "frames"
    shutil.copy(frames / "00000.png", frames / "00011.png")  # a frame of another run (or edited) in place
    _readers_refuse(work, capfd, "does not belong to run")


@pytest.mark.slow
def test_report_rescores_a_saved_eval_of_an_earlier_run(mirror_run, tmp_path, capfd):
    """``eval mirror S > S/mirror/eval.json`` (as the demo saves it), then ``mirror run`` again: the report
    showed the saved scores of the first run beside the second run's frames; now it re-scores and says so."""
    from bodystudio.viewer.report import write_report

    work = _copy(mirror_run, tmp_path)
    s = work / "s"
    result = run_inprocess(["eval", "mirror", s], capfd)
    assert result.rc == 0, result.text[-800:]
    (s / "mirror" / "eval.json").write_text(result.stdout)
    first = write_report(s, work / "r1.html", with_3d=False).mirrors[0]
    assert first.note is None and first.scores == json.loads(result.stdout)  # the saved scores, as they are
    assert run_inprocess(run_args(work, "0.1"), capfd).rc == 0  # the same edit again: a new run
    again = write_report(s, work / "r2.html", with_3d=False).mirrors[0]
    assert "scores an earlier run" in again.note
    assert again.scores["run_id"] == json.loads((s / "mirror" / "run" / "run.json").read_text())["run"]["run_id"]


@pytest.mark.slow
def test_view_does_not_show_another_source_body_beside_the_run(mirror_run, tmp_path, capfd):
    """After ``mirror init --force`` the view showed the new source body beside frames made with the old
    one (eval mirror refused the pair); it now leaves the body out and its title says to re-run."""
    from bodystudio.viewer.mirror import open_mirror_view, scene_for_mirror
    from bodystudio.viewer.scene import make_plotter

    work = _copy(mirror_run, tmp_path)
    s = work / "s"
    plotter = scene_for_mirror(open_mirror_view(s), plotter=make_plotter(off_screen=True))
    assert "source-body" in plotter.actors  # the run's own body
    plotter.close()
    assert run_inprocess(["mirror", "init", s, "--resolution", "6k", "--frames", "1", "--force"], capfd).rc == 0
    plotter = scene_for_mirror(open_mirror_view(s), plotter=make_plotter(off_screen=True))
    assert "source-body" not in plotter.actors
    assert "source body changed since this run" in plotter.actors["title"].GetText(2)
    plotter.close()


@pytest.mark.slow
def test_view_ignores_frames_left_by_an_earlier_longer_run(mirror_run, tmp_path, capfd):
    """A run over fewer frames (``run_mirror(frames=...)``, a live run) leaves the earlier run's other frame
    files in RUN/frames/; ``view --frame`` showed such a file as this run's output, labelled with its edits."""
    from bodystudio.mirror.run import run_mirror
    from bodystudio.viewer.mirror import before_after_panels, open_mirror_view

    work = _copy(mirror_run, tmp_path)
    s = work / "s"
    run_mirror(s, {"taller": 0.1}, work / "o2.mp4", side_by_side=False, progress=False, ramp_frames=0,
               frames=[10, 11], refine_pose=False)
    assert (s / "mirror" / "run" / "frames" / "00005.png").is_file()  # the first run's, not listed now
    view = open_mirror_view(s)
    assert [c.split(" ")[0] for c, _ in before_after_panels(view, 5)] == ["input", "truth"]
    assert [c.split(" ")[0] for c, _ in before_after_panels(view, 11)] == ["input", "mirror", "truth"]
