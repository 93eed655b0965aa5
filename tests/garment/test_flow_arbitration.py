"""§7.1's correction arbitrated per pixel by the video (issue 13, gar13f).

With the hem matte on, ``refine_and_composite`` composites the frame with and without the flow's correction and,
where the two garment regions differ, keeps a pixel as garment where the matte's colour model sees the actor's worn
garment: a right correction is kept, a wrong one undone, whichever hypothesis it is. Toy frames of two flat colours
(seconds). Measured (IoU with the worn band): arbitrated 0.998 in all four cases; the uncorrected hypothesis
0.818 where the flow is right, the correction used whole (the gate, ``hem=False``) 0.818 where it is wrong.
"""

from types import SimpleNamespace

import numpy as np
from scipy import ndimage

from bodystudio.garment import composite as cp
from bodystudio.garment import refine

H, W = 90, 60
WORN_ROWS = (20, 60)  # the actor's worn shirt in the video


def _field(dy):
    field = np.zeros((H, W, 2), np.float32)
    field[..., 1] = dy
    return field


def _case(render_top):
    """The actor (skin, rows 6-84) wearing a blue band at WORN_ROWS; the fitted render's garment at rows
    ``render_top`` .. ``render_top`` + 40."""
    body = np.zeros((H, W), bool)
    body[6:84, 10:50] = True
    worn = np.zeros((H, W), bool)
    worn[WORN_ROWS[0]:WORN_ROWS[1], 10:50] = True
    frame = np.zeros((H, W, 3), np.uint8)
    frame[body] = (200, 150, 120)
    frame[worn] = (40, 60, 180)
    g = np.zeros((H, W), bool)
    g[render_top:render_top + 40, 10:50] = True
    layer = SimpleNamespace(rgb=(g[..., None] * np.array([0.9, 0.9, 0.1])).astype(np.float32), mask=g,
                            depth=np.where(g, 1.9, 0.0).astype(np.float32),
                            body_image=(body[..., None] * np.full(3, 0.5)).astype(np.float32), body_mask=body,
                            body_depth=np.where(body, 2.0, 0.0).astype(np.float32))
    return frame, body, layer, worn


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_arbitration_is_the_video_where_the_hypotheses_differ():
    a = np.zeros((4, 6), bool)
    a[:2] = True
    b = np.zeros((4, 6), bool)
    b[1:3] = True
    prob = np.zeros((4, 6))
    prob[:, :3] = 0.9
    person = np.ones((4, 6), bool)
    person[:, 0] = False
    out = refine.arbitrate_flow_correction(a, b, prob, person)
    assert out[1].all()  # both agree: kept whatever the video says
    assert out[0, 1:3].all() and out[2, 1:3].all()  # differ, worn garment seen: garment
    assert not out[0, 3:].any() and not out[2, 3:].any()  # differ, no worn garment: not
    assert not out[0, 0] and not out[2, 0]  # outside the person: never
    assert not out[3].any()


def test_a_right_correction_is_kept_and_a_wrong_one_undone(monkeypatch):
    for render_top, dy, flow_right in ((24, 4.0, True), (20, 4.0, False), (16, -4.0, True), (20, -4.0, False)):
        frame, person, layer, worn = _case(render_top)
        monkeypatch.setattr(refine, "garment_motion_correction", lambda *a, _dy=dy, **k: _field(_dy))
        full = cp.refine_and_composite(frame, person, layer, rbf=False)
        plain = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False)
        whole = cp.refine_and_composite(frame, person, layer, rbf=False, hem=False)  # the gate: used whole
        assert full.flow_applied and full.hem_applied, (render_top, dy)
        assert _iou(full.garment_mask, worn) >= 0.99, (render_top, dy)
        if flow_right:  # the uncorrected hems are 4 rows off, beyond the hem matte's 1.5 px reach
            assert _iou(plain.garment_mask, worn) <= 0.88
            assert _iou(whole.garment_mask, worn) >= 0.99
        else:  # the correction moved a right hem 4 rows off
            assert _iou(plain.garment_mask, worn) >= 0.99
            assert _iou(whole.garment_mask, worn) <= 0.85
        # the pixels the video took from the uncorrected hypothesis show its garment, the ones it dropped the actor
        g = full.garment_mask
        assert np.array_equal(full.image[~person], frame[~person])
        assert (full.image[g][:, 2] < 60).all() and (full.image[person & ~g] == frame[person & ~g]).all()


def test_the_colours_are_the_corrected_warps_only_above_the_gate(monkeypatch):
    """The region is arbitrated either way; the texture follows the correction only when the gate finds it larger
    than the flow resolves (below, it is the albedo's smear: gar13f's 37 lost 0.4 dB psnr_person to it)."""
    frame, person, layer, worn = _case(24)
    rows = np.arange(H, dtype=np.float32)[:, None, None] / H
    layer.rgb = (layer.mask[..., None] * np.concatenate([np.full((H, W, 1), 0.9), np.broadcast_to(rows, (H, W, 1)),
                                                          np.full((H, W, 1), 0.1)], axis=2)).astype(np.float32)
    monkeypatch.setattr(refine, "garment_motion_correction", lambda *a, **k: _field(4.0))
    plain = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False)
    corrected = cp.refine_and_composite(frame, person, layer, rbf=False, hem=False)  # the correction used whole
    for significant, want in ((True, corrected), (False, plain)):
        monkeypatch.setattr(refine, "flow_correction_is_significant", lambda *a, _s=significant, **k: _s)
        full = cp.refine_and_composite(frame, person, layer, rbf=False)
        assert _iou(full.garment_mask, worn) >= 0.99
        # the interior, beyond the hem matte's reach (the matte colours the pixels it adds itself)
        both = ndimage.binary_erosion(full.garment_mask & want.garment_mask, iterations=3)
        assert both.sum() > 0.5 * worn.sum()
        assert np.array_equal(full.image[both], want.image[both]), significant
        assert np.array_equal(full.field, want.field)
    assert not np.array_equal(plain.image[both], corrected.image[both])
