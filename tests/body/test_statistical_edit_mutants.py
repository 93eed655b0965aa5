"""The semantic edit's refusal and step halving (Eq. 4 of Real-time Reshaping, then Newton on the mesh) pinned on
stand-ins: the refusal's threshold, sign and message with a planted residual, and the halved steps' trial points on
a one-attribute toy whose full step and its halves all raise the residual (issue 17, mutQ)."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.body.statistical import (
    _FD_STEP,
    _REACH_FACTOR,
    _TOLERANCE,
    MESH_ATTRIBUTE_NAMES,
    StatisticalBodyModel,
    load_statistical_model,
)
from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def sm():
    return load_statistical_model(resolution="2k", progress=False)


def _planted(sm, monkeypatch, off_units, sign=1.0, name="hip_m"):
    """``_match_measured`` returning the start unchanged and ``targets - measured`` ``off_units`` reach units on
    ``name`` (0 on the rest)."""
    calls = []

    def fake(self, c, targets, iterations=5, with_residual=False):
        calls.append(dict(targets))
        r = np.array([sign * off_units * _REACH_FACTOR * _TOLERANCE[n] if n == name else 0.0 for n in targets])
        return (c, r) if with_residual else c

    monkeypatch.setattr(StatisticalBodyModel, "_match_measured", fake)
    return calls


@pytest.mark.parametrize("off_units, refused", [(0.9, False), (1.5, True)])
def test_an_edit_ending_more_than_the_reach_off_is_refused(sm, monkeypatch, off_units, refused):
    """Five tolerances is the line: 0.9 of it returned, 1.5 of it refused (a doubled threshold would return it)."""
    _planted(sm, monkeypatch, off_units)
    c0 = np.zeros(sm.n_components)
    if refused:
        with pytest.raises(InputError, match="hip_m ends"):
            sm.edit(c0, {"stature_m": 0.01})
    else:
        np.testing.assert_array_equal(sm.edit(c0, {"stature_m": 0.01}), c0 + np.eye(len(sm.attribute_names))[
            sm.attribute_names.index("stature_m")] * 0.01 @ sm.semantic_directions)


def test_the_refusal_names_how_far_the_body_ends_from_its_target_signed_measured_minus_target(sm, monkeypatch):
    _planted(sm, monkeypatch, 2.0, sign=1.0)  # measured below the target: ends -2 * 5 * 2 mm = -0.02 m off
    with pytest.raises(InputError, match=r"hip_m ends -0\.02 off its target; use a smaller edit") as e:
        sm.edit(np.zeros(sm.n_components), {"stature_m": 0.01})
    assert "the other measurements held" in str(e.value)


def test_one_newton_step_is_checked_too(sm, monkeypatch):
    """``iterations=1`` is a Newton edit: refused like the default's; only 0 (the linear step alone) is not."""
    _planted(sm, monkeypatch, 2.0)
    with pytest.raises(InputError, match="not reachable"):
        sm.edit(np.zeros(sm.n_components), {"stature_m": 0.01}, iterations=1)
    sm.edit(np.zeros(sm.n_components), {"stature_m": 0.01}, iterations=0)


def test_follow_mode_matches_only_the_named_attributes_and_says_following(sm, monkeypatch):
    calls = _planted(sm, monkeypatch, 2.0, name="mass_kg")
    with pytest.raises(InputError, match="following: mass_kg ends"):
        sm.edit(np.zeros(sm.n_components), {"mass_kg": 5.0, "stature_m": 0.0}, others="follow")
    assert list(calls[-1]) == [n for n in MESH_ATTRIBUTE_NAMES if n in ("mass_kg", "stature_m")]
    calls = _planted(sm, monkeypatch, 0.0)
    c = sm.edit(np.zeros(sm.n_components), {"mass_kg": 5.0}, others="follow")
    np.testing.assert_allclose(c, sm._conditional_change({"mass_kg": 5.0}) @ sm.semantic_directions)
    assert list(calls[-1]) == ["mass_kg"]


def test_an_unknown_others_mode_is_one_line_naming_the_valid_ones(sm):
    for bad in ("FOLLOW", "free"):
        with pytest.raises(InputError, match=r"others='.*'; valid: held, follow"):
            sm.edit(np.zeros(sm.n_components), {"mass_kg": 1.0}, others=bad)


def _toy(f):
    """A one-attribute stand-in of the model for ``_match_measured``: stature = f(c[0]); records every measurement."""
    seen = []

    def mesh_attributes(c, names):
        seen.append(float(c[0]))
        return np.array([f(float(c[0]))])

    return SimpleNamespace(semantic_directions=np.array([[1.0]]), attribute_names=["stature_m"],
                           _mesh_attributes=mesh_attributes), seen


def test_a_step_raising_the_residual_is_halved_three_times_then_the_start_is_kept():
    """f = c^2 + 1 towards 0.5 from c = 0: the finite-difference slope is h, the full step -0.5 / h and every half of
    it lands far above; the trial points are exactly 1, 1/2, 1/4, 1/8 of the step and the start is returned."""
    toy, seen = _toy(lambda x: x * x + 1.0)
    c, r = StatisticalBodyModel._match_measured(toy, np.array([0.0]), {"stature_m": 0.5}, with_residual=True)
    h = _FD_STEP["stature_m"]
    step = (0.5 - 1.0) / ((h * h + 1.0 - 1.0) / h)
    assert seen[:2] == [0.0, h]
    np.testing.assert_allclose(seen[2:], [step, step / 2, step / 4, step / 8], rtol=1e-9)
    assert c[0] == 0.0 and r[0] == pytest.approx(-0.5)


def test_the_first_lowering_fraction_is_taken_and_the_iteration_stops_at_the_tolerance():
    """f = atan(c) towards 0 from c = 1.5 (Newton on atan overshoots beyond 1.39): the full step raises the residual,
    the half step is taken; a body already within tolerance is measured once and returned as it is."""
    toy, seen = _toy(np.arctan)
    c = StatisticalBodyModel._match_measured(toy, np.array([1.5]), {"stature_m": 0.0}, iterations=1)
    h = _FD_STEP["stature_m"]
    step = -np.arctan(1.5) / ((np.arctan(1.5 + h) - np.arctan(1.5)) / h)
    assert abs(np.arctan(1.5 + step)) > np.arctan(1.5) > abs(np.arctan(1.5 + step / 2))
    np.testing.assert_allclose(seen[2:], [1.5 + step, 1.5 + step / 2], rtol=1e-12)
    assert c[0] == pytest.approx(1.5 + step / 2, rel=1e-12)
    toy, seen = _toy(np.arctan)
    out = StatisticalBodyModel._match_measured(toy, np.array([0.2]), {"stature_m": float(np.arctan(0.2)) + 1e-4})
    assert seen == [0.2] and out[0] == 0.2
    assert not isinstance(StatisticalBodyModel._match_measured(toy, np.array([0.2]), {"stature_m": 0.0}), tuple)
