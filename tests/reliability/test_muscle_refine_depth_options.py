"""The Sec. 7 refinement's own depth clean-up and rim filter (``CaptureOptions.refine_depth_median_px``,
``refine_depth_gaussian_sigma_px``, ``refine_min_facing_cos``; docs/muscle.md fourteenth capture pass): bad values are
refused in one line, from the API and from the benchmarks' command lines, before any work."""

import pytest

from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions

BAD = [("refine_depth_median_px", "4"), ("refine_depth_median_px", "7"), ("refine_depth_gaussian_sigma_px", "-0.5"),
       ("refine_min_facing_cos", "1.0"), ("refine_min_facing_cos", "-0.2")]


@pytest.mark.parametrize("field, value", BAD)
def test_capture_options_refuse_bad_refinement_depth_values(field, value):
    with pytest.raises(InputError, match=field) as exc:
        CaptureOptions(**{field: float(value) if "." in value else int(value)})
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("field, value", BAD)
def test_bench_muscle_capture_option_refused_before_any_work(field, value, tmp_path, capsys):
    from benchmarks.bench_muscle import main

    with pytest.raises(SystemExit) as exc:
        main(["--step", "compare", "--work", str(tmp_path / "w"), "--capture-option", f"{field}={value}"])
    assert exc.value.code == 2
    assert field in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


@pytest.mark.parametrize("variant", ["bad:refine_depth_median_px=2", "bad:refine_min_facing_cos=1.5",
                                     "bad:no_such_field=1", "bad:refine_depth_gaussian_sigma_px=oops"])
def test_muscle_front_refuses_a_bad_variant_before_any_work(variant, tmp_path, capsys):
    from benchmarks.muscle_front import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "501", "--step", "variants", "--variant", variant])
    assert exc.value.code == 2
    assert "--variant" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


def test_muscle_front_refuses_a_negative_noise_seed_before_any_work(tmp_path, capsys):
    from benchmarks.muscle_front import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "501", "--noise-seed", "-1"])
    assert exc.value.code == 2
    assert "--noise-seed" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
