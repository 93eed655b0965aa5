"""``benchmarks/mirror_leg_pose.py`` (mir12aa): a bad ``--stride`` or a folder that is not a mirror session exits 2 with
one line naming it, before any run; the pose recorder puts back what it wrapped."""

import sys

import pytest

from benchmarks import mirror_leg_pose


def _bench(monkeypatch, capsys, *args):
    monkeypatch.setattr(sys, "argv", ["mirror_leg_pose.py", *args])
    with pytest.raises(SystemExit) as exit_:
        mirror_leg_pose.main()
    return exit_.value.code, capsys.readouterr().err


@pytest.mark.parametrize("stride", ["0", "-3"])
def test_a_bad_stride_is_refused_before_any_run(tmp_path, monkeypatch, capsys, stride):
    code, err = _bench(monkeypatch, capsys, "--stride", stride, "--out", str(tmp_path / "o"), str(tmp_path / "S"))
    assert code == 2 and f"--stride {stride}: give 1 or more" in err
    assert not (tmp_path / "o").exists()


def test_a_folder_that_is_not_a_session_is_refused(tmp_path, monkeypatch, capsys):
    (tmp_path / "S").mkdir()
    code, err = _bench(monkeypatch, capsys, "--out", str(tmp_path / "o"), str(tmp_path / "S"))
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1
    assert f"{tmp_path / 'S' / 'session.json'}: missing" in err
    assert not (tmp_path / "o").exists()


def test_the_recorder_puts_back_what_it_wrapped():
    from bodystudio.mirror import frames, reshape, track

    before = (frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target)
    with pytest.raises(RuntimeError), mirror_leg_pose.recorded_poses({}):
        assert track.untwisted_pose is not before[1]
        raise RuntimeError("a failing run")
    assert (frames.read_mirror_frame, track.untwisted_pose, reshape.posed_source_and_target) == before
