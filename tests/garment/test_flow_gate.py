"""§7.1's gate: the flow correction is used only when it is larger than the flow resolves (issue 13, gar13b).

Closed-form fields on small masks: the threshold is in pixels of the image the flow is computed on, at the
90th percentile over the garment; ``refine_and_composite`` falls back to §7.2 alone below it.
"""

from types import SimpleNamespace

import numpy as np

from bodystudio.garment import composite as cp
from bodystudio.garment import refine


def _field(H, W, dy):
    field = np.zeros((H, W, 2), np.float32)
    field[..., 1] = dy
    return field


def test_threshold_is_one_pixel_at_the_flow_resolution():
    assert refine.MIN_FLOW_CORRECTION_PX == 1.0
    mask = np.zeros((640, 480), bool)
    mask[200:400, 150:330] = True
    # 640 px high: the flow runs at 320, so 2 px of the frame are 1 px of the flow
    assert not refine.flow_correction_is_significant(_field(640, 480, 1.9), mask)
    assert refine.flow_correction_is_significant(_field(640, 480, 2.1), mask)
    # a frame no higher than the flow height is not rescaled
    small = mask[::2, ::2]
    assert refine.flow_correction_is_significant(_field(320, 240, 1.1), small)
    assert not refine.flow_correction_is_significant(_field(320, 240, 0.9), small)
    # the direction does not matter, the length does
    assert refine.flow_correction_is_significant(_field(320, 240, -1.1), small)
    assert not refine.flow_correction_is_significant(_field(320, 240, 5.0), np.zeros_like(small))
    assert not refine.flow_correction_is_significant(_field(320, 240, 1.1), small, min_px=1.2)


def test_threshold_is_the_90th_percentile_over_the_garment_only():
    H, W = 100, 100
    mask = np.zeros((H, W), bool)
    mask[:, :50] = True  # 5000 garment pixels
    field = _field(H, W, 0.5)
    field[:, 50:] = 9.0  # outside the garment: ignored
    assert not refine.flow_correction_is_significant(field, mask)
    field[:5, :50] = 9.0  # 5 % of the garment moves far: the 90th percentile does not
    assert not refine.flow_correction_is_significant(field, mask)
    field[:20, :50] = 9.0  # 20 %: it does
    assert refine.flow_correction_is_significant(field, mask)
    assert not refine.flow_correction_is_significant(field, mask, quantile=75.0)


def _layer(H=40, W=48):
    body_mask = np.zeros((H, W), bool)
    body_mask[6:34, 10:38] = True
    g_mask = np.zeros((H, W), bool)
    g_mask[12:30, 10:38] = True
    rgb = np.zeros((H, W, 3), np.float32)
    rgb[g_mask] = [0.2, 0.4, 0.6]
    return SimpleNamespace(rgb=rgb, mask=g_mask, depth=np.where(g_mask, 1.9, 0.0).astype(np.float32),
                           body_image=(body_mask[..., None] * np.full(3, 0.5)).astype(np.float32),
                           body_mask=body_mask, body_depth=np.where(body_mask, 2.0, 0.0).astype(np.float32))


def test_refinement_drops_a_sub_resolution_correction_and_keeps_a_larger_one(monkeypatch):
    layer = _layer()
    H, W = layer.mask.shape
    frame = np.full((H, W, 3), 90, np.uint8)
    person = layer.body_mask.copy()
    plain = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False)
    for dy, used in ((0.8, False), (3.0, True)):
        monkeypatch.setattr(refine, "garment_motion_correction", lambda *a, _dy=dy, **k: _field(H, W, _dy))
        out = cp.refine_and_composite(frame, person, layer, rbf=False)
        assert np.array_equal(out.field, _field(H, W, dy) if used else np.zeros((H, W, 2), np.float32)), dy
        # 3 px down-sampling moves the garment's top hem up by 3 rows; 0.8 px leaves the plain composite
        assert np.array_equal(out.garment_mask, plain.garment_mask) != used
    assert out.garment_mask[9:12].any() and not plain.garment_mask[9:12].any()
