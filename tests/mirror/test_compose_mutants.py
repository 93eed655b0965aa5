"""The composition's soft edge at the channel extremes (bodystudio.mirror.compose.compose; issue 17, second round,
after 7de6d24 blends only the soft edge): black over black stays 0 and white over white 255 at any alpha."""

import numpy as np

from bodystudio.mirror.compose import compose, update_background


def test_the_soft_edge_keeps_black_and_white():
    H, W = 12, 16
    frame = np.zeros((H, W, 3), np.uint8)
    frame[:, W // 2:] = 255
    bg = update_background(None, frame, np.zeros((H, W), bool))
    warped = frame.copy()
    alpha = np.zeros((H, W), np.float32)
    alpha[2:10, 2:14] = 1.0
    alpha[2:10, 3] = 0.5
    alpha[2:10, 12] = 0.25
    alpha[1, 1:15] = 0.75
    out = compose(warped, alpha, bg, frame, np.zeros((H, W), bool), hole_margin_px=0)
    np.testing.assert_array_equal(out, frame)


def test_the_soft_edge_is_blended_in_float32_as_the_whole_box_was():
    """The soft edge's sums are float32 (the whole-box blend's, so the frame is the same bit for bit): alphas at
    the half-grey-level boundaries where float32 and float64 round differently give the float32 answer."""
    k = np.arange(1, 255)
    a = np.concatenate([np.float32((k - 0.5) / 255.0), np.nextafter(np.float32((k - 0.5) / 255.0), np.float32(0)),
                        np.nextafter(np.float32((k - 0.5) / 255.0), np.float32(1))]).astype(np.float32)
    a = a[(a > 0) & (a < 1)]
    n = len(a)
    warped = np.zeros((1, n, 3), np.uint8)
    warped[..., 0], warped[..., 1], warped[..., 2] = 255, 200, 77
    frame = np.zeros((1, n, 3), np.uint8)
    frame[..., 1] = 13
    bg = update_background(None, frame, np.zeros((1, n), bool))
    out = compose(warped, a[None, :], bg, frame, np.zeros((1, n), bool), hole_margin_px=0)
    w32, f32, a32 = warped[0].astype(np.float32), frame[0].astype(np.float32), a[:, None]
    expect32 = np.clip(w32 * a32 + f32 * (np.float32(1.0) - a32) + np.float32(0.5), 0, 255).astype(np.uint8)
    a64 = a.astype(np.float64)[:, None]
    expect64 = np.clip(warped[0] * a64 + frame[0] * (1.0 - a64) + 0.5, 0, 255).astype(np.uint8)
    assert (expect32 != expect64).any()  # the case tells them apart
    np.testing.assert_array_equal(out[0], expect32)
