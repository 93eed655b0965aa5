"""Mutation tests of rec15i's tile-cleared z-buffer (issue 17, branch mutT; docs/mutation/capture-render.md,
reconstruct-depth.md): without ``tile_px`` the flagged tiles are 8 pixels square (the docstring's default) and the
pixels of those tiles are the whole buffer's; the depth term hands it the tiles of its pixels and its own tile size.
``tests/reconstruct/test_depth_compiled.py`` pins the caller's 7- and 8-pixel tiles on a body."""

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


def test_the_depth_term_clears_only_the_tiles_of_its_pixels(monkeypatch):
    """``reconstruct.depth._model_depth_at`` hands ``depth_buffer`` the tiles that hold its pixels (8 px): the
    model's depth there is the whole buffer's (0 where no triangle covers the pixel)."""
    from types import SimpleNamespace

    from bodystudio.reconstruct import depth as depth_mod

    seen = []
    real = depth_mod.depth_buffer

    def spy(*args, **kwargs):
        seen.append(args[5:])
        return real(*args, **kwargs)

    monkeypatch.setattr(depth_mod, "depth_buffer", spy)
    W, H = 61, 45
    uv = np.array([[5.0, 4.0], [50.0, 10.0], [12.0, 40.0], [58.0, 42.0]])
    z = np.array([1.0, 1.5, 2.0, 1.2])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    pixels = np.array([[10, 20], [44, 60], [0, 0]])
    got = depth_mod._model_depth_at(F, SimpleNamespace(width=W, height=H), uv, z, pixels)
    (tiles, tile_px), = seen
    assert tile_px == 8 and tiles.shape == (6, 8)
    np.testing.assert_array_equal(np.argwhere(tiles), [[0, 0], [1, 2], [5, 7]])
    whole = depth_buffer(uv, z, F, W, H)[pixels[:, 0], pixels[:, 1]]
    np.testing.assert_array_equal(got, np.where(np.isinf(whole), 0.0, whole))
    assert (got > 0).any() and (got == 0).any()
