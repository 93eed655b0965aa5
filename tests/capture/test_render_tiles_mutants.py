"""Mutation test of rec15i's tile-cleared z-buffer (issue 17, branch mutT; docs/mutation/capture-render.md): without
``tile_px`` the flagged tiles are 8 pixels square (the docstring's default); the pixels of those tiles are the whole
buffer's. ``tests/reconstruct/test_depth_compiled.py`` pins the caller's 7- and 8-pixel tiles on a body."""

import numpy as np

from bodystudio.capture.render import depth_buffer


def test_the_default_tiles_are_eight_pixels_square():
    W, H = 61, 45  # the last row and column of tiles clipped
    uv = np.array([[5.0, 4.0], [50.0, 10.0], [12.0, 40.0], [58.0, 42.0]])
    z = np.array([1.0, 1.5, 2.0, 1.2])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    whole = depth_buffer(uv, z, F, W, H)
    tiles = np.zeros(((H + 7) // 8, (W + 7) // 8), bool)
    tiles[::2, ::3] = True
    tiles[-1, -1] = True
    flagged = np.kron(tiles, np.ones((8, 8), bool))[:H, :W]
    assert (np.isinf(whole) & flagged).sum() > 50 and (np.isfinite(whole) & flagged).sum() > 50
    for fill in (-1.0, 0.0, 7.0):  # what the unflagged pixels hold is not read: freed buffers of junk before each
        junk = np.full((H, W), fill, np.float32)
        del junk
        part = depth_buffer(uv, z, F, W, H, tiles)
        np.testing.assert_array_equal(part[flagged], whole[flagged])
