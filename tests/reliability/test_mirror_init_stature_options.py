"""``benchmarks/mirror_init_stature.py`` (mir12ad): a bad ``--weight`` or a folder that is not a synthetic mirror
session exits 2 with one line naming it, before the model is loaded or anything is written."""

import sys

import pytest

from benchmarks import mirror_init_stature


def _bench(monkeypatch, capsys, *args):
    monkeypatch.setattr(sys, "argv", ["mirror_init_stature.py", *args])
    with pytest.raises(SystemExit) as exit_:
        mirror_init_stature.main()
    return exit_.value.code, capsys.readouterr().err


@pytest.mark.parametrize("weight", ["0", "-1", "nan", "inf"])
def test_a_bad_weight_is_refused(tmp_path, monkeypatch, capsys, weight):
    code, err = _bench(monkeypatch, capsys, "--weight", weight, "--write", "x.npz", str(tmp_path))
    assert code == 2 and f"--weight {float(weight)}: give a number > 0" in err
    assert len([line for line in err.splitlines() if "error:" in line]) == 1  # argparse's usage, then one error line
    assert list(tmp_path.iterdir()) == []


def test_a_folder_that_is_not_a_session_is_refused(tmp_path, monkeypatch, capsys):
    (tmp_path / "S" / "mirror").mkdir(parents=True)
    code, err = _bench(monkeypatch, capsys, "--write", "x.npz", str(tmp_path / "S"))
    assert code == 2
    assert f"{tmp_path / 'S'}: not a synthetic mirror session (no gt/mirror/actors.npz)" in err
    assert list((tmp_path / "S" / "mirror").iterdir()) == []
