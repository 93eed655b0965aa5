"""``benchmarks/mirror_refine_end_to_end.py``'s ``refine-before-mir12ae`` run (mir12ae): the run before E_upright and
the running posture became its default, set only while the run lasts and put back after a failing one; an unknown
run is refused by name before any session is opened."""

import sys

import pytest

from benchmarks import mirror_refine_end_to_end as bench
from bodystudio.mirror import refine
from bodystudio.mirror import run as run_mod


def test_the_run_before_mir12ae_is_set_while_it_lasts_and_put_back_after_a_failure():
    before = (run_mod.PELVIS_TILT_RAD, run_mod.POSTURE_BONES)
    assert before == (refine.PELVIS_TILT_RAD, ("spine_02", "neck_01", "head"))  # the defaults since mir12ae
    with pytest.raises(RuntimeError), bench._refine_as("refine-before-mir12ae"):
        assert run_mod.PELVIS_TILT_RAD is None and run_mod.POSTURE_BONES == ()
        assert run_mod.refine_weights(1).pelvis_tilt_rad is None
        raise RuntimeError("a failing run")
    assert (run_mod.PELVIS_TILT_RAD, run_mod.POSTURE_BONES) == before
    with bench._refine_as("refine"):  # the plain run is the default's
        assert (run_mod.PELVIS_TILT_RAD, run_mod.POSTURE_BONES) == before


def test_an_unknown_run_is_refused_before_any_session(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["mirror_refine_end_to_end.py", "--runs", "refine-before-mir12zz",
                                      "--out", str(tmp_path / "o"), str(tmp_path / "S")])
    with pytest.raises(SystemExit) as exit_:
        bench.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "refine-before-mir12zz" in err and "refine-before-mir12ae" in err
    assert not (tmp_path / "o").exists()
