"""ChArUco board geometry, files and detection against independent references (issue 17, mutation of calib/board.py).

References: the corners written out as ((i + 1) * square, (j + 1) * square, 0) row by row, the board texture
composed square by square from OpenCV's single-marker drawing (markers numbered over the white squares row
by row), the PNG read back by Pillow (pixels and pHYs), the figure of the PDF page inspected as matplotlib
saves it, convex-hull areas of hand-placed corners, and every refusal's whole line.
"""

import functools
import json
import re

import cv2
import numpy as np
import pytest

from bodystudio.calib.board import (
    CharucoBoardSpec,
    CharucoDetection,
    _charuco_detector,
    board_corners,
    board_image,
    board_texture_px_per_m,
    detect_charuco,
    load_board_json,
    read_image_grey,
    save_board_json,
    write_board_pdf,
    write_board_png,
)
from bodystudio.errors import FileFormatError, InputError


def _reference_texture(squares_x, squares_y, px_sq, marker_px, dictionary, black_first=True):
    """Board texture square by square: black where (row + col) is even (odd for a legacy board with an even
    number of rows), a marker with a one-bit border centred in every white square, ids row by row."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    img = np.zeros((squares_y * px_sq, squares_x * px_sq), np.uint8)
    k = 0
    off = (px_sq - marker_px) // 2
    for r in range(squares_y):
        for c in range(squares_x):
            if ((r + c) % 2 == 0) == black_first:
                continue
            img[r * px_sq:(r + 1) * px_sq, c * px_sq:(c + 1) * px_sq] = 255
            marker = cv2.aruco.generateImageMarker(d, k, marker_px, borderBits=1)
            img[r * px_sq + off:r * px_sq + off + marker_px, c * px_sq + off:c * px_sq + off + marker_px] = marker
            k += 1
    return img


@functools.cache
def _flat_board():
    """A 5 x 4 board (not square: x and y swaps show) at 40 px a square with a 20 px white margin."""
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03)
    return spec, board_image(spec, px_per_m=1000.0, margin_m=0.02)


# --- the specification ----------------------------------------------------------------------------------

def test_board_geometry_written_out():
    spec = CharucoBoardSpec(6, 4, 0.05, 0.03, "DICT_5X5_100")
    expected = np.array([[(i + 1) * 0.05, (j + 1) * 0.05, 0.0] for j in range(3) for i in range(5)])
    corners = board_corners(spec)
    assert corners.dtype == np.float64 and corners.shape == (15, 3)
    np.testing.assert_allclose(corners, expected, atol=1e-7)
    assert spec.n_corners == 15
    assert spec.size_m == pytest.approx((0.30, 0.20), abs=1e-15)
    np.testing.assert_allclose(spec.center_m, [0.15, 0.10, 0.0], atol=1e-15)
    assert spec.center_m.shape == (3,)
    board = spec.cv_board()
    assert board.getChessboardSize() == (6, 4)
    assert board.getSquareLength() == pytest.approx(0.05) and board.getMarkerLength() == pytest.approx(0.03)


def test_spec_fields_are_converted_and_serialised(tmp_path):
    spec = CharucoBoardSpec(np.int64(7), np.int32(5), np.float32(0.0625), 3 * 0.01, "DICT_4X4_50", True)
    assert type(spec.squares_x) is int and type(spec.squares_y) is int
    assert type(spec.square_m) is float and type(spec.marker_m) is float
    assert (spec.squares_x, spec.squares_y, spec.square_m, spec.marker_m) == (7, 5, 0.0625, 0.03)
    whole = CharucoBoardSpec(4, 3, 1, 0.5)  # a JSON integer is a size too
    assert type(whole.square_m) is float and whole.square_m == 1.0
    expected = {"type": "charuco", "squares_x": 7, "squares_y": 5, "square_m": 0.0625, "marker_m": 0.03,
                "dictionary": "DICT_4X4_50", "legacy_pattern": True}
    assert spec.to_dict() == expected
    save_board_json(tmp_path / "b.json", spec)
    assert json.loads((tmp_path / "b.json").read_text()) == expected
    assert load_board_json(tmp_path / "b.json") == spec
    untyped = {k: v for k, v in expected.items() if k != "type"}  # no "type": a ChArUco board
    (tmp_path / "u.json").write_text(json.dumps(untyped))
    assert load_board_json(tmp_path / "u.json") == spec
    assert CharucoBoardSpec.from_dict(expected) == spec


@pytest.mark.parametrize("kwargs", [
    dict(squares_x=3, squares_y=3, square_m=1e-3, marker_m=5e-4),
    dict(squares_x=3, squares_y=3, square_m=2.0, marker_m=1.5),
    dict(squares_x=100, squares_y=3, square_m=0.1, marker_m=0.05, dictionary="DICT_4X4_250"),
    dict(squares_x=3, squares_y=100, square_m=0.1, marker_m=0.05, dictionary="DICT_4X4_250"),
    dict(squares_x=10, squares_y=10, square_m=0.1, marker_m=0.05),  # 50 markers of DICT_4X4_50's 50
    dict(squares_x=3, squares_y=67, square_m=0.1, marker_m=0.05, dictionary="DICT_4X4_100"),  # 201 // 2 = 100
])
def test_spec_bounds_accepted(kwargs):
    spec = CharucoBoardSpec(**kwargs)
    assert spec.squares_x == kwargs["squares_x"] and spec.square_m == kwargs["square_m"]


@pytest.mark.parametrize("kwargs, message", [
    (dict(square_m=True), "board square_m must be a number of metres, got True"),
    (dict(square_m="0.1"), "board square_m must be a number of metres, got '0.1'"),
    (dict(marker_m=None), "board marker_m must be a number of metres, got None"),
    (dict(square_m=0.00099, marker_m=0.0005),
     "board square size 0.00099 m is outside 0.001-2.0 m; give the printed square's side in metres"),
    (dict(square_m=2.01, marker_m=1.0),
     "board square size 2.01 m is outside 0.001-2.0 m; give the printed square's side in metres"),
    (dict(square_m=float("nan")),
     "board square size nan m is outside 0.001-2.0 m; give the printed square's side in metres"),
    (dict(squares_x=7.0), "board squares_x must be a whole number of squares, got 7.0"),
    (dict(squares_y=False), "board squares_y must be a whole number of squares, got False"),
    (dict(squares_x=2, squares_y=5), "board needs at least 3x3 and at most 100x100 squares, got 2x5"),
    (dict(squares_x=5, squares_y=2), "board needs at least 3x3 and at most 100x100 squares, got 5x2"),
    (dict(squares_x=101, squares_y=3, dictionary="DICT_4X4_1000"),
     "board needs at least 3x3 and at most 100x100 squares, got 101x3"),
    (dict(squares_x=3, squares_y=101, dictionary="DICT_4X4_1000"),
     "board needs at least 3x3 and at most 100x100 squares, got 3x101"),
    (dict(legacy_pattern=1), "board legacy_pattern must be true or false, got 1"),
    (dict(marker_m=0.1), "marker size 0.1 m must be positive and smaller than the square size 0.1 m"),
    (dict(marker_m=0.0), "marker size 0.0 m must be positive and smaller than the square size 0.1 m"),
    (dict(dictionary="DICT_7X7_1"),
     "unknown ArUco dictionary 'DICT_7X7_1'; use one of e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250"),
    (dict(dictionary=5), "unknown ArUco dictionary 5; use one of e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250"),
    (dict(squares_x=11, squares_y=10),
     "DICT_4X4_50 has too few markers for a 11x10 board (55 needed); pick a larger dictionary"),
    (dict(squares_x=3, squares_y=67, dictionary="DICT_4X4_50"),
     "DICT_4X4_50 has too few markers for a 3x67 board (100 needed); pick a larger dictionary"),
])
def test_spec_refusals_word_for_word(kwargs, message):
    with pytest.raises(InputError) as err:
        CharucoBoardSpec(**kwargs)
    assert str(err.value) == message


def test_board_description_refusals_word_for_word(tmp_path):
    with pytest.raises(InputError) as err:
        CharucoBoardSpec.from_dict({"type": "charuco", "squares_x": 5, "squares_y": 4})
    assert str(err.value) == "board description lacks square_m, marker_m"
    with pytest.raises(InputError) as err:
        CharucoBoardSpec.from_dict({"squares_x": 5, "squares_y": 4, "square_m": 0.1, "marker_m": 0.05, "colour": 1})
    assert re.fullmatch(r"board description has unknown fields or values of the wrong type \(.*'colour'.*\)",
                        str(err.value))
    hint = "write one with `bodystudio calib board`"
    for name, content, message in [
        ("list.json", "[1, 2]", "not a ChArUco board description; " + hint),
        ("aruco.json", json.dumps({"type": "aruco", "squares_x": 5}), "not a ChArUco board description; " + hint),
        ("lacks.json", json.dumps({"squares_x": 5, "squares_y": 4, "square_m": 0.1}),
         "board description lacks marker_m; " + hint),
        ("small.json", json.dumps({"squares_x": 2, "squares_y": 4, "square_m": 0.1, "marker_m": 0.05}),
         "board needs at least 3x3 and at most 100x100 squares, got 2x4; " + hint),
    ]:
        path = tmp_path / name
        path.write_text(content)
        with pytest.raises(FileFormatError) as err:
            load_board_json(path)
        assert str(err.value) == f"{path}: {message}"
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(FileFormatError, match="not a valid board description"):
        load_board_json(tmp_path / "bad.json")


# --- the texture and the printable files -----------------------------------------------------------------

@pytest.mark.parametrize("legacy", [False, True])
def test_texture_is_the_board_composed_square_by_square(legacy):
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03, legacy_pattern=legacy)
    img = board_image(spec, px_per_m=1000.0)  # 40 px squares, 30 px markers
    assert img.dtype == np.uint8 and img.shape == (160, 200)
    # OpenCV's legacy pattern starts with a white square when the number of rows is even
    ref = _reference_texture(5, 4, 40, 30, "DICT_4X4_50", black_first=not legacy)
    assert np.array_equal(img, ref)
    assert board_texture_px_per_m(spec, 1000.0) == 1000.0


def test_texture_margin_and_pixel_rounding():
    spec, img = _flat_board()
    assert img.shape == (160 + 40, 200 + 40)  # 0.02 m of margin at 40 px per 0.04 m square: 20 px a side
    assert (img[:20] == 255).all() and (img[-20:] == 255).all() and (img[:, :20] == 255).all()
    assert (img[:, -20:] == 255).all()
    assert np.array_equal(img[20:-20, 20:-20], board_image(spec, px_per_m=1000.0))
    # 0.04 m * 1012 px/m = 40.48 -> 40 px squares: exactly 1000 px/m
    assert board_image(spec, px_per_m=1012.0).shape == (160, 200)
    assert board_texture_px_per_m(spec, 1012.0) == pytest.approx(1000.0, abs=1e-9)
    assert board_image(spec, px_per_m=1013.0).shape == (164, 205)  # 40.52 -> 41
    # at least 4 px a square: 0.04 m * 50 px/m = 2 px (OpenCV draws no marker below 6 px, so only the figure)
    assert board_texture_px_per_m(spec, 50.0) == pytest.approx(100.0, abs=1e-9)
    assert board_image(spec, px_per_m=1000.0, margin_m=0.0101).shape == (160 + 20, 200 + 20)  # 10.1 -> 10 px
    # the default 4000 px/m: 0.1001 m * 4000 = 400.4 -> 400 px squares (4001 px/m would give 401)
    assert board_image(CharucoBoardSpec(3, 3, 0.1001, 0.07)).shape == (1200, 1200)


def test_png_is_the_texture_at_its_dpi(tmp_path):
    from PIL import Image

    spec = CharucoBoardSpec(3, 3, 0.02, 0.016)
    dpi = 127.0  # 5000 px/m: 100 px squares, 0.01 m margin = 50 px
    write_board_png(tmp_path / "b.png", spec, dpi=dpi, margin_m=0.01)
    with Image.open(tmp_path / "b.png") as im:
        assert im.size == (400, 400)
        assert im.info["dpi"] == pytest.approx((dpi, dpi), abs=0.01)
        rgba = np.asarray(im.convert("RGBA"))
    expected = np.full((400, 400), 255, np.uint8)
    expected[50:-50, 50:-50] = _reference_texture(3, 3, 100, 80, "DICT_4X4_50")
    for channel in range(3):
        assert np.array_equal(rgba[..., channel], expected)
    assert (rgba[..., 3] == 255).all()
    write_board_png(tmp_path / "m.png", spec, dpi=dpi)  # the default margin: 1 cm
    with Image.open(tmp_path / "m.png") as im:
        assert im.size == (400, 400)
    assert not list(tmp_path.glob("*.tmp*"))
    write_board_png(tmp_path / "board.image", spec, dpi=dpi)  # a PNG whatever the name ends in
    assert (tmp_path / "board.image").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    write_board_png(tmp_path / "d.png", spec)  # the default 300 dpi: 236 px squares, 118 px of margin
    with Image.open(tmp_path / "d.png") as im:
        assert im.size == (3 * 236 + 2 * 118, 3 * 236 + 2 * 118)
        assert im.info["dpi"] == pytest.approx((300, 300), abs=0.01)


def test_png_dpi_and_marker_size_refusals(tmp_path):
    small = CharucoBoardSpec(3, 3, 0.01, 0.0075)
    for dpi in (49.5, 1200.5):
        with pytest.raises(InputError) as err:
            write_board_png(tmp_path / "x.png", small, dpi=dpi)
        assert str(err.value) == f"--dpi {dpi:g}: choose between 50 and 1200 (300 is a good print resolution)"
    # 50 dpi is allowed, so it is the markers that are refused there
    with pytest.raises(InputError) as err:
        write_board_png(tmp_path / "x.png", small, dpi=50)
    assert str(err.value) == ("--dpi 50: the 7.5 mm markers would be 15 px wide; raise --dpi or the marker size so "
                              "that they are at least 20 px")
    edge = CharucoBoardSpec(3, 3, 0.01, 0.00635)
    with pytest.raises(InputError) as err:
        write_board_png(tmp_path / "x.png", edge, dpi=79)
    assert str(err.value) == ("--dpi 79: the 6.35 mm markers would be 20 px wide; raise --dpi or the marker size so "
                              "that they are at least 20 px")
    assert not (tmp_path / "x.png").exists()
    write_board_png(tmp_path / "edge.png", edge, dpi=80)  # 0.00635 m at 80 dpi: 20 px exactly
    write_board_png(tmp_path / "hi.png", small, dpi=1200, margin_m=0.0)
    from PIL import Image

    with Image.open(tmp_path / "hi.png") as im:
        assert im.size == (3 * 472, 3 * 472)  # 0.01 m at 1200 dpi: 472.4 -> 472 px squares


def test_pdf_page_is_the_board_at_true_size(tmp_path, monkeypatch):
    import matplotlib.figure

    seen = {}
    original = matplotlib.figure.Figure.savefig

    def spy(fig, *args, **kwargs):
        ax = fig.axes[0]
        image = ax.images[0]
        seen.update(figsize=tuple(fig.get_size_inches()), bounds=ax.get_position().bounds, axis_on=ax.axison,
                    extent=tuple(image.get_extent()), data=np.asarray(image.get_array()), cmap=image.get_cmap().name,
                    clim=image.get_clim(), interpolation=image.get_interpolation(),
                    texts=[(t.get_text(), t.get_position(), t.get_fontsize(), t.get_color()) for t in fig.texts],
                    fmt=kwargs.get("format"))
        return original(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03)
    write_board_pdf(tmp_path / "b.pdf", spec, margin_m=0.02)
    page_w, page_h = 0.24, 0.20
    assert seen["figsize"] == pytest.approx((page_w / 0.0254, page_h / 0.0254), rel=1e-12)
    assert seen["bounds"] == pytest.approx((0.02 / page_w, 0.02 / page_h, 0.2 / page_w, 0.16 / page_h), rel=1e-9)
    assert seen["axis_on"] is False
    assert seen["extent"] == pytest.approx((0.0, 0.2, 0.16, 0.0), abs=1e-12)
    assert np.array_equal(seen["data"], _reference_texture(5, 4, 200, 150, "DICT_4X4_50"))
    assert seen["cmap"] == "gray" and seen["clim"] == (0, 255) and seen["interpolation"] == "nearest"
    [(text, pos, size, colour)] = seen["texts"]
    assert text == "ChArUco 5x4 DICT_4X4_50 square 40.0 mm marker 30.0 mm - print at 100 %"
    assert pos == pytest.approx((0.5 * 0.02 / page_w, 0.2 * 0.02 / page_h), rel=1e-12)
    assert size == 6 and colour == "0.4"
    assert seen["fmt"] == "pdf"
    head = (tmp_path / "b.pdf").read_bytes()
    assert head.startswith(b"%PDF")
    box = [float(v) for v in re.search(rb"/MediaBox \[ *([\d. ]+)\]", head).group(1).split()]
    assert box[2:] == pytest.approx([page_w / 0.0254 * 72, page_h / 0.0254 * 72], abs=0.01)
    import matplotlib.pyplot as plt

    assert plt.get_fignums() == []  # the page's figure is closed
    write_board_pdf(tmp_path / "d.pdf", CharucoBoardSpec(3, 3, 0.1, 0.075))  # the default margin: 1 cm
    assert seen["figsize"] == pytest.approx((0.32 / 0.0254, 0.32 / 0.0254), rel=1e-12)
    assert seen["texts"][0][0] == "ChArUco 3x3 DICT_4X4_50 square 100.0 mm marker 75.0 mm - print at 100 %"


# --- detection -------------------------------------------------------------------------------------------

def test_flat_board_corners_on_their_pixel_boundaries():
    spec, img = _flat_board()
    det = detect_charuco(img, spec)
    assert det.corner_ids.dtype.kind == "i" and det.corners_px.dtype == np.float64
    assert det.corner_ids.tolist() == list(range(12)) and det.corners_px.shape == (12, 2)
    # corner k = (i + 1, j + 1) squares from the board's top-left: the pixel boundary at 20 + 40 (i + 1) - 0.5
    expected = np.array([[20 + 40 * (i + 1) - 0.5, 20 + 40 * (j + 1) - 0.5] for j in range(3) for i in range(4)])
    np.testing.assert_allclose(det.corners_px, expected, atol=0.05)
    assert det.image_size == (240, 200)
    bgr = detect_charuco(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), spec)
    assert np.array_equal(bgr.corner_ids, det.corner_ids)
    np.testing.assert_allclose(bgr.corners_px, det.corners_px, atol=1e-9)
    assert bgr.image_size == (240, 200)


def test_upside_down_board_ids_follow_the_board_not_the_image():
    spec, img = _flat_board()
    det = detect_charuco(cv2.rotate(img, cv2.ROTATE_180), spec)
    assert det.corner_ids.tolist() == list(range(12))  # sorted by id
    expected = np.array([[20 + 40 * (i + 1) - 0.5, 20 + 40 * (j + 1) - 0.5] for j in range(3) for i in range(4)])
    np.testing.assert_allclose(det.corners_px, np.array([239.0, 199.0]) - expected, atol=0.05)


def test_min_corners_is_inclusive_and_an_empty_detection_is_well_formed():
    spec, img = _flat_board()
    assert detect_charuco(img, spec, min_corners=12).n_corners == 12
    empty = detect_charuco(img, spec, min_corners=13)
    assert empty.n_corners == 0 and empty.corner_ids.shape == (0,) and empty.corners_px.shape == (0, 2)
    assert empty.corner_ids.dtype.kind == "i" and empty.image_size == (240, 200)
    # the default: 6 corners are enough (a 3 x 4 board has exactly 6)
    small = CharucoBoardSpec(3, 4, 0.04, 0.03)
    assert detect_charuco(board_image(small, px_per_m=1000.0, margin_m=0.02), small).n_corners == 6
    blank = detect_charuco(np.full((50, 70, 3), 255, np.uint8), spec)
    assert blank.n_corners == 0 and blank.corners_px.shape == (0, 2) and blank.image_size == (70, 50)
    assert blank.coverage == 0.0 and blank.quality() == {"n_corners": 0, "coverage": 0.0}


def test_detector_settings():
    spec = CharucoBoardSpec(5, 4, 0.04, 0.03)
    detector = _charuco_detector(spec)
    assert detector.getDetectorParameters().cornerRefinementMethod == cv2.aruco.CORNER_REFINE_SUBPIX
    charuco = detector.getCharucoParameters()
    assert charuco.minMarkers == 2 and charuco.tryRefineMarkers is True
    assert detector.getBoard().getChessboardSize() == (5, 4)


def test_coverage_is_the_hull_area_over_the_image():
    rect = CharucoDetection(np.arange(5), np.array([[10, 10], [110, 10], [110, 110], [10, 110], [60, 50.0]]),
                            (300, 100))
    assert rect.n_corners == 5
    assert rect.coverage == pytest.approx(1 / 3, abs=1e-9)
    assert rect.quality() == {"n_corners": 5, "coverage": 0.33333}
    tri = CharucoDetection(np.arange(3), np.array([[0, 0], [100, 0], [0, 50.0]]), (200, 100))
    assert tri.coverage == pytest.approx(0.125, abs=1e-12)
    two = CharucoDetection(np.arange(2), np.array([[0, 0], [100, 50.0]]), (200, 100))
    assert two.coverage == 0.0


def test_read_image_grey(tmp_path):
    colour = np.zeros((6, 8, 3), np.uint8)
    colour[..., 2] = 200  # red in BGR
    colour[2:, :, 1] = 100
    cv2.imwrite(str(tmp_path / "c.png"), colour)
    grey = read_image_grey(tmp_path / "c.png")
    assert grey.shape == (6, 8) and grey.dtype == np.uint8
    # OpenCV's grey: 0.299 R + 0.587 G + 0.114 B (in fixed point: within one level)
    assert abs(int(grey[0, 0]) - 0.299 * 200) <= 1 and abs(int(grey[3, 3]) - (0.299 * 200 + 0.587 * 100)) <= 1
