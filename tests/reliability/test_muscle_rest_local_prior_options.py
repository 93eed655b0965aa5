"""The rest-shape fit's local-target prior options (``CaptureOptions.body_rest_local_sigma``,
``body_rest_population_locals``) and ``benchmarks.muscle_tail``'s variants: bad values are refused in one line before
any work."""

import pytest

from benchmarks.muscle_tail import main
from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions


@pytest.mark.parametrize("field, value", [("body_rest_local_sigma", 0.0), ("body_rest_local_sigma", -0.25),
                                          ("body_rest_local_sigma", float("nan")),
                                          ("body_rest_population_locals", -1.0),
                                          ("body_rest_population_locals", float("nan"))])
def test_a_bad_local_prior_option_is_refused_in_one_line(field, value):
    with pytest.raises(InputError, match="body_rest_local_sigma must be > 0") as exc:
        CaptureOptions(**{field: value})
    assert "\n" not in str(exc.value) and field in str(exc.value)


def test_the_local_prior_defaults_to_the_measured_one():
    o = CaptureOptions()
    assert o.body_rest_local_sigma == 0.1 and o.body_rest_population_locals == 2.0  # docs/muscle.md sixteenth pass


@pytest.mark.parametrize("args", [["--variant", "p:body_rest_local_sigma=0"],
                                  ["--variant", "p:body_rest_population_locals=-2"],
                                  ["--variant", "p:no_such_option=1"], ["--variant", "p:body_rest_local_sigma"],
                                  ["--variant", "a", "--variant", "b:norm_limit=0.2"]])
def test_the_benchmark_refuses_a_bad_variant_before_any_work(args, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "501", *args])
    assert exc.value.code == 2
    assert "--variant" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
