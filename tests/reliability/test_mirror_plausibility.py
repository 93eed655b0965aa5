"""``mirror run`` with a source body of another person (``mirror init`` of session A given to session B with
``--source``): well-formed, it used to run to the end with exit 0, tracking and reshaping B with A's skeleton.
The run now compares the session's tracked skeleton with the source body's
(:func:`bodystudio.mirror.plausibility.check_source_body`) and refuses a body that does not fit, naming the
file and the fix; ``--accept-implausible`` runs it with the verdict in run.json."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bodystudio.capture.faults import legs_untracked, shift_colour_camera

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def two_actors(tmp_path_factory) -> dict[str, Path]:
    """Mirror sessions of subjects 5 and 6 (14 frames, the actor in place from frame 10), each with its init
    (measured apart by 0.15-0.17 on 30-frame sessions; the same actor <= 0.035)."""
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.init import initialise_source_body, save_source_body
    from bodystudio.mirror.synthetic import synth_mirror_session

    root = tmp_path_factory.mktemp("mirror_plaus")
    out = {}
    for subject in (5, 6):
        S = root / f"s{subject}"
        synth_mirror_session(S, subject_seed=subject, n_frames=14, walk_in=False)
        save_source_body(S / "mirror" / "source_body.npz", initialise_source_body(open_session(S)))
        out[subject] = S
    return out


def test_own_source_body_passes(two_actors, tmp_path, capfd):
    from bodystudio.mirror.plausibility import SOURCE_MISMATCH_WARN

    S = two_actors[5]
    run = tmp_path / "run"
    result = run_inprocess(["mirror", "run", S, "--out", tmp_path / "o.mp4", "--run", run, "--no-side-by-side",
                            "--taller", "0.1"], capfd)
    assert_clean_error(result, 0, "")
    plausibility = json.loads((run / "run.json").read_text())["plausibility"]
    verdict = plausibility["source_body"]
    assert verdict["ok"] and not verdict["warnings"]
    assert verdict["mismatch"] < SOURCE_MISMATCH_WARN and abs(verdict["scale"] - 1.0) < 0.04
    registration = plausibility["registration"]
    assert registration["ok"] and not registration["warnings"] and registration["offset_px"] <= 3.0


def test_another_persons_source_body_is_refused(two_actors, tmp_path, capfd):
    source = two_actors[6] / "mirror" / "source_body.npz"
    run = tmp_path / "run"
    result = run_inprocess(["mirror", "run", two_actors[5], "--out", tmp_path / "o.mp4", "--run", run,
                            "--source", source, "--taller", "0.1"], capfd)
    assert_clean_error(result, 2, "another person's source body")
    assert str(source) in result.stderr and "mirror init" in result.stderr and "--accept-implausible" in result.stderr
    assert not (run / "run.json").exists() and not (tmp_path / "o.mp4").exists()


def test_accept_implausible_runs_and_records_the_verdict(two_actors, tmp_path, capfd):
    from bodystudio.mirror.plausibility import SOURCE_MISMATCH_REFUSE

    run = tmp_path / "run"
    result = run_inprocess(["mirror", "run", two_actors[5], "--out", tmp_path / "o.mp4", "--run", run,
                            "--no-side-by-side", "--source", two_actors[6] / "mirror" / "source_body.npz",
                            "--accept-implausible"], capfd)
    assert_clean_error(result, 0, "")
    verdict = json.loads((run / "run.json").read_text())["plausibility"]["source_body"]
    assert not verdict["ok"] and verdict["mismatch"] > SOURCE_MISMATCH_REFUSE and verdict["problems"]


def test_init_reports_what_it_saw_and_warns_when_the_legs_were_out_of_view(two_actors, tmp_path, capfd):
    import shutil

    for planted in (False, True):
        S = Path(shutil.copytree(two_actors[5], tmp_path / f"S{planted}"))
        if planted:
            legs_untracked(S)
        result = run_inprocess(["mirror", "init", S, "--force"], capfd)
        assert_clean_error(result, 0, "")
        summary = json.loads(result.stdout.strip().splitlines()[-1])
        assert summary["coverage"]["seen"]["head"] == 1.0
        if planted:
            assert summary["coverage"]["seen"]["legs"] == 0.0
            assert len(summary["warnings"]) == 1 and "the legs tracked in 0%" in summary["warnings"][0]
        else:
            assert summary["coverage"]["seen"]["legs"] == 1.0 and summary["warnings"] == []


def test_misregistered_depth_and_colour_are_refused(two_actors, tmp_path, capfd):
    import shutil

    from bodystudio.capture.session import open_session
    from bodystudio.mirror.plausibility import depth_color_registration

    S = Path(shutil.copytree(two_actors[5], tmp_path / "S"))
    shift_colour_camera(S)
    found = depth_color_registration(open_session(S))
    assert 8.0 <= found["offset_px"] <= 12.0 and found["shift"][0] < 0, found  # the 10 px, found to +-2 px
    run = tmp_path / "run"
    result = run_inprocess(["mirror", "run", S, "--out", tmp_path / "o.mp4", "--run", run, "--taller", "0.1"], capfd)
    assert_clean_error(result, 2, "kinect/calibration.json")
    assert "re-calibrate the Kinect" in result.stderr and "--accept-implausible" in result.stderr
    assert not (run / "run.json").exists() and not (tmp_path / "o.mp4").exists()
