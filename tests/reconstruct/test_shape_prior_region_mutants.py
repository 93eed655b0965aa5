"""Mutation tests of rec15p / rec15q's region blend and rim reach (docs/mutation/reconstruct-shape_prior.md,
"rec15p-q region and reach"): the default fall-off, ``lower_torso`` joined to other regions, a vertex exactly at the
``spine_02`` tail, and a rim list handed as a plain Python list. Stand-in strips only (< 0.1 s)."""
from types import SimpleNamespace as NS

import numpy as np

from bodystudio.reconstruct.shape_prior import region_blend_weights, rim_reach
from tests.reconstruct.test_shape_prior_carried import _strip


def test_the_default_falloff_is_four_rings():
    V, F = _strip()
    body = NS(vertices=V, faces=F)
    regions = np.array(["crotch"] * 6 + ["legs"] * 18, dtype=object)
    w = region_blend_weights(body, regions, ("crotch",))
    np.testing.assert_array_equal(w, region_blend_weights(body, regions, ("crotch",), falloff_rings=4))
    col = w.reshape(-1, 2)
    assert np.all(col[3:7] > 0.0) and np.all(col[7:] == 0.0)  # column 7 is 5 rings out: 0 only with 4 rings


def test_lower_torso_joins_the_other_regions_and_a_vertex_at_the_tail_is_not_below_it():
    V, F = _strip()
    V[:, 1] = np.repeat(np.linspace(0.9, 1.4, 12), 2)
    top = V[8, 1]  # column 4's height exactly: the spine_02 tail
    skel = NS(bone_names=("pelvis", "spine_02"), tails=np.array([[0, 0.95, 0], [0, top, 0]]))
    body = NS(vertices=V, faces=F, skeleton=skel)
    regions = np.array(["head"] * 2 + ["torso"] * 20 + ["head"] * 2, dtype=object)
    w = region_blend_weights(body, regions, ("head", "lower_torso"), falloff_rings=0)
    expected = (regions == "head") | ((regions == "torso") & (V[:, 1] < top))
    np.testing.assert_array_equal(w == 1.0, expected)
    assert w[8] == 0.0 and w[6] == 1.0 and w[0] == 1.0 and w[-1] == 1.0


def test_rim_reach_takes_a_plain_list_of_vertices():
    patch = np.zeros(10, dtype=bool)
    patch[[1, 3, 5, 7]] = True
    assert rim_reach([], patch) == 0.0  # no pair at all (a frame whose rims were all refused)
    assert rim_reach([1, 3, 3, 9], patch) == 0.5
