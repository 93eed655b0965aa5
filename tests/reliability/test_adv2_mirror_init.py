"""``bodystudio mirror init`` as a hostile user runs it (adversarial pass, round 2).

Before: a second ``mirror init`` silently replaced the source body (a ``mirror run`` made from the old body
then no longer matched it), and ``--frames N`` beyond the session's frames initialised from fewer frames
than asked for, both with exit 0. Now the first needs ``--force`` and the second is refused with one line
naming the session's frame count; nothing is written in either case."""

from __future__ import annotations

import json

import pytest

from bodystudio.cli.main import main

from .conftest import assert_clean_error, run_inprocess

N_FRAMES = 12


@pytest.fixture(scope="module")
def mirror_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("adv2mir") / "s"
    assert main(["synth", "mirror", str(out), "--subject-seed", "3", "--frames", str(N_FRAMES), "--no-walk-in",
                 "--taller", "0.1"]) == 0
    return out


def test_frames_beyond_the_session_are_refused(mirror_session, capfd):
    result = run_inprocess(["mirror", "init", mirror_session, "--resolution", "2k", "--frames", "50"], capfd)
    assert_clean_error(result, 2, f"has {N_FRAMES} frames")
    assert not (mirror_session / "mirror" / "source_body.npz").exists()


def test_a_second_init_needs_force(mirror_session, capfd):
    body = mirror_session / "mirror" / "source_body.npz"
    summary = mirror_session / "mirror" / "source_body.json"
    # the default (90 frames) on a shorter session: the whole session, no refusal
    assert run_inprocess(["mirror", "init", mirror_session, "--resolution", "2k"], capfd).rc == 0
    before, before_summary = body.read_bytes(), summary.read_bytes()
    result = run_inprocess(["mirror", "init", mirror_session, "--resolution", "6k", "--frames", "3"], capfd)
    assert_clean_error(result, 2, "pass --force to replace it")
    assert body.read_bytes() == before and summary.read_bytes() == before_summary
    assert run_inprocess(["mirror", "init", mirror_session, "--resolution", "6k", "--frames", "3", "--force"],
                         capfd).rc == 0
    assert body.read_bytes() != before
    assert json.loads(summary.read_text())["resolution"] == "6k"
