"""The tracked run's default shape prior (rec15p / rec15q, docs/reconstruct.md): ``shape_prior="auto"`` is
``TRACKED_SHAPE_PRIOR`` (the carried prior gated by the rims' reach on the back, the crotch kept the template's) with
tracking and ``off`` without; a prior asked for by name keeps its own gate and region."""

import numpy as np
import pytest

from bodystudio.reconstruct import sequence as seq
from bodystudio.reconstruct.sequence import TRACKED_SHAPE_PRIOR, resolve_shape_prior


def test_the_tracked_default_is_the_gated_carried_prior_without_the_crotch():
    assert TRACKED_SHAPE_PRIOR == {"shape_prior": "carried", "shape_prior_reach": 0.4,
                                   "shape_prior_region": "head+torso+arms+hands+legs+feet"}
    assert resolve_shape_prior(True) == ("carried", 0.4, "head+torso+arms+hands+legs+feet")
    assert resolve_shape_prior(True, "auto", None, None) == resolve_shape_prior(True)


def test_without_tracking_auto_is_off():
    assert resolve_shape_prior(False) == ("off", 0.0, "all")


@pytest.mark.parametrize(("tracking", "args", "expected"), [
    (True, ("auto", 0.7, None), ("carried", 0.7, "head+torso+arms+hands+legs+feet")),
    (True, ("auto", None, "all"), ("carried", 0.4, "all")),
    (True, ("auto", 0.0, "all"), ("carried", 0.0, "all")),
    (True, ("carried", None, None), ("carried", 0.0, "all")),  # by name: ungated, everywhere (rec15p's option)
    (True, ("off", None, None), ("off", 0.0, "all")),
    (False, ("frame", None, "torso"), ("frame", 0.0, "torso")),
    (False, ("run", 0.3, None), ("run", 0.3, "all")),  # left for the run's own check to refuse
])
def test_given_settings_win(tracking, args, expected):
    assert resolve_shape_prior(tracking, *args) == expected


@pytest.mark.parametrize("tracking", [True, False])
def test_the_frames_loop_runs_and_records_the_resolved_setting(monkeypatch, tmp_path, tracking):
    """reconstruct_frames with no shape prior given: the tracked run gates the carried prior by the back's reach
    (fits only where the rims reach less than 0.4) on the crotch-free regions, the per-frame run fits nothing."""
    from tests.reconstruct.test_shape_prior_carried import _carried_run

    reaches = iter([0.6, 0.2, 0.7, 0.1, 0.3])
    monkeypatch.setattr(seq, "back_patch", lambda body: np.ones(4, dtype=bool))
    monkeypatch.setattr(seq, "rim_reach", lambda vertices, patch: next(reaches))
    _rec, fits, poses, writer = _carried_run(monkeypatch, tmp_path, tracking=tracking, reach=None, prior="auto",
                                          region=None)
    meta = {k: v for k, v in writer.meta.items() if k in ("shape_prior", "shape_prior_reach", "shape_prior_region")}
    if tracking:
        assert meta == {"shape_prior": "carried", "shape_prior_reach": 0.4,
                        "shape_prior_region": "head+torso+arms+hands+legs+feet"}
        assert len(fits) == 3  # reaches 0.2, 0.1, 0.3 of the five initialised frames
        assert poses and all("region_weights" in p[3] for p in poses)  # the region blend, not the whole body
    else:
        assert meta == {"shape_prior": "off", "shape_prior_reach": 0.0, "shape_prior_region": "all"}
        assert fits == [] and poses == []
