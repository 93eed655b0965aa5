"""The warp's edge clamp (MIR12g, :func:`bodystudio.mirror.warp.edge_clamped`) point by point (issue 17, branch mutI).

On a 20 x 30 image: a source position off the image by less than the reach moves onto the nearest edge (each
coordinate clipped to [0, W - 1] / [0, H - 1], the other left as it is); one at the reach or beyond, on any of the
four sides, and OUTSIDE_PX (no foreground, whatever the reach) stay; positions on the image stay."""
import numpy as np
import pytest

from bodystudio.mirror.warp import EDGE_REACH_PX, OUTSIDE_PX, edge_clamped

H, W = 20, 30


def _clamped(points, reach=EDGE_REACH_PX):
    xy = np.array(points, np.float32)[None]
    return edge_clamped(xy, (H, W), reach)[0]


def test_the_reach_is_the_fields_own_limit():
    assert EDGE_REACH_PX == -OUTSIDE_PX == 16.0


@pytest.mark.parametrize("point, want", [
    ((5.0, 5.0), (5.0, 5.0)),  # on the image
    ((0.0, 0.0), (0.0, 0.0)), ((29.0, 19.0), (29.0, 19.0)), ((0.5, 19.0), (0.5, 19.0)),  # on its edges
    ((-3.0, 5.5), (0.0, 5.5)), ((5.5, -3.0), (5.5, 0.0)),  # just off the left / top
    ((32.0, 5.5), (29.0, 5.5)), ((5.5, 22.0), (5.5, 19.0)),  # just off the right / bottom
    ((-3.0, -4.0), (0.0, 0.0)), ((33.0, 21.0), (29.0, 19.0)),  # off two edges: the corner
    ((-15.5, 5.0), (0.0, 5.0)), ((5.0, -15.5), (5.0, 0.0)),  # just within the reach
    ((44.5, 5.0), (29.0, 5.0)), ((5.0, 34.5), (5.0, 19.0)),
    ((5.0, -16.0), (5.0, -16.0)), ((45.0, 5.0), (45.0, 5.0)), ((5.0, 35.0), (5.0, 35.0)),  # at the reach: stay
    ((-40.0, 5.0), (-40.0, 5.0)), ((5.0, -40.0), (5.0, -40.0)),  # far beyond: stay
    ((80.0, 5.0), (80.0, 5.0)), ((5.0, 80.0), (5.0, 80.0)), ((80.0, 80.0), (80.0, 80.0)),
    ((OUTSIDE_PX, 5.0), (OUTSIDE_PX, 5.0)), ((OUTSIDE_PX, OUTSIDE_PX), (OUTSIDE_PX, OUTSIDE_PX)),  # no foreground
])
def test_each_position_within_the_reach_moves_onto_the_nearest_edge(point, want):
    # one off-image point beside it, so that the clamp runs (a field wholly on the image is returned as it is)
    out = _clamped([point, (-2.0, 3.0)])
    np.testing.assert_array_equal(out[0], np.float32(want))
    np.testing.assert_array_equal(out[1], (0.0, 3.0))


def test_a_smaller_or_larger_reach_moves_its_own_limit_and_never_the_no_foreground_mark():
    out = _clamped([(-7.5, 5.0), (-8.0, 5.0), (5.0, -8.0), (37.0, 5.0), (5.0, 27.0), (36.5, 5.0), (5.0, 26.5)], 8.0)
    np.testing.assert_array_equal(out, np.float32([(0, 5), (-8, 5), (5, -8), (37, 5), (5, 27), (29, 5), (5, 19)]))
    out = _clamped([(OUTSIDE_PX, 5.0), (5.0, OUTSIDE_PX), (-18.0, 5.0), (-20.0, 5.0)], 20.0)
    # OUTSIDE_PX in x marks no foreground (stays); in y alone it is a position 16 px above the image
    np.testing.assert_array_equal(out, np.float32([(OUTSIDE_PX, 5), (5, 0), (-18, 5), (-20, 5)]))
