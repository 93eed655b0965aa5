"""A bad E_upright scale (mir12ad, ``RefineWeights.pelvis_tilt_rad`` / ``run.PELVIS_TILT_RAD``) is one InputError
naming the field, raised before the refinement touches its inputs; None and a positive number pass (the run's default
since mir12ae: refine.PELVIS_TILT_RAD)."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror import run
from bodystudio.mirror.refine import PELVIS_TILT_RAD, RefineWeights, refine_pose


@pytest.mark.parametrize("bad", [0.0, -0.1, float("nan"), float("inf"), True, "3", np.array([0.05])])
def test_a_bad_scale_is_one_input_error_before_any_work(bad):
    with pytest.raises(InputError, match="pelvis_tilt_rad") as info:
        refine_pose(None, None, None, None, None, weights=RefineWeights(pelvis_tilt_rad=bad))
    assert "\n" not in str(info.value)


def test_on_in_the_run_by_default_and_the_run_passes_its_scale(monkeypatch):
    """The run holds the pelvis upright at refine.PELVIS_TILT_RAD by default since mir12ae (RefineWeights' own
    default stays off); None takes the term out, another scale is passed as it is, for one and two players."""
    assert RefineWeights().pelvis_tilt_rad is None
    assert run.PELVIS_TILT_RAD == PELVIS_TILT_RAD
    assert run.refine_weights(1).pelvis_tilt_rad == PELVIS_TILT_RAD
    assert run.refine_weights(2).pelvis_tilt_rad == PELVIS_TILT_RAD
    monkeypatch.setattr(run, "PELVIS_TILT_RAD", None)
    assert run.refine_weights(1).pelvis_tilt_rad is None and run.refine_weights(2).pelvis_tilt_rad is None
    monkeypatch.setattr(run, "PELVIS_TILT_RAD", PELVIS_TILT_RAD / 2)
    assert run.refine_weights(1).pelvis_tilt_rad == PELVIS_TILT_RAD / 2
    assert run.refine_weights(2).pelvis_tilt_rad == PELVIS_TILT_RAD / 2
    assert run.refine_weights(1).depth_samples == run.REFINE_DEPTH_SAMPLES_ONE_PLAYER
