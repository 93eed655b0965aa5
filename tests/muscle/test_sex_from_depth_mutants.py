"""mus11y's sex from the depth (:mod:`bodystudio.muscle.capture`): ``held_out_depth_energy_mm``, ``model_knows_women``,
``candidate_sexes``, ``sex_from_depth_energies``, the options' margin and the ``sex_fit`` record's reader, against
hand-worked cases.

Mutation tests (issue 17, docs/mutation/muscle-capture.md, "mus11y's sex from the depth"): the energy's frames are
checked on a spy of ``depth_energy_mm`` / ``facing_frames`` (which frames, which arguments), the margins are exact in
binary, the record is read back by ``json``. A survivor here is a woman captured as a man (or the reverse) unnoticed.
Well under a second.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle import capture as C


def _opts(stride, **kw):
    return SimpleNamespace(body_rest_frame_stride=stride, sequence_min_facing_cos=0.25, norm_limit=0.125,
                           sequence_huber_m=0.0625, **kw)


@pytest.mark.parametrize("stride, expect", [(1, list(range(10))), (2, [1, 3, 5, 7, 9]), (3, [1, 4, 7]),
                                            (4, [2, 6])])
def test_held_out_energy_takes_the_frames_the_rest_fit_leaves_out(monkeypatch, stride, expect):
    seen = {}

    def facing(frames, cos):
        seen["facing"] = (list(frames), cos)
        return [f"f{k}" for k in frames]  # renamed: the energy must get the facing frames, not the input ones

    def energy(model, poses, frames, rest, joints, norm_limit, huber):
        seen["energy"] = (model, list(poses), list(frames), rest, joints, norm_limit, huber)
        return 2.5

    monkeypatch.setattr(C, "facing_frames", facing)
    monkeypatch.setattr(C, "depth_energy_mm", energy)
    poses = [f"p{k}" for k in range(10)]
    got = C.held_out_depth_energy_mm("M", poses, list(range(10)), "R", "J", _opts(stride))
    assert got == 2.5
    assert seen["facing"] == (list(range(10)), 0.25)
    assert seen["energy"] == ("M", [f"p{k}" for k in expect], [f"f{k}" for k in expect], "R", "J", 0.125, 0.0625)


def _rows(*sexes, columns=5):
    return SimpleNamespace(shape_rows=np.array([[22, 0.5, 1.7, 0.5, s, 0][:columns] for s in sexes], float))


def test_model_knows_women_reads_the_sex_column_below_one_half():
    assert C.model_knows_women(_rows(1.0, 0.25)) is True
    assert C.model_knows_women(_rows(1.0, 0.4375)) is True
    assert C.model_knows_women(_rows(1.0, 0.5)) is False  # 0.5 is not a woman's row
    assert C.model_knows_women(_rows(1.0, 0.75)) is False
    assert C.model_knows_women(_rows(0.0, 1.0, columns=6)) is True  # a sixth column does not matter
    assert C.model_knows_women(_rows(1.0, 1.0, columns=4)) is False  # no sex column
    assert C.model_knows_women(SimpleNamespace(shape_rows=None)) is False
    assert C.model_knows_women(SimpleNamespace()) is False
    assert C.model_knows_women(SimpleNamespace(shape_rows=np.zeros(5))) is False  # one dimension: no rows


def test_candidate_sexes_by_hand():
    o, off = SimpleNamespace(sex_from_depth=True), SimpleNamespace(sex_from_depth=False)
    assert C.candidate_sexes(_rows(1.0, 0.0), o) == (1.0, 0.0)
    assert C.candidate_sexes(_rows(1.0, 1.0), o) == (1.0,)
    assert C.candidate_sexes(_rows(1.0, 0.0), off) == (1.0,)
    got = C.candidate_sexes(_rows(1.0, 0.0), o, SimpleNamespace(sex=np.float32(0)))
    assert got == (0.0,) and type(got[0]) is float
    assert C.candidate_sexes(_rows(1.0, 1.0), off, SimpleNamespace(sex=1)) == (1.0,)


def test_sex_from_depth_energies_exact_margins():
    assert C.sex_from_depth_energies({1.0: 3.5, 0.0: 3.0}, 0.5) == {
        "sex": 0.0, "chosen": "female", "energy_mm": {"male": 3.5, "female": 3.0}, "margin_mm": 0.5,
        "ambiguous": True}  # 0.5 apart: within the margin, inclusive
    rec = C.sex_from_depth_energies({0.0: 3.0, 1.0: 3.5}, 0.25)
    assert rec["ambiguous"] is False and rec["sex"] == 0.0
    rec = C.sex_from_depth_energies({1.0: 3.0, 0.0: 3.5}, 0.25)  # the man's lower
    assert (rec["sex"], rec["chosen"], rec["ambiguous"]) == (1.0, "male", False)
    assert rec["energy_mm"] == {"male": 3.0, "female": 3.5}
    rec = C.sex_from_depth_energies({1.0: np.float32(3), 0.0: 4}, 1)  # numpy / int inputs: plain floats out
    assert rec["ambiguous"] is True and rec["margin_mm"] == 1.0
    assert all(type(v) is float for v in (rec["margin_mm"], rec["energy_mm"]["male"], rec["energy_mm"]["female"]))
    assert type(rec["ambiguous"]) is bool
    json.dumps(rec)  # written into params.json as it is
    assert C.sex_from_depth_energies({1.0: 3.0, 0.0: 3.0}, 0.0) == {  # a tie: a man (the paper's), ambiguous
        "sex": 1.0, "chosen": "male", "energy_mm": {"male": 3.0, "female": 3.0}, "margin_mm": 0.0, "ambiguous": True}


def test_the_margin_option():
    o = C.CaptureOptions()
    assert o.sex_from_depth is True and o.sex_margin_mm == 0.1
    assert C.CaptureOptions(sex_margin_mm=0.0).sex_margin_mm == 0.0  # 0 accepted: only a tie is ambiguous
    for bad in (-0.0625, float("nan"), -np.inf):
        with pytest.raises(InputError) as err:
            C.CaptureOptions(sex_margin_mm=bad)
        assert str(err.value) == ("sex_margin_mm must be >= 0 (the held-out depth energies' difference below which "
                                  f"the sex from the depth is ambiguous), got {bad}")


def _capture(sex_fit):
    V = np.array([[[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]], float)
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])
    return C.ArmCapture(V, F, [None], None, (1.0, np.eye(3), np.zeros(3)), "nicp", "k", sex_fit=sex_fit)


def test_the_sex_fit_record_written_and_read(tmp_path):
    rec = {"sex": 1.0, "chosen": "male", "energy_mm": {"male": 3.0, "female": 3.5}, "margin_mm": 0.25,
           "ambiguous": False}
    out = C.write_arm_capture(tmp_path / "a", _capture(rec))
    params = json.loads((out / "params.json").read_text())
    assert params["sex_fit"] == rec
    assert C.load_arm_capture(out).sex_fit == rec
    none = C.write_arm_capture(tmp_path / "b", _capture(None))
    assert json.loads((none / "params.json").read_text())["sex_fit"] is None
    assert C.load_arm_capture(none).sex_fit is None
    params = json.loads((none / "params.json").read_text())
    del params["sex_fit"]  # a capture written before mus11y
    (none / "params.json").write_text(json.dumps(params))
    assert C.load_arm_capture(none).sex_fit is None
    for bad in ([1.0], 0.0):
        (none / "params.json").write_text(json.dumps({**params, "sex_fit": bad}))
        with pytest.raises(FileFormatError) as err:
            C.load_arm_capture(none)
        assert f"ValueError: sex_fit {bad!r} is not a record" in str(err.value) and str(none) in str(err.value)
