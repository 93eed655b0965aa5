"""The pose smoothing's degree and sigma (``CaptureOptions.pose_smoothing_degree`` / ``pose_sigma_frames``;
docs/muscle.md fifteenth capture pass): bad values are refused in one line, from the API and from the benchmarks'
command lines, before any work."""

import pytest

from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions


@pytest.mark.parametrize("degree", [-1, 4, 2.0, True, "2"])
def test_capture_options_refuse_a_bad_smoothing_degree(degree):
    with pytest.raises(InputError, match="pose_smoothing_degree") as exc:
        CaptureOptions(pose_smoothing_degree=degree)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("degree", [-1, 4, 0.0, False])
def test_capture_options_refuse_a_bad_shoulder_smoothing_degree(degree):
    with pytest.raises(InputError, match="shoulder_smoothing_degree") as exc:
        CaptureOptions(shoulder_smoothing_degree=degree)
    assert "\n" not in str(exc.value)
    assert CaptureOptions(shoulder_smoothing_degree=None).shoulder_smoothing_degree is None  # None: the elbow's


@pytest.mark.parametrize("sigma", [-1.0, float("nan")])
def test_capture_options_refuse_a_negative_smoothing_sigma(sigma):
    with pytest.raises(InputError, match="pose_sigma_frames") as exc:
        CaptureOptions(pose_sigma_frames=sigma)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("item", ["pose_smoothing_degree=5", "pose_smoothing_degree=1.5", "pose_sigma_frames=-2.0",
                                  "shoulder_smoothing_degree=9"])
def test_bench_muscle_capture_option_refused_before_any_work(item, tmp_path, capsys):
    from benchmarks.bench_muscle import main

    with pytest.raises(SystemExit) as exc:
        main(["--step", "compare", "--work", str(tmp_path / "w"), "--capture-option", item])
    assert exc.value.code == 2
    assert item.split("=")[0] in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


@pytest.mark.parametrize("variant", ["bad:pose_smoothing_degree=7", "bad:pose_sigma_frames=-1.0",
                                     "bad:norm_limit=0.5", "bad:pose_smoothing_degree=oops",
                                     "bad:shoulder_smoothing_degree=-1"])
def test_muscle_tangential_refuses_a_bad_variant_before_any_work(variant, tmp_path, capsys):
    from benchmarks.muscle_tangential import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", "501", "--variant", variant])
    assert exc.value.code == 2
    assert "--variant" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
