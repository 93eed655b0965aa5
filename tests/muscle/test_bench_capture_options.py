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
