"""The decoder rule (issue 16): any libjpeg/libpng warning refuses the image naming the file, except a PNG
colour-profile warning on an intact chunk (the pixels OpenCV decodes never depend on it). Damage -- a CRC
error in any chunk, a truncated file, a broken IDAT -- is refused."""

from __future__ import annotations

import base64
import logging
import struct
import zlib

import cv2
import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.fileio import colour_profile_warning, read_image

IMAGE = (np.random.default_rng(0).random((24, 32, 3)) * 255).astype(np.uint8)


def _chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    out, i = [], 8
    while i < len(data):
        n = struct.unpack(">I", data[i:i + 4])[0]
        out.append((data[i + 4:i + 8], data[i + 8:i + 8 + n]))
        i += 12 + n
    return out


def _png(extra: list[tuple[bytes, bytes]] = (), bad_crc: bytes | None = None) -> bytes:
    """IMAGE as PNG with ``extra`` chunks after IHDR; the chunk named ``bad_crc`` gets a wrong CRC."""
    chunks = _chunks(cv2.imencode(".png", IMAGE)[1].tobytes())
    chunks[1:1] = list(extra)
    out = b"\x89PNG\r\n\x1a\n"
    for kind, body in chunks:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        if kind == bad_crc:
            crc ^= 0xFFFF
        out += struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)
    return out


#: LittleCMS's sRGB display profile (588 bytes; what Pillow's ImageCms.createProfile("sRGB") writes),
#: zlib-compressed: a real, conforming profile of the kind cameras and their SDKs embed.
_SRGB_PROFILE = zlib.decompress(base64.b64decode(
    "eNqVkTlLA1EUhb8kimIiQRRcEEwRxUJBFMRSY5EmSIgRjNokk03IMswkSLAVbCwCFqKNW+E/0FawVRAERRCxtnRrJIz3JYGIaOEb"
    "3tyPM3Mu950H9kBGy5pN05DNFYyQ3+dZjCx5Wp5x0k0HvQxENVOfCQYD/Lk+brGpejOqevG/5YwnTA1srcKTmm4UhGUaAmsFXfGW"
    "cJeWjsaFD4RHDBlQ+FLpsRo/KU7V+E2xEQ7Ngl319KS+cewba2kjKzws7M1milp9HnUSVyK3MC+1T3Y/JiH8+PAQo8gqGQqMSs1J"
    "Zr/7xqq+OfLi0eStU8IQR4q0eEdELUrXhNSk6Al5MpRU7j/zNJMT47XuLh80P1rW6yC0bEOlbFmfh5ZVOQLHA5znGv685DT1Lnq5"
    "oXn3wb0BpxcNLbYDZ5vQc69HjWhVcsi2J5PwcgLtEei8hrblWlb17xzfQXhdrugKdvdgSP53r3wBIlVoGQ=="))


def _icc_profile(colour_space: bytes = b"RGB ") -> bytes:
    """The sRGB profile with its data colour space replaced (b"GRAY": libpng warns, the chunk is intact)."""
    return _SRGB_PROFILE[:16] + colour_space + _SRGB_PROFILE[20:]


def _iccp(profile: bytes) -> tuple[bytes, bytes]:
    return b"iCCP", b"camera\x00\x00" + zlib.compress(profile)


def _read(tmp_path, data: bytes):
    path = tmp_path / "frame.png"
    path.write_bytes(data)
    return read_image(path), path


@pytest.mark.parametrize("extra", [[(b"sRGB", b"\x00")], [(b"gAMA", struct.pack(">I", 45455))],
                                   [_iccp(_icc_profile())]], ids=["sRGB", "gAMA", "valid-iCCP"])
def test_colour_chunks_as_cameras_write_them_decode_silently(tmp_path, extra, capfd):
    image, _ = _read(tmp_path, _png(extra))
    assert np.array_equal(image, IMAGE)
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize("extra,phrase", [([_iccp(_icc_profile(b"GRAY"))], "Gray color space"),
                                          ([(b"sRGB", b"\x09")], "sRGB: invalid")],
                         ids=["iCCP-gray-profile-on-RGB", "sRGB-bad-intent"])
def test_colour_profile_warning_is_accepted_with_exact_pixels_and_logged(tmp_path, extra, phrase, caplog, capfd):
    """libpng warns about the profile's content; the chunk is intact and OpenCV ignores it: pixels exact."""
    with caplog.at_level(logging.INFO, logger="bodystudio.fileio"):
        image, path = _read(tmp_path, _png(extra))
    assert np.array_equal(image, IMAGE)
    assert any(str(path) in r.getMessage() and phrase in r.getMessage() for r in caplog.records), caplog.text
    assert capfd.readouterr().err == ""  # not on the user's terminal: only with --verbose


@pytest.mark.parametrize("make,phrase", [
    (lambda: _png([_iccp(_icc_profile())], bad_crc=b"iCCP"), "CRC"),
    (lambda: _png([(b"tEXt", b"Software\x00cam")], bad_crc=b"tEXt"), "CRC"),
    (lambda: _png(bad_crc=b"IDAT"), "CRC"),
    (lambda: _png()[:-40], "frame.png"),
], ids=["iCCP-crc", "tEXt-crc", "IDAT-crc", "truncated-file"])
def test_damage_is_refused_naming_the_file(tmp_path, make, phrase):
    with pytest.raises(FileFormatError) as err:
        _read(tmp_path, make())
    text = str(err.value)
    assert "frame.png" in text and phrase in text and "\n" not in text


def test_rule_on_libpng_lines():
    assert colour_profile_warning("libpng warning: iCCP: known incorrect sRGB profile")
    assert colour_profile_warning("libpng warning: iCCP: cHRM chunk does not match sRGB")
    assert colour_profile_warning("libpng warning: Interlace handling should be turned on when using png_read_image")
    assert not colour_profile_warning("libpng warning: iCCP: CRC error")
    assert not colour_profile_warning("libpng warning: iCCP: unexpected zlib return code")
    assert not colour_profile_warning("libpng warning: IDAT: Too many IDATs found")
    assert not colour_profile_warning("libpng warning: tEXt: CRC error")



def test_the_reused_capture_file_carries_nothing_to_the_next_image(tmp_path, capfd):
    """The decoder's stderr capture file is made once per process (issue 15's frame time, rec15i): a damaged image's
    warnings and an accepted profile warning stay with their image; the intact image read after each decodes
    silently, and the program's own output between them reaches the terminal."""
    import os

    from bodystudio.fileio import decode_image

    with pytest.raises(FileFormatError, match="CRC"):
        _read(tmp_path, _png(bad_crc=b"IDAT"))
    image, _ = _read(tmp_path, _png())
    assert np.array_equal(image, IMAGE)
    os.write(2, b"the program's own line\n")
    assert np.array_equal(decode_image(_png([(b"sRGB", b"\x09")]), "p.png"), IMAGE)  # warns, accepted
    assert np.array_equal(decode_image(_png(), "q.png"), IMAGE)
    with pytest.raises(FileFormatError, match="tEXt"):
        decode_image(_png([(b"tEXt", b"Software\x00cam")], bad_crc=b"tEXt"), "r.png")
    assert capfd.readouterr().err == "the program's own line\n"
