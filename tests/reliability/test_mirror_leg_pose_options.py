"""``benchmarks/mirror_leg_pose.py`` (mir12aa): a bad ``--stride`` or a folder that is not a mirror session exits 2 with
one line naming it, before any run; the pose recorder puts back what it wrapped."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _bench(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "benchmarks/mirror_leg_pose.py", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120, env={"PYTHONPATH": str(ROOT), "PATH": ""})


@pytest.mark.parametrize("stride", ["0", "-3"])
def test_a_bad_stride_is_refused_before_any_run(tmp_path, stride):
    out = _bench("--stride", stride, "--out", str(tmp_path / "o"), str(tmp_path / "S"))
    assert out.returncode == 2
    assert f"--stride {stride}: give 1 or more" in out.stderr
    assert not (tmp_path / "o").exists()


def test_a_folder_that_is_not_a_session_is_refused(tmp_path):
    (tmp_path / "S").mkdir()
    out = _bench("--out", str(tmp_path / "o"), str(tmp_path / "S"))
    assert out.returncode == 2
    assert out.stderr.startswith("error: ") and out.stderr.count("\n") == 1
    assert f"{tmp_path / 'S' / 'session.json'}: missing" in out.stderr
    assert not (tmp_path / "o").exists()


def test_the_recorder_puts_back_what_it_wrapped():
    sys.path.insert(0, str(ROOT))
    from benchmarks.mirror_leg_pose import recorded_poses
    from bodystudio.mirror import frames, reshape, track

    before = (frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target)
    with pytest.raises(RuntimeError), recorded_poses({}):
        assert track.untwisted_pose is not before[1]
        raise RuntimeError("a failing run")
    assert (frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target) == before
