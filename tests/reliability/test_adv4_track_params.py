"""``TrackParams`` (the tracked frame's fit, API) at and beyond its ranges (adversarial pass 4).

Its lost-track thresholds and ``tau_px`` were range-checked, the fit's own terms were not: ``robust_m=0`` gave every
silhouette residual Huber weight 0 (``articulated_fit._huber_weights``), so each tracked frame kept the previous
frame's pose, and a negative ``prior_weight`` / ``joint_weight`` / ``inside_weight`` pushed the fit away from its
prior, the joints or the hull, all with exit 0. Each is now refused in one line naming the field and its range."""

from __future__ import annotations

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.reconstruct.articulated_fit import _huber_weights
from bodystudio.reconstruct.tracking import TrackParams


@pytest.mark.parametrize("field, value", [("robust_m", 0.0), ("robust_m", -0.03), ("robust_m", np.nan),
                                          ("prior_weight", -0.05), ("joint_weight", -1.0),
                                          ("inside_weight", -0.5), ("inside_m", -0.1), ("outside_px", -2.0),
                                          ("outside_px", np.inf)])
def test_the_fits_terms_out_of_range_are_refused(field, value):
    with pytest.raises(InputError, match=rf"^tracking {field} \S+ is out of range; use a value in \["):
        TrackParams(**{field: value})


def test_the_range_edges_are_accepted_and_robust_m_zero_was_the_identity():
    for field, value in (("robust_m", 1e-4), ("robust_m", 1.0), ("prior_weight", 0.0), ("joint_weight", 0.0),
                         ("inside_weight", 0.0), ("inside_m", 0.0), ("outside_px", 0.0)):
        assert getattr(TrackParams(**{field: value}), field) == value
    # why 0 is refused: every non-zero residual weighs nothing, the Gauss-Newton step is zero
    assert not np.any(_huber_weights(np.array([0.001, -0.02, 0.3]), 0.0))
