"""``benchmarks.bench_muscle --capture-option KEY=VALUE``: CaptureOptions variants for the benchmark's captures."""

import pytest

from benchmarks.bench_muscle import parse_capture_options


def _error(msg):
    raise ValueError(msg)


def test_capture_options_are_parsed_as_literals():
    got = parse_capture_options(["sequence_fit_skeleton=True", "sequence_free_joints=(False, True, True)",
                                 "sequence_skeleton_prior_weight=1000.0"], _error)
    assert got == {"sequence_fit_skeleton": True, "sequence_free_joints": (False, True, True),
                   "sequence_skeleton_prior_weight": 1000.0}


@pytest.mark.parametrize("item", ["no_such_field=1", "sequence_fit_skeleton", "sequence_rounds=three"])
def test_bad_capture_options_are_refused_in_one_line(item):
    with pytest.raises(ValueError, match="^--capture-option ") as exc:
        parse_capture_options([item], _error)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("item", ["no_such_key=1", "tracker_weight=ten"])
def test_muscle_energy_refuses_bad_options_in_one_line(item, tmp_path, capsys):
    from benchmarks.muscle_energy import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--option", item])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"--option {item}" in err
    assert not (tmp_path / "w").exists()  # nothing written
