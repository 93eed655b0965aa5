"""The target skeleton's two paths (bodystudio.mirror.reshape.target_skeleton; issue 17, second round, after the
model-joint path of 749c0fe): the model path needs both the model and the target coefficients (either alone is
Eq. 3), and the skeleton it returns keeps the source's bone names, parents and rest rolls."""

import numpy as np
import pytest

from bodystudio.body import build_body
from bodystudio.body.population import sample_population
from bodystudio.mirror.init import SourceBody, refit_skeleton
from bodystudio.mirror.reshape import target_coeffs, target_skeleton


@pytest.fixture(scope="module")
def model_source(model_6k):
    c = model_6k.project(build_body(*sample_population(1, seed=5)[0], resolution="6k").vertices)
    return SourceBody(c, model_6k.vertices(c), refit_skeleton(model_6k, c), (0,), 0.0, model_6k.weights, model_6k.faces)


def test_the_model_path_needs_the_model_and_the_coefficients_and_keeps_the_rig(model_6k, model_source):
    c_t = target_coeffs(model_6k, model_source.coeffs, {"taller": 0.12})
    V_t = model_6k.vertices(c_t)
    by_eq3 = target_skeleton(model_source, V_t)
    for sk in (target_skeleton(model_source, V_t, model_6k), target_skeleton(model_source, V_t, None, c_t)):
        np.testing.assert_array_equal(sk.heads, by_eq3.heads)  # either alone: Eq. 3
        np.testing.assert_array_equal(sk.tails, by_eq3.tails)
    moved = target_skeleton(model_source, V_t, model_6k, c_t)
    src = model_source.skeleton
    assert np.abs(moved.heads - by_eq3.heads).max() > 1e-4  # the model path is another skeleton
    assert moved.bone_names == src.bone_names and np.array_equal(moved.parents, src.parents)
    np.testing.assert_array_equal(moved.rolls, src.rolls)
    assert by_eq3.bone_names == src.bone_names and np.array_equal(by_eq3.rolls, src.rolls)
