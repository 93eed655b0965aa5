"""The synthetic mirror studio's colour plate shows the room a lens sees: no ceiling folded into its top corners.

Before mir12t the rasteriser drew the room's ceiling corners (60 degrees off the axis, beyond the Kinect v2 colour
lens's monotonic radius 1.67) folded back through the distortion polynomial: grey wedges ~1.5 m in front of the
wall at the top corners of every colour frame (11266 of the test's 26400 top-corner pixels > 5 cm off a ray cast,
up to 2.8 m; 0 since).
"""

import numpy as np

from bodystudio.capture.render import render
from bodystudio.mirror.synthetic import mirror_room, mirror_sensor

#: The room's box (no furniture): (axis, value) of its planes and its extent.
_PLANES = ((1, 0.0), (1, 2.8), (0, -2.8), (0, 2.8), (2, -1.3))
_LO, _HI = np.array([-2.8, 0.0, -1.3]), np.array([2.8, 2.8, 1.5])


def _raycast_box_depth(camera) -> np.ndarray:
    """Camera-z depth (H, W) of the room's box along each pixel's undistorted ray (the lens's true image)."""
    H, W = camera.height, camera.width
    cols, rows = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    o, d = camera.rays(np.stack([cols.ravel(), rows.ravel()], axis=1))
    best = np.full(len(d), np.inf)
    for axis, value in _PLANES:
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (value - o[:, axis]) / d[:, axis]
        P = o + s[:, None] * d
        inside = (s > 0) & np.all((P >= _LO - 1e-3) & (P <= _HI + 1e-3), axis=1)
        best = np.where(inside & (s < best), s, best)
    P = o + best[:, None] * d
    return ((P - camera.center) @ camera.R.T)[:, 2].reshape(H, W)


def test_colour_plate_top_corners_show_the_wall_not_the_folded_ceiling():
    camera = mirror_sensor("v2").color
    room = mirror_room()
    depth = render(room.vertices, room.faces, camera).depth
    truth = _raycast_box_depth(camera)
    # the top 110 rows' outer 120 columns each side: wall and ceiling only (the shelf starts at row 116, col 78)
    band = np.zeros(depth.shape, bool)
    band[:110, :120] = band[:110, -120:] = True
    off = np.abs(depth - truth)[band] > 0.05
    assert np.isfinite(truth[band]).all()
    assert off.sum() <= 0.005 * band.sum(), f"{off.sum()} of {band.sum()} top-corner pixels off the ray cast"
