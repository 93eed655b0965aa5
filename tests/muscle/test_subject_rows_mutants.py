"""mus11p's ``subject_rows`` (issue 17): :func:`bodystudio.muscle.model.training_rows_per_subject` on stand-in models
(the median over the training subjects of their stored shape rows, exact-row matching, rounding, the floor of 1) and
``extend_arm_model(subject_rows=)``'s refusal and pass-through with ``_add_subjects`` recorded. Each test < 0.1 s.
"""
from __future__ import annotations

from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.muscle.model as M
from bodystudio.errors import InputError
from bodystudio.muscle.model import ArmShapeParams, training_rows_per_subject


def _shape(bmi, sex=1.0):
    return {"bmi": bmi, "muscularity": 0.5, "height_m": 1.8, "arm_length_m": 0.6, "sex": sex}


def _row(d):
    return ArmShapeParams.from_dict(d).as_row()


def _model(entries, extra_rows=()):
    """``entries``: (source, shape dict or None, rows stored); the rows in that order, then ``extra_rows``."""
    subjects, rows = [], []
    for k, (source, shape, n) in enumerate(entries):
        subjects.append({"name": f"s{k}", "source": source, "shape": shape})
        rows += [_row(shape)] * n if n else []
    rows += list(extra_rows)
    return NS(subjects=subjects, shape_rows=np.array(rows).reshape(-1, 5))


def test_median_of_the_training_subjects_rows():
    m = _model([("training", _shape(20), 3), ("training", _shape(22), 3), ("training", _shape(24), 1),
                ("capture", _shape(26), 5), ("ground truth", _shape(27), 4)])
    assert training_rows_per_subject(m) == 3
    # a subject of another source or without a (complete) shape is not counted
    m = _model([("training", _shape(20), 2), ("capture", _shape(26), 9), ("training", None, 0),
                ("training", {"bmi": 30.0}, 0)], extra_rows=[_row(_shape(30))] * 7)
    m.subjects[3]["shape"] = {"bmi": 30.0, "muscularity": 0.5, "height_m": 1.8}  # no arm length
    assert training_rows_per_subject(m) == 2
    assert type(training_rows_per_subject(m)) is int
    # the subjects skipped come first: the ones after them still count
    m = _model([("capture", _shape(26), 1), ("training", None, 0), ("training", _shape(20), 3),
                ("training", _shape(21), 3)])
    assert training_rows_per_subject(m) == 3


def test_rounding_floor_and_no_training_subject():
    assert training_rows_per_subject(_model([("training", _shape(20), 1), ("training", _shape(22), 2)])) == 2  # 1.5
    assert training_rows_per_subject(_model([("training", _shape(20), 2), ("training", _shape(22), 5),
                                             ("training", _shape(23), 4), ("training", _shape(24), 5)])) == 4  # 4.5
    assert training_rows_per_subject(_model([("capture", _shape(20), 4)])) == 1
    assert training_rows_per_subject(_model([])) == 1
    # a training subject whose row is not stored counts 0 rows: at least 1
    assert training_rows_per_subject(_model([("training", _shape(20), 0)], extra_rows=[_row(_shape(21))])) == 1
    assert training_rows_per_subject(_model([("training", _shape(20), 0), ("training", _shape(21), 0),
                                             ("training", _shape(22), 3)])) == 1


def test_rows_match_exactly_within_1e_12_and_by_sex():
    d = _shape(20)
    r = _row(d)
    near, far = r + [5e-13, 0, 0, 0, 0], r + [0, 0, 0, 2e-12, 0]
    assert training_rows_per_subject(_model([("training", d, 1)], extra_rows=[near, near, far])) == 3
    other_sex = _row(_shape(20, sex=0.0))
    assert training_rows_per_subject(_model([("training", d, 2)], extra_rows=[other_sex] * 3)) == 2
    woman = _shape(20, sex=0.0)
    edge = _row(woman) + [0, 0, 0, 0, 1e-12]  # exactly the tolerance (1e-12 - 0.0): counted
    assert training_rows_per_subject(_model([("training", woman, 0)], extra_rows=[edge] * 3)) == 3


def _extend(monkeypatch):
    """``extend_arm_model``'s helpers replaced; the keywords ``_add_subjects`` gets (a helper, not a fixture: the
    direct mutant recheck calls the tests with a fresh monkeypatch only)."""
    seen = []
    monkeypatch.setattr(M, "_check_samples", lambda captures, n: None)
    monkeypatch.setattr(M, "with_shape_form", lambda model, form: model)
    monkeypatch.setattr(M, "body_space_for_model", lambda model: "space")
    monkeypatch.setattr(M, "_add_subjects", lambda *a, **kw: seen.append(kw) or "extended")
    return seen


def test_extend_passes_subject_rows_and_defaults_to_own(monkeypatch):
    extend = _extend(monkeypatch)
    model = NS(n_vertices=4, shape_form="linear")
    assert M.extend_arm_model(model, []) == "extended"
    assert extend[-1]["subject_rows"] == "own" and extend[-1]["prior_weight"] == M.EXTENSION_ROW_PRIOR_WEIGHT == 30.0
    assert extend[-1]["weight_prior_weight"] == M.EXTENSION_ROW_WEIGHT_PRIOR_WEIGHT == 3.0
    M.extend_arm_model(model, [], prior_weight=0.25, subject_rows="training")
    assert extend[-1]["prior_weight"] == 0.25 and extend[-1]["subject_rows"] == "training"
    for rows in ("own", "training"):
        M.extend_arm_model(model, [], subject_rows=rows)
        assert extend[-1]["subject_rows"] == rows


@pytest.mark.parametrize("bad", ["twice", "Training", "", None])
def test_extend_refuses_other_subject_rows(monkeypatch, bad):
    extend = _extend(monkeypatch)
    with pytest.raises(InputError, match=rf"^subject_rows={bad!r} must be one of own, training$"):
        M.extend_arm_model(NS(n_vertices=4, shape_form="linear"), [], subject_rows=bad)
    assert extend == []
