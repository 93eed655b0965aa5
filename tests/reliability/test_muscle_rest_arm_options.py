"""The grazing-pair options of the rest-shape and sequence fits (``CaptureOptions.body_rest_min_facing_cos``,
``sequence_min_facing_cos``) and ``benchmarks.muscle_rest_arm``'s variants: bad values are refused in one line
before any work."""

import pytest

from benchmarks.muscle_rest_arm import main
from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions


@pytest.mark.parametrize("field", ["body_rest_min_facing_cos", "sequence_min_facing_cos"])
@pytest.mark.parametrize("value", [-0.1, 1.0, 2.0, float("nan")])
def test_a_facing_cosine_outside_zero_to_one_is_refused(field, value):
    with pytest.raises(InputError, match=field.split("_min")[0]) as exc:
        CaptureOptions(**{field: value})
    assert "\n" not in str(exc.value) and "[0, 1)" in str(exc.value)


def test_the_facing_cosines_default_to_the_measured_ones():
    o = CaptureOptions()
    assert o.body_rest_min_facing_cos == 0.0 and o.sequence_min_facing_cos == 0.3


@pytest.mark.parametrize("variant", ["g:body_rest_min_facing_cos=1.5", "g:no_such_option=1",
                                     "g:body_rest_min_facing_cos", "g:sequence_min_facing_cos=-1",
                                     "--known-poses g:norm_limit=0.2"])
def test_the_benchmark_refuses_a_bad_variant_before_any_work(variant, tmp_path, capsys):
    *flags, variant = variant.split()
    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "501", *flags, "--variant", variant])
    assert exc.value.code == 2
    assert "--variant" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
