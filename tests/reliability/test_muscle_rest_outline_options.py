"""The rest-shape fit's outline options (``CaptureOptions.body_rest_outline_weight``, ``body_rest_outline_offset_m``)
and ``benchmarks.muscle_tail``'s variants with them: bad values are refused in one line before any work."""

import pytest

from benchmarks.muscle_tail import main
from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions


@pytest.mark.parametrize("field, value", [("body_rest_outline_weight", -1.0),
                                          ("body_rest_outline_weight", float("nan")),
                                          ("body_rest_outline_offset_m", 0.02), ("body_rest_outline_offset_m", -0.5),
                                          ("body_rest_outline_offset_m", float("nan"))])
def test_a_bad_outline_option_is_refused_in_one_line(field, value):
    with pytest.raises(InputError, match="body_rest_outline_weight must be >= 0") as exc:
        CaptureOptions(**{field: value})
    assert "\n" not in str(exc.value) and str(value) in str(exc.value)


@pytest.mark.parametrize("args", [["--variant", "o:body_rest_outline_weight=-1"],
                                  ["--variant", "o:body_rest_outline_offset_m=0.5"],
                                  ["--variant", "o:body_rest_outline_weight"]])
def test_the_benchmark_refuses_a_bad_outline_variant_before_any_work(args, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "508", "--rest-variants", *args])
    assert exc.value.code == 2
    assert "--variant" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
