"""``benchmarks/mirror_init_unpose_pose.py`` (mir12z): bad options exit 2 with one line naming them, before any work,
and nothing is written."""

import pytest

from benchmarks.mirror_init_unpose_pose import main


def _session(tmp_path, with_truth=True):
    s = tmp_path / "S57"
    (s / "gt" / "mirror").mkdir(parents=True)
    if with_truth:
        (s / "gt" / "mirror" / "actors.npz").write_bytes(b"")
    return s


@pytest.mark.parametrize("args, phrase", [
    (["--shadow", "W"], "--shadow and --name go together"),
    (["--name", "x.npz"], "--shadow and --name go together"),
    (["--shadow", "W", "--name", "x.json"], "a plain file name ending in .npz"),
    (["--shadow", "W", "--name", "../x.npz"], "a plain file name ending in .npz"),
])
def test_bad_shadow_options_exit_2(tmp_path, capsys, args, phrase):
    s = _session(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main([str(s), *[str(tmp_path / a) if a == "W" else a for a in args]])
    assert exc.value.code == 2
    assert phrase in capsys.readouterr().err
    assert not (tmp_path / "W").exists()


def test_a_session_without_ground_truth_is_refused(tmp_path, capsys):
    s = _session(tmp_path, with_truth=False)
    with pytest.raises(SystemExit) as exc:
        main([str(s)])
    assert exc.value.code == 2
    assert "gt/mirror/actors.npz missing" in capsys.readouterr().err


def test_an_unknown_bone_is_refused(tmp_path, capsys):
    s = _session(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main([str(s), "--true-swing", "knee_l", "--shadow", str(tmp_path / "W"), "--name", "x.npz"])
    assert exc.value.code == 2
    assert "unknown bone(s) ['knee_l']" in capsys.readouterr().err
    assert not (tmp_path / "W").exists()
