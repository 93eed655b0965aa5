"""adv5's import checks in ``capture/importer.py`` against hand-computed cases (mutOO; no import runs, < 1 s).

The frame rate from the frames' times (``recording_fps``, ``video_fps``, ``video_rate_varies``,
``check_video_rates``), the depth unit from the first frame with depth (``check_depth_unit``,
``check_stated_depth_scale``), the masks' half-maximum threshold (``subject_pixels``), the principal-point check
(``check_principal_point_centred``) and drifting frame numbers (``file_frame_number``, ``check_frame_numbers``,
``check_joint_frame_numbers``): each at the edge of its bound and with its whole message.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError

SRC = Path("rec/intri.yml")


def test_principal_point_within_15_percent_of_the_centre_is_taken():
    from bodystudio.capture.importer import check_principal_point_centred

    K = np.array([[500.0, 0, 160 + 0.15 * 320], [0, 500, 120], [0, 0, 1]])
    check_principal_point_centred(K, (320, 240), SRC, "c0")  # 15 % exactly
    K = np.array([[500.0, 0, 160], [0, 500, 120 - 0.15 * 240], [0, 0, 1]])
    check_principal_point_centred(K, (320, 240), SRC, "c0")  # 15 % exactly, in y


def test_principal_point_of_a_larger_calibration_is_refused_naming_its_size():
    from bodystudio.capture.importer import check_principal_point_centred

    K = np.array([[500.0, 0, 160], [0, 500, 120], [0, 0, 1]])
    with pytest.raises(FileFormatError) as e:
        check_principal_point_centred(K, (160, 120), SRC, "c0")  # off by 0.5 in x and y: 50 %
    assert str(e.value) == (
        "rec/intri.yml: camera c0 has no W_c0/H_c0 and its frames are 160x120, but K's principal point (160, 120) "
        "is 50 % of the image off their centre (a lens's lies within a few %): it is for about 320x240 images; "
        "calibrate at the frames' size and orientation, or add W_c0/H_c0 to intri.yml")
    K = np.array([[500.0, 0, 100], [0, 500, 80], [0, 0, 1]])  # y off by 20/120 = 16.7 %, x 0 %
    with pytest.raises(FileFormatError, match=r"is 17 % of the image off"):
        check_principal_point_centred(K, (200, 120), SRC, "c0")


def test_principal_point_of_turned_frames_names_the_turn():
    from bodystudio.capture.importer import check_principal_point_centred

    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])  # for 640x480, frames 480x640
    with pytest.raises(FileFormatError) as e:
        check_principal_point_centred(K, (480, 640), SRC, "phone")
    assert ("is 17 % of the image off their centre (a lens's lies within a few %): the frames are turned 90 degrees "
            "against it (640x480); calibrate") in str(e.value)
    # turned, but only within the bound on one axis: a size, not the turn
    K = np.array([[500.0, 0, 320], [0, 500, 400], [0, 0, 1]])
    with pytest.raises(FileFormatError, match=r"it is for about 640x800 images"):
        check_principal_point_centred(K, (480, 640), SRC, "phone")


def test_recording_fps_is_one_over_the_median_period_within_1_to_240():
    from bodystudio.capture.importer import recording_fps

    assert recording_fps(None) is None and recording_fps([0.5]) is None
    assert recording_fps([0.0, 0.1, 0.2, 0.5, 0.3]) == 10.0  # sorted first: periods 0.1, 0.1, 0.1, 0.2
    assert recording_fps([0.0, 1 / 15, 2 / 15]) == 15.0
    assert recording_fps([0.0, 1 / 7]) == round(7.0, 3) and recording_fps([0.0, 1.0 / 29.97]) == 29.97
    assert recording_fps([0.0, 1.0]) == 1.0 and recording_fps([0.0, 1 / 240]) == 240.0  # both ends taken
    with pytest.raises(FileFormatError) as e:
        recording_fps([0.0, 33.0, 66.0], Path("t.txt"))
    assert str(e.value) == ("t.txt: the median frame period 33 s is not a camera's (1..240 fps); give the times in "
                            "seconds")
    with pytest.raises(FileFormatError, match=r"period 0.004 s"):
        recording_fps([0.0, 0.004, 0.008])
    with pytest.raises(FileFormatError, match=r"period 0 s"):
        recording_fps([1.0, 1.0, 1.0])


def test_video_fps_spans_the_frames_when_even_and_takes_the_median_when_not():
    from bodystudio.capture.importer import video_fps

    assert video_fps(np.array([0.0]), SRC) is None
    assert video_fps(np.array([0.0, 0.0, 0.0]), SRC) is None
    ms = np.array([0.0, 0.067, 0.133, 0.2, 0.267, 0.333, 0.4, 0.467, 0.533, 0.6])  # Matroska ms of 15 fps
    assert video_fps(ms, SRC) == 15.0  # 9 periods over 0.6 s; the median (0.067) gives 14.925
    uneven = np.array([0.0, 0.1, 0.2, 0.3, 0.6, 0.7])
    assert video_fps(uneven, SRC) == 10.0
    assert video_fps(np.array([2.0, 2.5]), SRC) == 2.0


def test_video_rate_varies_beyond_a_quarter_of_the_median_period():
    from bodystudio.capture.importer import video_rate_varies

    assert not video_rate_varies(np.array([0.0, 0.5]))
    assert not video_rate_varies(np.array([0.0, 0.1, 0.2, 0.325]))  # 0.125 = 1.25 x the median: on the bound
    assert video_rate_varies(np.array([0.0, 0.1, 0.2, 0.33]))
    assert video_rate_varies(np.array([0.0, 0.1, 0.2, 0.27]))  # 0.07 < 0.075
    assert not video_rate_varies(np.array([0.0, 0.0, 0.0, 0.0]))


def _video(where, times):
    return SimpleNamespace(where=where, times_s=None if times is None else np.asarray(times, np.float64))


def test_check_video_rates_names_the_first_uneven_frame_and_the_differing_camera():
    from bodystudio.capture.importer import check_video_rates

    even30 = np.arange(10) / 30.0
    held = np.r_[np.arange(6) / 30.0, 6 / 30.0 + 0.1, 7 / 30.0 + 0.1]
    with pytest.raises(FileFormatError) as e:
        check_video_rates({"a": _video("a.mp4", even30), "b": _video("b.mp4", held)})
    assert str(e.value) == ("b.mp4: variable frame rate (frame 6 comes 133 ms after frame 5, the median period is 33 "
                            "ms); frames paired by index would be recorded at different times; give --timestamps "
                            "with each camera's frame times")
    check_video_rates({"b": _video("b.mp4", held)}, n_frames=6)  # the frames imported are steady
    check_video_rates({"b": _video("b.mp4", held)}, paired=False)  # one camera, unpaired: its rate only
    with pytest.raises(FileFormatError) as e:
        check_video_rates({"a": _video("a.mp4", even30), "x": _video("x", None), "c": _video("c.mp4", [0.0]),
                           "b": _video("b.mp4", np.arange(10) / 15.0)})
    assert str(e.value) == ("b.mp4: 15 fps but a.mp4 is 30 fps; frames paired by index would be recorded at different "
                            "times; give --timestamps with each camera's frame times")
    check_video_rates({"a": _video("a.mp4", even30), "b": _video("b.mp4", np.arange(10) / 30.2)})  # within 1 %
    with pytest.raises(FileFormatError, match=r"^b.mp4: 30.4 fps but a.mp4 is 30 fps"):
        check_video_rates({"a": _video("a.mp4", even30), "b": _video("b.mp4", np.arange(10) / 30.4)})
    # unpaired, an uneven camera's rate is one over its median period (10 fps) against 30
    with pytest.raises(FileFormatError, match=r"^b.mp4: 10 fps but a.mp4 is 30 fps"):
        check_video_rates({"a": _video("a.mp4", even30), "b": _video("b.mp4", [0, 0.1, 0.2, 0.3, 0.9])}, paired=False)
    check_video_rates({"a": _video("a.mp4", even30), "z": _video("z.mp4", np.zeros(5))})  # no times: skipped


def _folder(names):
    return SimpleNamespace(files=[Path("cam") / n for n in names])


def test_frame_numbers_are_the_last_digit_run_of_the_stem():
    from bodystudio.capture.importer import file_frame_number

    assert file_frame_number(Path("cam2/img_0012.png")) == 12
    assert file_frame_number(Path("c1_frame7_000034.jpg")) == 34
    assert file_frame_number(Path("x/frame.png")) is None
    assert file_frame_number(Path("7/a12b.png")) == 12


def test_check_frame_numbers_refuses_drift_and_takes_an_offset():
    from bodystudio.capture.importer import check_frame_numbers

    a = _folder([f"{k:05d}.png" for k in (0, 1, 2, 4, 5)])
    b = _folder([f"{k:05d}.png" for k in (0, 1, 2, 3, 5)])
    with pytest.raises(FileFormatError) as e:
        check_frame_numbers({"a": a, "b": b}, 5)
    assert str(e.value) == ("cam/00003.png: paired by order with 00004.png of a, but their frame numbers drift apart "
                            "from there (3 and 4, 0 apart before): a frame dropped by one camera; remove the frames "
                            "not every camera has, or give --timestamps")
    check_frame_numbers({"a": a, "b": b}, 3)  # the first three frames agree
    c = _folder([f"{k:05d}.png" for k in (100, 101, 102, 104, 105)])
    check_frame_numbers({"a": a, "c": c}, 5)  # a constant offset of 100
    with pytest.raises(FileFormatError, match=r"\(103 and 4, 100 apart before\)"):
        check_frame_numbers({"a": a, "c": _folder([f"{k:05d}.png" for k in (100, 101, 102, 103, 105)])}, 5)
    check_frame_numbers({"a": a, "n": _folder(["x.png"] * 5)}, 5)  # unnumbered: not compared
    check_frame_numbers({"a": a, "v": SimpleNamespace()}, 5)  # videos: no files
    every_other = _folder([f"{k:05d}.png" for k in (0, 2, 4, 6, 8)])
    check_frame_numbers({"e": every_other, "a": a}, 5)  # not a frame counter
    check_frame_numbers({"a": a}, 5)


def test_check_joint_frame_numbers_names_the_jump():
    from bodystudio.capture.importer import check_joint_frame_numbers

    check_joint_frame_numbers([3, 4, 5], Path("j.csv"))
    check_joint_frame_numbers([7], Path("j.csv"))
    with pytest.raises(FileFormatError) as e:
        check_joint_frame_numbers([0, 1, 3, 4, 6], Path("j.csv"))
    assert str(e.value) == ("j.csv: the joint frames jump from frame 1 to frame 3; joints go to the recording's frames "
                            "in order, so each later frame's would go to an earlier frame: give one entry per "
                            "recorded frame (tracked 0 where the body was lost)")
    with pytest.raises(FileFormatError, match=r"^joints: the joint frames jump from 00000.json to 00002.json;"):
        check_joint_frame_numbers([0, 2], Path("joints"), ["00000.json", "00002.json"])
    with pytest.raises(FileFormatError, match=r"jump from frame 5 to frame 5;"):
        check_joint_frame_numbers([4, 5, 5], Path("j.csv"))


def test_subject_pixels_above_half_the_brightest_value():
    from bodystudio.capture.importer import subject_pixels

    m = np.array([[0, 1, 127, 128, 129, 255]], np.uint8)
    np.testing.assert_array_equal(subject_pixels(m), [[False, False, False, True, True, True]])  # 2 m > 255
    labels = np.array([[0, 1, 1, 0]], np.uint8)
    np.testing.assert_array_equal(subject_pixels(labels), [[False, True, True, False]])
    np.testing.assert_array_equal(subject_pixels(np.zeros((2, 2), np.uint8)), np.zeros((2, 2), bool))
    soft = np.array([[0, 2, 3, 4]], np.uint8)  # top 4: above 2
    np.testing.assert_array_equal(subject_pixels(soft), [[False, False, True, True]])
    wide = np.array([[0, 30000, 32768, 40000, 65535]], np.uint16)  # no uint16 overflow in 2 m
    np.testing.assert_array_equal(subject_pixels(wide), [[False, False, True, True, True]])
    assert subject_pixels(np.zeros((0, 3), np.uint8)).shape == (0, 3)


def test_stated_depth_scale_puts_the_median_within_0_1_to_20_m():
    from bodystudio.capture.importer import check_stated_depth_scale

    check_stated_depth_scale(np.array([0, 2000, 2000, 9000], np.uint16), Path("d.png"), 1000.0)  # 2 m
    check_stated_depth_scale(np.array([0.0, np.nan, 0.1]), Path("d.exr"), 1.0)  # 0.1 m exactly
    check_stated_depth_scale(np.array([20.0]), Path("d.exr"), 1.0)  # 20 m exactly
    check_stated_depth_scale(np.zeros(4, np.uint16), Path("d.png"), 1.0)  # no depth: nothing to check
    check_stated_depth_scale(np.array([np.nan, 0.0]), Path("d.exr"), 1.0)
    with pytest.raises(FileFormatError) as e:
        check_stated_depth_scale(np.array([2000.0, np.inf, 2000.0]), Path("d.exr"), 1.0)
    assert str(e.value) == ("d.exr: at --depth-scale 1 the median depth is 2000 m, no depth camera's (0.1-20 m); "
                            "pass the units per metre the file is stored in (metres: 1, millimetres: 1000, TUM: 5000)")
    with pytest.raises(FileFormatError, match=r"median depth is 0.002 m"):
        check_stated_depth_scale(np.array([0.0, 2.0, 2.0], np.float32), Path("d.exr"), 1000.0)
    with pytest.raises(FileFormatError, match=r"median depth is 20.5 m"):
        check_stated_depth_scale(np.array([20500, 0], np.uint16), Path("d.png"), 1000.0)


def test_depth_unit_of_a_later_frame_against_the_first():
    from bodystudio.capture.importer import check_depth_unit

    first = Path("d/0.png")
    tum = np.array([0, 10000, 10000], np.uint16)  # 2 m in TUM units
    check_depth_unit(tum, Path("d/1.png"), 5000.0, first, np.uint16, False)
    mm = np.array([0, 2000, 2000], np.uint16)  # 2 m in millimetres, 0.4 m in TUM units
    with pytest.raises(FileFormatError) as e:
        check_depth_unit(mm, Path("d/1.png"), 5000.0, first, np.uint16, False)
    assert str(e.value) == ("d/1.png: depth looks like millimetres (median 2.00 m; 0.40 m at 5000 per metre) but "
                            "d/0.png was read at 5000 per metre; export every depth frame of the recording in one unit")
    check_depth_unit(mm, Path("d/1.png"), 5000.0, first, np.uint16, True)  # a stated scale: not second-guessed
    check_depth_unit(np.zeros(3, np.uint16), Path("d/1.png"), 5000.0, first, np.uint16, False)  # no depth
    check_depth_unit(np.array([0, 2500], np.uint16), Path("d/1.png"), 5000.0, first, np.uint16, False)  # 0.5 m edge
    check_depth_unit(np.array([0, 22500], np.uint16), Path("d/1.png"), 5000.0, first, np.uint16, False)  # 4.5 m edge
    far = np.array([0, 40000, 40000], np.uint16)  # 8 m as TUM, 40 m as mm: no other unit makes it plausible
    check_depth_unit(far, Path("d/1.png"), 5000.0, first, np.uint16, False)
    with pytest.raises(FileFormatError, match=r"^d/1.png: depth looks like TUM units \(median 2.00 m; 10.00 m at "
                       r"1000 per metre\) but d/0.png was read at 1000 per metre"):
        check_depth_unit(tum, Path("d/1.png"), 1000.0, first, np.uint16, False)
    with pytest.raises(FileFormatError) as e:
        check_depth_unit(np.array([2.0], np.float32), Path("d/1.exr"), 5000.0, first, np.dtype(np.uint16), False)
    assert str(e.value) == ("d/1.exr: depth stored as float32 but d/0.png as uint16; export every depth frame of the "
                            "recording in one format")
    check_depth_unit(np.array([2000.0], np.float32), Path("d/1.exr"), 1.0, first, np.dtype(np.float32), False)
    with pytest.raises(FileFormatError, match=r"^d/1.png: depth must be a 16-bit PNG, got uint8"):
        check_depth_unit(np.array([0, 200], np.uint8), Path("d/1.png"), 5000.0, first, np.uint16, False)


# --- the first run's survivors (each case at the edge that tells the mutant apart) ---


def test_principal_point_turn_and_percent_edges():
    from bodystudio.capture.importer import check_principal_point_centred

    K = np.array([[500.0, 0, 330], [0, 500, 245], [0, 0, 1]])  # for 660x490 turned: 10 / 640, 5 / 480 off
    with pytest.raises(FileFormatError, match=r"is 19 % of the image off .* the frames are turned 90 degrees"):
        check_principal_point_centred(K, (480, 640), SRC, "phone")
    K = np.array([[500.0, 0, 416], [0, 500, 240], [0, 0, 1]])  # turned: 96 / 640 = 15 % exactly
    with pytest.raises(FileFormatError, match=r"the frames are turned 90 degrees against it \(640x480\)"):
        check_principal_point_centred(K, (480, 640), SRC, "phone")
    K = np.array([[500.0, 0, 110], [0, 500, 50], [0, 0, 1]])
    with pytest.raises(FileFormatError, match=r"\(110, 50\) is 60 % of the image off"):
        check_principal_point_centred(K, (100, 100), SRC, "c")


def test_video_rate_edges():
    from bodystudio.capture.importer import check_video_rates, video_fps, video_rate_varies

    assert video_rate_varies(np.array([0.0, 0.1, 0.3]))  # three frames are enough
    assert not video_rate_varies(np.array([0.0, 0.5, 1.0, 1.625]))  # 1.25 x the median exactly, in binary
    assert not video_rate_varies(np.array([0.0, 0.0, 0.0, 0.0, 1.0]))  # a median of 0: no rate
    assert video_fps(np.array([0.0, 0.5, 1.0, 1.625]), SRC) == round(3 / 1.625, 3)  # even on the bound: the span
    check_video_rates({"a": _video("a.mp4", [0.0, 0.5, 1.0, 1.625])})
    with pytest.raises(FileFormatError, match=r"^b.mp4: 15 fps but a.mp4 is 30 fps"):  # two frames are a rate
        check_video_rates({"a": _video("a.mp4", np.arange(10) / 30.0), "b": _video("b.mp4", [0.0, 1 / 15])})
    with pytest.raises(FileFormatError, match=r"^b.mp4: 15 fps but a.mp4 is 30 fps"):  # a camera without times
        check_video_rates({"a": _video("a.mp4", np.arange(10) / 30.0), "z": _video("z.mp4", np.zeros(4)),
                           "y": SimpleNamespace(where="y"), "b": _video("b.mp4", np.arange(5) / 15.0)})
    with pytest.raises(FileFormatError) as e:
        check_video_rates({"a": _video("a.mp4", [0.0, 0.7, 1.4, 2.1, 3.5])})
    assert "(frame 4 comes 1400 ms after frame 3, the median period is 700 ms)" in str(e.value)
    # an even camera's rate is its frames over their span (here 5 / 0.54 s), not one over the median period
    with pytest.raises(FileFormatError, match=r"^b.mp4: 9.26 fps but a.mp4 is 10 fps"):
        check_video_rates({"a": _video("a.mp4", 2.0 + np.arange(6) / 10.0),
                           "b": _video("b.mp4", [0.0, 0.1, 0.2, 0.3, 0.42, 0.54])})
    check_video_rates({"a": _video("a.mp4", np.arange(101) / 100.0),  # 100 and 101 fps: 1 % apart exactly
                       "b": _video("b.mp4", np.arange(102) / 101.0)})


def test_video_fps_and_recording_fps_edges():
    from bodystudio.capture.importer import recording_fps, video_fps

    with pytest.raises(FileFormatError, match=r"^rec/intri.yml: the median frame period 33 s"):
        video_fps(np.array([0.0, 33.0, 66.0]), SRC)
    with pytest.raises(FileFormatError, match=r"^rec/intri.yml: the median frame period 33 s"):
        video_fps(np.array([0.0, 33.0, 66.0, 130.0]), SRC)
    with pytest.raises(FileFormatError):
        recording_fps([0.0, 1 / 240.5])
    assert recording_fps([0.0, 0.0334]) == 29.94


def test_frame_numbers_edges():
    from bodystudio.capture.importer import check_frame_numbers, check_joint_frame_numbers

    a = _folder([f"{k:05d}.png" for k in (0, 1, 2, 3, 4)])
    b = _folder([f"{k:05d}.png" for k in (0, 2, 3, 4, 5)])
    check_frame_numbers({"a": a, "b": b}, 1)
    with pytest.raises(FileFormatError) as e:
        check_frame_numbers({"a": a, "b": b}, 5)
    assert str(e.value).startswith("cam/00002.png: paired by order with 00001.png of a, but their frame numbers drift "
                                   "apart from there (2 and 1, 0 apart before)")
    check_frame_numbers({"e": _folder(["00000.png", "00002.png"]), "a": a}, 2)  # two frames two apart: no counter
    with pytest.raises(FileFormatError, match=r"jump from b.json to c.json;"):
        check_joint_frame_numbers([0, 1, 3], Path("j"), ["a.json", "b.json", "c.json"])


def test_depth_edges():
    from bodystudio.capture.importer import check_depth_unit, check_stated_depth_scale

    check_stated_depth_scale(np.array([1.0, np.inf]), Path("d.exr"), 1.0)  # inf is no depth
    check_stated_depth_scale(np.array([0.5, 0.5, 25.0]), Path("d.exr"), 1.0)  # sub-unit floats count
    with pytest.raises(FileFormatError, match=r"median depth is 0.001 m"):
        check_stated_depth_scale(np.array([1, 1, 1, 5000], np.uint16), Path("d.png"), 1000.0)
    first, f1 = Path("d/0.png"), Path("d/1.png")
    with pytest.raises(FileFormatError, match=r"^d/1.png: depth looks like metres \(median 1.00 m;"):
        check_depth_unit(np.array([1, 1, 1, 10000], np.uint16), f1, 5000.0, first, np.uint16, False)
    with pytest.raises(FileFormatError, match=r"looks like millimetres \(median 2.00 m;"):
        check_depth_unit(np.array([0, 2000], np.uint16), f1, 5000.0, first, np.uint16, False)  # one pixel
    check_depth_unit(np.array([4500], np.uint16), f1, 1000.0, first, np.uint16, False)  # 4.5 m as mm: inclusive
    with pytest.raises(FileFormatError, match=r"looks like TUM units \(median 0.90 m; 4.50 m at 1000"):
        check_depth_unit(np.array([4504], np.uint16), f1, 1000.0, first, np.uint16, False)
    with pytest.raises(FileFormatError) as e:
        check_depth_unit(np.array([2, 2], np.uint16), f1, 5000.0, first, np.uint16, False)
    assert str(e.value).startswith("d/1.png: depth looks like metres (median 2.00 m; 0.00 m at 5000 per metre)")
    with pytest.raises(FileFormatError, match=r"looks like millimetres \(median 0.50 m;"):
        check_depth_unit(np.array([500], np.uint16), f1, 5000.0, first, np.uint16, False)
    check_depth_unit(np.array([4500], np.uint16), f1, 1.0, first, np.uint16, False)  # TUM 0.9 and mm 4.5: ambiguous


def test_subject_pixels_of_a_two_level_mask():
    from bodystudio.capture.importer import subject_pixels

    np.testing.assert_array_equal(subject_pixels(np.array([[0, 1, 2]], np.uint8)), [[False, False, True]])
