"""Closing and opening of the silhouette clean-up (capture/silhouettes.py ``morphology``) on exact masks.

A real defect found by tests/garment/test_person_analytic.py (issue 17, mutation round for garment/person.py):
OpenCV's ``morphologyEx`` with an even-sized ellipse (``--close 2``, the garment stage's person mattes) moved the
mask one pixel down-right and dropped a corner.
"""

import cv2
import numpy as np
import pytest

from bodystudio.capture.silhouettes import SegmentationParams, clean_mask, morphology


@pytest.mark.parametrize("size", [2, 3, 4, 5])
def test_closing_keeps_a_square_in_place_and_fills_a_one_pixel_gap(size):
    m = np.zeros((20, 20), np.uint8)
    m[5:12, 4:11] = 1
    closed = morphology(m, size, close=True)
    assert np.array_equal(closed, m)  # a square is closed: unchanged, not shifted
    opened = morphology(m, size, close=False)
    assert np.all(opened <= m) and opened[6:11, 5:10].all()  # opening trims at most the corners, in place
    assert np.array_equal(np.argwhere(opened).min(0) + np.argwhere(opened).max(0), [16, 14])  # centred on the square
    gap = m.copy()
    gap[6:11, 7] = 0  # a one-pixel crack inside it
    assert np.array_equal(morphology(gap, size, close=True), m)


@pytest.mark.parametrize("size", [2, 3, 4, 5])
def test_closing_is_extensive_opening_anti_extensive_and_both_idempotent(size):
    rng = np.random.default_rng(size)
    for _ in range(20):
        m = (rng.random((24, 24)) < 0.4).astype(np.uint8)
        c = morphology(m, size, close=True)
        o = morphology(m, size, close=False)
        assert np.all(c >= m) and np.all(o <= m)
        assert np.array_equal(morphology(c, size, close=True), c)
        assert np.array_equal(morphology(o, size, close=False), o)
        if size % 2:  # odd: OpenCV's own closing/opening
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
            assert np.array_equal(c, cv2.morphologyEx(m, cv2.MORPH_CLOSE, k))
            assert np.array_equal(o, cv2.morphologyEx(m, cv2.MORPH_OPEN, k))


def test_clean_mask_with_a_two_pixel_closing_does_not_move_the_matte():
    m = np.zeros((40, 40), bool)
    m[10:30, 12:26] = True
    got = clean_mask(m, SegmentationParams(close_px=2, min_component_px=1))
    assert np.array_equal(got, m)
