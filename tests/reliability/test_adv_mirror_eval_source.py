"""``eval mirror`` after ``mirror init`` was re-run (adversarial pass): the run's frames were made with the
old source body but the init and tracking scores came from the new one, mixed into one JSON with exit 0.
The run now records its source body's fingerprint and ``eval mirror`` refuses another body."""

from __future__ import annotations

import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.fixture(scope="module")
def mirror_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("advmir") / "s"
    assert main(["synth", "mirror", str(out), "--subject-seed", "3", "--frames", "12", "--no-walk-in",
                 "--taller", "0.1"]) == 0
    return out


def test_eval_refuses_a_run_of_another_source_body(mirror_session, tmp_path, capsys):
    s = str(mirror_session)
    assert main(["mirror", "init", s, "--resolution", "2k", "--frames", "1"]) == 0
    assert main(["mirror", "run", s, "--taller", "0.1", "--ramp-frames", "0", "--out", str(tmp_path / "o.mp4")]) == 0
    capsys.readouterr()
    assert main(["eval", "mirror", s]) == 0
    assert '"init_stature_err_mm"' in capsys.readouterr().out
    # mirror init again, on the 6k template: another source body than the run's
    assert main(["mirror", "init", s, "--resolution", "6k", "--frames", "1", "--force"]) == 0
    capsys.readouterr()
    run_bad(["eval", "mirror", s], capsys, "the run used another source body")
