"""``bodystudio garment fit --clothing-mm MM`` / ``--no-shape-refinement`` (the final shape refinement, gar13c) /
``--no-pose-refinement`` (the poses refined on the refined shape, gar13d):
a thickness outside 0-30 mm or not a number is refused in one line before any work, nothing written; valid
values reach the fit."""

from __future__ import annotations

import pytest

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory):
    from bodystudio.garment.synthetic import synth_garment_session

    out = tmp_path_factory.mktemp("gshape_in") / "s"
    synth_garment_session(out, subject_seed=2, n_frames=2, resolution=(96, 128), template="2k", texture_size=32,
                          shadows=False)
    return out


@pytest.mark.parametrize("mm", ["-1", "31", "nan", "inf"])
def test_clothing_thickness_out_of_range(tiny_session, tmp_path, capfd, mm):
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--clothing-mm", mm], capfd)
    assert_clean_error(r, 2, "--clothing-mm")
    assert not (tmp_path / "o").exists()


def test_clothing_thickness_not_a_number(tiny_session, tmp_path, capfd):
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o",
                       "--clothing-mm", "thick"], capfd)
    assert r.rc == 2 and "Traceback" not in r.text
    assert not (tmp_path / "o").exists()


def test_api_refuses_before_any_work(tmp_path):
    from bodystudio.errors import InputError
    from bodystudio.garment.fit import fit_garment_video

    with pytest.raises(InputError, match="between 0 and 30"):
        fit_garment_video(tmp_path / "missing.mp4", 1.7, tmp_path / "o", clothing_allowance_m=0.05)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, refine, allowance, poses", [([], True, None, True),
                                                            (["--no-shape-refinement"], False, None, True),
                                                            (["--no-pose-refinement"], True, None, False),
                                                            (["--clothing-mm", "4"], True, 0.004, True),
                                                            (["--clothing-mm", "0"], True, 0.0, True)])
def test_options_reach_the_fit(tiny_session, tmp_path, capfd, monkeypatch, args, refine, allowance, poses):
    import bodystudio.garment.fit as gf

    seen = {}

    def fake(source, stature, out, **kw):
        seen.update(kw)
        raise gf.InputError("stop here")

    monkeypatch.setattr(gf, "fit_garment_video", fake)
    r = run_inprocess(["garment", "fit", tiny_session, "--stature", "1.7", "--out", tmp_path / "o", *args], capfd)
    assert_clean_error(r, 2, "stop here")
    assert seen["shape_refinement"] is refine and seen["pose_refinement"] is poses
    assert seen["clothing_allowance_m"] == (None if allowance is None else pytest.approx(allowance))
