"""Mutation-testing gaps of gar13f's flow arbitration (issue 17, mutK): ``arbitrate_flow_correction``'s threshold
(a worn-garment probability of exactly 0.5 is not "the video sees the worn garment", the docstring's ``> 0.5``) and
the wiring of ``refine_and_composite`` that chooses the region and the colours between the two hypotheses. Toy
frames of two flat colours, as in test_flow_arbitration.py (seconds)."""

import numpy as np

from bodystudio.garment import refine


def test_a_probability_of_exactly_one_half_is_not_the_worn_garment():
    corrected = np.array([[True, True, False]])
    uncorrected = np.array([[False, False, True]])
    person = np.ones((1, 3), bool)
    prob = np.array([[0.5, 0.5000001, 0.5]])
    out = refine.arbitrate_flow_correction(corrected, uncorrected, prob, person)
    assert out.tolist() == [[False, True, False]]
