"""Mutation test (issue 17) of mir12e's ``mirror.run.player_masks``: the labels are the product of the ids and the
reshaped players' mask, with no float detour (a division by the mask gives the same uint8 labels on x86 only
through inf / nan casts, with numpy's warnings)."""

import warnings

import numpy as np


def test_player_mask_labels_without_warnings_or_float_casts():
    from bodystudio.mirror.run import player_masks

    players_c = np.array([[0, 1, 2, 3], [3, 2, 1, 0]], np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        person, others, labels = player_masks(players_c, (1, 3), True)
    np.testing.assert_array_equal(labels, [[0, 1, 0, 3], [3, 0, 1, 0]])
    assert labels.dtype == np.uint8
    np.testing.assert_array_equal(others, players_c == 2)
    np.testing.assert_array_equal(person, (players_c == 1) | (players_c == 3))
