"""The joint-distance term on the stature's pairs only (mir12ad, ``bone_length_pairs``, ``init.STATURE_BONE_PAIRS``):
the thighs, shins, spine, neck and head, the SDK's distances between the floor and the top of the head.

On the 2k statistical model (cached by test_init_bone_lengths.py's loader): the init hands the fit the SDK's means
and per-frame weights of the selected pairs only (the others NaN, weight 0), all pairs with None (the default);
unknown pairs are refused; and a fit that sees only the front of the torso gets the planted body's legs, spine, neck
and head from the stature pairs, and only those (a planted bug that drops the selection, or
keeps the pairs but zeroes their weight, fails one of these).
"""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import BONE_PAIRS, STATURE_BONE_PAIRS, selected_bone_pairs
from tests.mirror.test_init_bone_lengths import (
    _distances,
    _front_torso_fit,
    _joints,
    _model_2k,
    _planted,
    _recorded_bone_length_fits,
)


@pytest.fixture(scope="module")
def model():
    return _model_2k()


def test_the_selection_names_pairs_of_bone_pairs_in_either_order():
    assert selected_bone_pairs(None).all() and len(selected_bone_pairs(None)) == len(BONE_PAIRS)
    keep = selected_bone_pairs(STATURE_BONE_PAIRS)
    assert [BONE_PAIRS[i] for i in np.flatnonzero(keep)] == [p for p in BONE_PAIRS if p in STATURE_BONE_PAIRS]
    assert keep.sum() == 7 and not keep[0] and not keep[5]  # no shoulder or hip width
    assert selected_bone_pairs([("KneeLeft", "HipLeft")]).sum() == 1
    for bad in ([("KneeLeft", "WristLeft")], [("KneeLeft",)], ["KneeLeft"], [("Head", "Head", "Neck")]):
        with pytest.raises(InputError, match="bone_length_pairs"):
            selected_bone_pairs(bad)


def test_the_init_passes_only_the_selected_pairs(model, monkeypatch):
    J, obs, seen = _recorded_bone_length_fits(model, monkeypatch)
    keep = selected_bone_pairs(STATURE_BONE_PAIRS)
    init_mod.initialise_from_observations(obs, model, passes=1, max_frames=4, bone_length_weight=3.0,
                                          bone_length_pairs=STATURE_BONE_PAIRS)
    lengths, weight = seen[0]
    np.testing.assert_allclose(lengths[keep], _distances(J)[keep], atol=1e-9)
    assert np.isnan(lengths[~keep]).all()
    np.testing.assert_allclose(weight, np.where(keep, 3.0 * 12, 0.0))
    init_mod.initialise_from_observations(obs, model, passes=1, max_frames=4, bone_length_weight=3.0)
    np.testing.assert_allclose(seen[1][0], _distances(J), atol=1e-9)  # None: every pair
    with pytest.raises(InputError, match="bone_length_pairs"):
        init_mod.initialise_from_observations(obs, model, passes=1, bone_length_weight=3.0,
                                              bone_length_pairs=[("Head", "WristLeft")])
    assert init_mod.BONE_LENGTH_PAIRS is None and init_mod.BONE_LENGTH_WEIGHT == 0.0  # off by default


def test_the_stature_pairs_pin_the_legs_and_spine_the_torso_front_does_not_show(model):
    """Only the torso's front is seen: with the stature pairs' distances the legs, spine, neck and head come within
    1 mm of the planted body's (> 4 mm without); the pairs left out (shoulder and hip width, arms) are not pinned."""
    c_true = _planted(model, seed=9, scale=1.5)
    truth = _distances(_joints(model, c_true))
    keep = selected_bone_pairs(STATURE_BONE_PAIRS)
    without = _front_torso_fit(model, c_true, 0.0, truth)
    stature = _front_torso_fit(model, c_true, 30.0, np.where(keep, truth, np.nan))
    every = _front_torso_fit(model, c_true, 30.0, truth)
    err = {k: np.abs(_distances(_joints(model, x)) - truth) for k, x in
           (("without", without), ("stature", stature), ("every", every))}
    assert err["without"][keep].mean() > 0.004, err["without"][keep]
    assert err["stature"][keep].mean() < 0.001 and err["stature"][keep].mean() < 0.2 * err["without"][keep].mean()
    assert err["every"][~keep].mean() < 0.5 * err["stature"][~keep].mean()  # the others stay the prior's
