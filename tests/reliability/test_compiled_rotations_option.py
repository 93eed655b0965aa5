"""``TrackParams(compiled_rotations=...)`` (rec15j): the tracker hands the option to its pose refinement; off by
default."""

import numpy as np
import pytest

from bodystudio.reconstruct import tracking
from bodystudio.reconstruct.articulated_fit import PoseRefineParams


@pytest.mark.parametrize("value", [False, True])
def test_the_tracker_passes_the_option_to_its_refinement(monkeypatch, value):
    seen = {}

    def refine(body, previous, hull, params, data_term=None, anchors=None):
        seen["params"] = params
        return previous

    monkeypatch.setattr(tracking, "refine_bone_transforms", refine)
    monkeypatch.setattr(tracking, "silhouette_data_term", lambda fields, params: None)
    T = np.tile(np.eye(4), (3, 1, 1))
    tracking.track_bone_transforms(None, T, None, tracking.TrackParams(compiled_rotations=value))
    assert seen["params"].compiled_rotations is value


def test_off_by_default():
    assert tracking.TrackParams().compiled_rotations is False
    assert PoseRefineParams().compiled_rotations is False
