"""``CaptureOptions.shape_prior_weight`` (mus12a: the fitted shape's population prior, on by default): a bad weight is
refused in one line naming the field and the fix; a model without a spread to take the prior from fits as before."""

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.muscle.capture import CaptureOptions
from bodystudio.muscle.refine import population_shape_prior


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("-inf")])
def test_a_bad_weight_is_refused_in_one_line(bad):
    with pytest.raises(InputError) as err:
        CaptureOptions(shape_prior_weight=bad)
    message = str(err.value)
    assert "\n" not in message and "shape_prior_weight must be >= 0" in message and "0: no prior" in message


def test_zero_turns_the_prior_off_and_the_default_is_on():
    assert CaptureOptions(shape_prior_weight=0.0).shape_prior_weight == 0.0
    assert CaptureOptions().shape_prior_weight == pytest.approx(0.1)


def test_a_model_of_one_subject_gives_no_prior_rather_than_an_error():
    model = SimpleNamespace(shape_rows=np.tile([21.0, 0.5, 1.7, 0.48, 1.0], (3, 1)))  # one subject, three rows
    mean, sigma = population_shape_prior(model, 1.0, 0.48)
    assert np.isinf(sigma).all() and mean.shape == (4,)
