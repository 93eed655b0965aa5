"""Mutation tests (issue 17) of mir12e's window of the pose refinement's distance transform
(``mirror.refine.grown_box``, ``_window_is_exact``): each side's margin, the 6 px slack for the bilinear
neighbours and central differences, and the box offset, on hand-computed cases (milliseconds)."""

import numpy as np
import pytest


def test_grown_box_grows_and_clips_to_the_image():
    from bodystudio.mirror.refine import grown_box

    assert grown_box((10, 20, 30, 40), 2, (100, 100)) == (8, 22, 28, 42)
    assert grown_box((3, 10, 4, 12), 5, (12, 14)) == (0, 12, 0, 14)
    assert grown_box((3, 10, 4, 12), 0, (12, 14)) == (3, 10, 4, 12)


def test_window_is_exact_without_points_or_without_a_side_inside_the_mask():
    from bodystudio.mirror.refine import _window_is_exact

    box, sil = (0, 100, 0, 100), (10, 90, 10, 90)
    assert _window_is_exact((10, 90, 10, 90), box, sil, np.zeros((0, 2)), np.zeros(0))
    # the window is the mask's whole box: no side beyond which the mask has pixels, any distance is exact
    assert _window_is_exact((10, 90, 10, 90), box, sil, np.array([[11.0, 11.0]]), np.array([500.0]))
    # a larger window than the mask's box: the same
    assert _window_is_exact((0, 100, 0, 100), box, sil, np.array([[50.0, 50.0]]), np.array([500.0]))


# one window side inside the mask's box (10..90 in both axes) at a time; the sample 10 px from that side
@pytest.mark.parametrize("window,point", [((10, 90, 40, 90), (50.0, 50.0)),   # left side x = 40
                                          ((10, 90, 10, 61), (50.0, 50.0)),   # right side: last column 60
                                          ((40, 90, 10, 90), (50.0, 50.0)),   # top side y = 40
                                          ((10, 61, 10, 90), (50.0, 50.0))])  # bottom side: last row 60
def test_window_is_exact_needs_the_distance_plus_6_px_within_the_margin(window, point):
    from bodystudio.mirror.refine import _window_is_exact

    box, sil = (0, 100, 0, 100), (10, 90, 10, 90)
    p = np.array([point])
    assert _window_is_exact(window, box, sil, p, np.array([4.0]))  # 4 + 6 <= 10
    assert not _window_is_exact(window, box, sil, p, np.array([4.01]))
    # a second sample far from the side does not hide the first one's failure
    p2 = np.array([point, (50.0, 50.0)])
    assert not _window_is_exact(window, box, sil, p2 + [[0, 0], [0, 0]], np.array([4.01, 0.0]))


def test_window_is_exact_reads_the_mask_box_in_the_boxs_frame():
    """``silhouette`` is in image pixels, ``window`` and points in the box's: the box origin is subtracted."""
    from bodystudio.mirror.refine import _window_is_exact

    box = (20, 200, 30, 200)  # origin y 20, x 30
    sil = (40, 120, 50, 130)  # in the box's frame: y 20..100, x 20..100
    p = np.array([[30.0, 60.0]])
    # left side at x 20 = the mask's own left edge in the box's frame: not a side beyond which it has pixels
    assert _window_is_exact((20, 100, 20, 100), box, sil, p, np.array([50.0]))
    # left side at x 21: one column of the mask lies beyond it; the sample is 9 px from it
    assert _window_is_exact((20, 100, 21, 100), box, sil, p, np.array([3.0]))
    assert not _window_is_exact((20, 100, 21, 100), box, sil, p, np.array([3.5]))
    # top side at y 20 (the mask's top edge, box frame) and bottom at 100: exact; top at 21: 39 px margin
    assert _window_is_exact((20, 100, 20, 100), box, sil, np.array([[60.0, 60.0]]), np.array([60.0]))
    assert _window_is_exact((21, 100, 20, 100), box, sil, np.array([[60.0, 60.0]]), np.array([33.0]))
    assert not _window_is_exact((21, 100, 20, 100), box, sil, np.array([[60.0, 60.0]]), np.array([33.5]))
    # right / bottom sides at 99: last column / row 98; the sample at 60 is 38 px from them
    assert _window_is_exact((20, 100, 20, 99), box, sil, np.array([[60.0, 60.0]]), np.array([32.0]))
    assert not _window_is_exact((20, 100, 20, 99), box, sil, np.array([[60.0, 60.0]]), np.array([32.5]))
    assert _window_is_exact((20, 99, 20, 100), box, sil, np.array([[60.0, 60.0]]), np.array([32.0]))
    assert not _window_is_exact((20, 99, 20, 100), box, sil, np.array([[60.0, 60.0]]), np.array([32.5]))


def test_mask_box_of_edge_cases():
    """A mask in the first row only, a one-pixel mask, a non-2-D or empty mask (None)."""
    from bodystudio.mirror.refine import mask_box

    m = np.zeros((5, 6), bool)
    m[0, 2:4] = True
    assert mask_box(m, 0) == (0, 1, 2, 4)
    assert mask_box(m, 1) == (0, 2, 1, 5)
    assert mask_box(np.ones((1, 1), bool), 0) == (0, 1, 0, 1)
    assert mask_box(np.ones(5, bool), 3) is None
    assert mask_box(np.ones((2, 3, 4), bool), 3) is None
    assert mask_box(np.zeros((0, 4), bool), 3) is None
    assert mask_box(np.zeros((4, 4), bool), 3) is None
