"""Analytic checks of garment/person.py (the actor's frames and mattes, input of §4 of Garment Replacement).

Written for mutation testing (issue 17; the module had no test file of its own): the frame-range grammar and
its messages, the temporal-median plate, the mattes of a square moving over a static textured set, the
person-size checks at their thresholds, the clean plate reader, a tiny lossless-ish video, and a stand-in
session. Each test well under a second or two; no body model.
"""

import re
from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.garment import person as gp


def exact(message):
    """A ``pytest.raises(match=...)`` pattern for exactly this message."""
    return "^" + re.escape(str(message)) + "$"


# ------------------------------------------------------------------------------------------ --frames


@pytest.mark.parametrize("frames, n, want", [(None, 7, (0, 7)), ("", 7, (0, 7)), ("2:5", 7, (2, 5)),
                                             (":3", 7, (0, 3)), ("4:", 7, (4, 7)), ("0:7", 7, (0, 7)),
                                             ("6:7", 7, (6, 7)), (":", 7, (0, 7))])
def test_frame_range_is_a_python_slice_with_optional_ends(frames, n, want):
    s = gp.parse_frame_range(frames, n, "clip.mp4")
    assert (s.start, s.stop, s.step) == (*want, None)


@pytest.mark.parametrize("frames", ["0:8", "7:", "7:9", "3:8"])
def test_frame_range_beyond_the_clip_is_refused_naming_it(frames):
    with pytest.raises(InputError, match=exact(f"--frames {frames}: out of range; clip.mp4 has frames 0:7")):
        gp.parse_frame_range(frames, 7, "clip.mp4")


@pytest.mark.parametrize("frames", ["5", "1:2:3", "a:3", "1:b", "1.5:3"])
def test_malformed_frame_range_is_one_line(frames):
    with pytest.raises(InputError, match=exact(f"--frames {frames!r}: use START:END (frame indices, e.g. 0:60)")):
        gp.parse_frame_range(frames, 7, "clip.mp4")
    with pytest.raises(InputError, match=exact(f"--frames {frames!r}: use START:END (frame indices, e.g. 0:60)")):
        gp._requested_end(frames)


@pytest.mark.parametrize("frames", ["5:2", "3:3", "-1:4", "-2:"])
def test_reversed_or_negative_frame_range_is_refused(frames):
    with pytest.raises(InputError, match=exact(f"--frames {frames}: START must be >= 0 and below END (e.g. 0:60)")):
        gp._frame_range_ends(frames)


def test_frame_range_ends_and_the_requested_end():
    assert gp._frame_range_ends("0:1") == (0, 1) and gp._frame_range_ends(":") == (0, None)
    assert gp._frame_range_ends("3:") == (3, None) and gp._frame_range_ends(":4") == (0, 4)
    assert gp._requested_end(None) is None and gp._requested_end("") is None
    assert gp._requested_end("2:9") == 9 and gp._requested_end("2:") is None


# ------------------------------------------------------------------------------------------ mattes


def moving_square(n=9, H=48, W=64, side=14, seed=0):
    """A static textured set with a dark square crossing it left to right; the true masks."""
    rng = np.random.default_rng(seed)
    plate = rng.integers(90, 200, (H, W, 3)).astype(np.uint8)
    images, masks = [], []
    for k in range(n):
        img = plate.copy()
        m = np.zeros((H, W), bool)
        c0 = 2 + k * (W - side - 4) // (n - 1)
        m[17:17 + side, c0:c0 + side] = True
        img[m] = (30, 20, 120)
        images.append(img)
        masks.append(m)
    return np.stack(images), np.stack(masks), plate


def test_temporal_background_is_the_per_pixel_median():
    images, _, plate = moving_square()
    bg = gp.temporal_background(images)
    assert bg.dtype == np.float32 and bg.shape == plate.shape
    assert np.array_equal(bg, plate.astype(np.float32))  # the square covers each pixel in few frames
    # an even count of frames: the median is the mean of the middle two
    pair = np.stack([np.zeros((2, 2, 3), np.uint8), np.full((2, 2, 3), 10, np.uint8)])
    assert np.all(gp.temporal_background(pair) == 5.0)


def test_temporal_background_subsamples_long_clips_to_about_60_frames():
    n = 180  # step 3: frames 0, 3, 6, ... are used
    images = np.zeros((n, 1, 1, 3), np.uint8)
    images[1::3] = 200  # frames never used by the step: the median stays 0
    images[2::3] = 200
    assert np.all(gp.temporal_background(images) == 0)
    assert np.all(gp.temporal_background(images[:119]) == 200)  # step 1: two thirds are 200


def test_mattes_follow_the_moving_square_against_the_median_and_a_clean_plate():
    images, masks, plate = moving_square()
    got = gp.person_mattes(images)
    assert got.dtype == bool and got.shape == masks.shape
    iou = (got & masks).sum() / (got | masks).sum()
    assert iou > 0.95, iou
    clean = gp.person_mattes(images, plate=plate)
    assert (clean & masks).sum() / (clean | masks).sum() > 0.95
    # a plate equal to the frame itself: nothing moves, no matte
    assert not gp.person_mattes(images[:1], plate=images[0]).any()


def test_mattes_keep_only_the_largest_region():
    images, masks, plate = moving_square()
    speck = images.copy()
    speck[:, 2:5, 2:5] = (30, 20, 120)  # a 3x3 speck far from the square in every frame
    got = gp.person_mattes(speck, plate=plate)
    assert not got[:, 2:5, 2:5].any()
    assert (got & masks).sum() / (got | masks).sum() > 0.95


def test_check_person_thresholds_and_messages():
    H, W, n = 20, 20, 4  # 400 px: 0.5 % is 2 px, 85 % is 340 px
    masks = np.zeros((n, H, W), bool)
    with pytest.raises(InputError, match=exact(
            "clip: no person found (the largest moving region covers 0.00 % of the image); film the actor moving "
            "in front of a static background, or pass --background PLATE.png (a frame of the empty set)")):
        gp.check_person(masks, "clip")
    masks.reshape(n, -1)[:, :2] = True  # exactly 0.5 % in every frame: accepted
    gp.check_person(masks, "clip")
    one = np.zeros((n, H, W), bool)
    one.reshape(n, -1)[:, :1] = True  # 0.25 % everywhere
    with pytest.raises(InputError, match=r"covers 0\.25 % of the image"):
        gp.check_person(one, "clip")
    flood = np.zeros((n, H, W), bool)
    flood.reshape(n, -1)[:3, :341] = True  # 85.25 % in 3 of 4 frames
    flood.reshape(n, -1)[3, :100] = True
    with pytest.raises(InputError, match=exact(
            "clip: no person found (the moving region covers 85 % of the image in 3 of 4 frames: the camera, the "
            "light or the image noise moves, not an actor); use a clip from a fixed camera in front of a static "
            "background, or pass --background PLATE.png (a frame of the empty set)")):
        gp.check_person(flood, "clip")
    half = flood.copy()
    half.reshape(n, -1)[2, 100:] = False  # flooded in 2 of 4: not more than half
    gp.check_person(half, "clip")
    at = np.zeros((n, H, W), bool)
    at.reshape(n, -1)[:, :340] = True  # exactly 85 %: not flooded
    gp.check_person(at, "clip")
    gap = masks.copy()
    gap[1] = False
    gap[3].reshape(-1)[1] = False  # 1 px = 0.25 %
    with pytest.raises(InputError, match=exact(
            "clip: no person found in 2 of 4 frames; pass --frames to the range where the actor is in view, or "
            "--background PLATE.png (a frame of the empty set) when the actor stays on the spot")):
        gp.check_person(gap, "clip")


# ------------------------------------------------------------------------------------------ files


def test_background_plate_is_read_as_rgb_float_and_checked_for_size(tmp_path):
    import cv2

    rgb = np.zeros((6, 8, 3), np.uint8)
    rgb[..., 0] = 200  # red
    rgb[2, 3] = (10, 20, 30)
    path = tmp_path / "plate.png"
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    got = gp.read_background_plate(path, (8, 6))
    assert got.dtype == np.float32 and np.array_equal(got, rgb.astype(np.float32))
    with pytest.raises(InputError, match=exact(f"--background {path}: 8x6 but the video is 6x8; give a frame of the "
                                               f"same camera and resolution")):
        gp.read_background_plate(path, (6, 8))
    missing = tmp_path / "none.png"
    with pytest.raises(InputError, match=exact(f"--background {missing}: no such image; give a frame of the empty "
                                               f"set (PNG or JPEG)")):
        gp.read_background_plate(missing, (8, 6))


def write_video(path, frames, fps=12.0):
    import imageio_ffmpeg

    h, w = frames[0].shape[:2]
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, macro_block_size=1, quality=10)
    writer.send(None)
    for f in frames:
        writer.send(np.ascontiguousarray(f))
    writer.close()
    return path


def test_read_video_frames_fps_and_range(tmp_path):
    frames = [np.full((16, 16, 3), 20 * k, np.uint8) for k in range(6)]
    path = write_video(tmp_path / "v.mp4", frames)
    images, fps = gp.read_video(path)
    assert images.shape == (6, 16, 16, 3) and images.dtype == np.uint8 and fps == 12.0
    assert np.all(np.abs(images.reshape(6, -1).mean(1) - 20 * np.arange(6)) < 4)  # frame k is grey 20 k
    part, _ = gp.read_video(path, "2:4")
    assert np.array_equal(part, images[2:4])
    tail, _ = gp.read_video(path, "3:")
    assert np.array_equal(tail, images[3:])
    with pytest.raises(InputError, match=exact("--frames 2:9: out of range; " + str(path) + " has frames 0:6")):
        gp.read_video(path, "2:9")


def test_read_video_stops_at_the_requested_end_and_caps_long_clips(tmp_path, monkeypatch):
    import imageio_ffmpeg

    frames = [np.full((8, 8, 3), 10 * k, np.uint8) for k in range(6)]
    path = write_video(tmp_path / "v.mp4", frames)
    real = imageio_ffmpeg.read_frames
    pulled = []

    def counting(*a, **kw):
        gen = real(*a, **kw)
        yield next(gen)
        for raw in gen:
            pulled.append(1)
            yield raw

    monkeypatch.setattr(imageio_ffmpeg, "read_frames", counting)
    images, _ = gp.read_video(path, "1:3")
    assert len(images) == 2 and len(pulled) == 3  # frames 0, 1, 2 read, not the rest
    pulled.clear()
    monkeypatch.setattr(gp, "MAX_VIDEO_FRAMES", 4)
    with pytest.raises(InputError, match=exact(f"{path}: more than 4 frames; cut the clip or pass --frames a:b")):
        gp.read_video(path)
    assert len(pulled) == 5
    monkeypatch.setattr(gp, "MAX_VIDEO_FRAMES", 5)
    assert len(gp.read_video(path, "0:6")[0]) == 6  # the requested end is checked before the cap
    with pytest.raises(InputError, match="more than 5 frames"):
        gp.read_video(path)


def test_read_video_refusals(tmp_path):
    missing = tmp_path / "none.mp4"
    with pytest.raises(InputError, match=exact(f"{missing}: no such video file or session folder")):
        gp.read_video(missing)
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"not a video at all" * 10)
    with pytest.raises(FileFormatError, match=r"^" + re.escape(f"{junk}: unreadable video (") + r".+"
                       + re.escape("); pass a video file ffmpeg can decode") + "$"):
        gp.read_video(junk)
    with pytest.raises(InputError, match=exact("--frames '1-2': use START:END (frame indices, e.g. 0:60)")):
        gp.read_video(write_video(tmp_path / "ok.mp4", [np.zeros((8, 8, 3), np.uint8)] * 2), "1-2")


def test_read_video_of_no_frames_and_decoder_errors(tmp_path, monkeypatch):
    import imageio_ffmpeg

    path = write_video(tmp_path / "v.mp4", [np.zeros((8, 8, 3), np.uint8)] * 2)

    def header_only(*a, **kw):
        yield {"size": (8, 8), "fps": 25.0}

    monkeypatch.setattr(imageio_ffmpeg, "read_frames", header_only)
    with pytest.raises(FileFormatError, match=exact(f"{path}: the video has no frames; pass a video with the actor "
                                                    f"in it")):
        gp.read_video(path)

    def no_fps(*a, **kw):
        yield {"size": (8, 8), "fps": None}
        yield bytes(8 * 8 * 3)

    monkeypatch.setattr(imageio_ffmpeg, "read_frames", no_fps)
    images, fps = gp.read_video(path)
    assert fps == 30.0 and images.shape == (1, 8, 8, 3)

    def fails(*a, **kw):
        raise RuntimeError("  \n")
        yield

    monkeypatch.setattr(imageio_ffmpeg, "read_frames", fails)
    with pytest.raises(FileFormatError, match=exact(f"{path}: unreadable video (RuntimeError); pass a video file "
                                                    f"ffmpeg can decode")):
        gp.read_video(path)

    def long_message(*a, **kw):
        raise KeyError("x" * 200 + "\nsecond line")
        yield

    monkeypatch.setattr(imageio_ffmpeg, "read_frames", long_message)
    with pytest.raises(FileFormatError, match=exact(f"{path}: unreadable video ('{'x' * 119}); pass a video file "
                                                    f"ffmpeg can decode")):
        gp.read_video(path)


def test_person_frames_of_a_video_number_the_frames_from_the_range_start(tmp_path):
    images, masks, plate = moving_square(n=8, H=48, W=64)
    path = write_video(tmp_path / "clip.mp4", list(images))
    pf = gp.person_frames(path, "2:6")
    assert pf.source == str(path) and pf.fps == 12.0 and pf.size == (64, 48)
    assert np.array_equal(pf.frame_ids, [2, 3, 4, 5]) and pf.frame_ids.dtype == np.int64
    assert pf.images.shape == (4, 48, 64, 3) and pf.masks.shape == (4, 48, 64)
    # the mattes of the decoded frames against their own temporal median (H.264 blurs the square's edges)
    assert np.array_equal(pf.masks, gp.person_mattes(pf.images))
    assert pf.masks[:, 17:31].sum() > 0.8 * pf.masks.sum()  # on the square's rows
    whole = gp.person_frames(path)
    assert np.array_equal(whole.frame_ids, np.arange(8))


def test_person_frames_with_a_clean_plate(tmp_path, monkeypatch):
    """--background: the mattes against the plate image (read as RGB), the frames as read (no codec here)."""
    import cv2

    images, masks, plate = moving_square(n=5)
    static = images.copy()
    static[:] = images[2]  # the actor stays on the spot: the temporal median would not find them
    monkeypatch.setattr(gp, "read_video", lambda path, frames=None: (static[1:4] if frames else static, 25.0))
    (tmp_path / "clip.mp4").write_bytes(b"")
    cv2.imwrite(str(tmp_path / "plate.png"), cv2.cvtColor(plate, cv2.COLOR_RGB2BGR))
    pf = gp.person_frames(tmp_path / "clip.mp4", "1:4", background=tmp_path / "plate.png")
    assert np.array_equal(pf.frame_ids, [1, 2, 3]) and pf.fps == 25.0
    assert (pf.masks & masks[2]).sum() / (pf.masks | masks[2]).sum() > 0.95
    with pytest.raises(InputError, match="no person found"):
        gp.person_frames(tmp_path / "clip.mp4")


def test_person_frames_refusals(tmp_path):
    missing = tmp_path / "gone.mp4"
    with pytest.raises(InputError, match=exact(f"{missing}: no such video file or session folder")):
        gp.person_frames(missing)
    with pytest.raises(InputError, match=exact(f"--background: {tmp_path} is a session with its own masks; pass it "
                                               f"for a video file only")):
        gp.person_frames(tmp_path, background="plate.png")
    still = write_video(tmp_path / "still.mp4", [np.full((32, 32, 3), 120, np.uint8)] * 4)
    with pytest.raises(InputError, match=r"^" + re.escape(f"{still}: no person found (the largest moving region")):
        gp.person_frames(still)


def fake_session(n=5, H=6, W=8, cams=("cam_00", "cam_01"), streams=("rgb", "mask"), fps=24.0):
    def frame(fid):
        img = np.full((H, W, 3), fid, np.uint8)
        mask = np.zeros((H, W), bool)
        mask[:, fid % W] = True
        return SimpleNamespace(images={c: img + i for i, c in enumerate(cams)},
                               masks={c: mask if i == 0 else ~mask for i, c in enumerate(cams)})

    meta = {} if fps is None else {"fps": fps}
    return SimpleNamespace(camera_names=list(cams), streams=list(streams), frame_ids=[10 + k for k in range(n)],
                           frame=frame, metadata=meta)


def test_session_frames_are_the_first_cameras_images_and_masks(tmp_path, monkeypatch):
    import bodystudio.capture.session as cs

    monkeypatch.setattr(cs, "open_session", lambda path: fake_session())
    pf = gp.session_person_frames(tmp_path / "s", "1:4")
    assert pf.source == str(tmp_path / "s") and pf.fps == 24.0
    assert np.array_equal(pf.frame_ids, [11, 12, 13]) and pf.frame_ids.dtype == np.int64
    assert np.array_equal(pf.images[:, 0, 0, 0], [11, 12, 13])  # cam_00's images, not cam_01's (+1)
    assert np.array_equal(pf.masks[:, 0].argmax(1), [3, 4, 5])  # cam_00's masks (column fid % 8)
    assert pf.masks.dtype == bool
    whole = gp.session_person_frames(tmp_path / "s")
    assert np.array_equal(whole.frame_ids, [10, 11, 12, 13, 14])
    monkeypatch.setattr(cs, "open_session", lambda path: fake_session(fps=None))
    assert gp.session_person_frames(tmp_path / "s").fps == 30.0
    with pytest.raises(InputError, match=exact(f"--frames 2:9: out of range; {tmp_path / 's'} has frames 0:5")):
        gp.session_person_frames(tmp_path / "s", "2:9")


@pytest.mark.parametrize("kw", [{"cams": ()}, {"streams": ("rgb",)}, {"streams": ("mask",)}])
def test_session_without_rgb_and_masks_is_refused(tmp_path, monkeypatch, kw):
    import bodystudio.capture.session as cs

    monkeypatch.setattr(cs, "open_session", lambda path: fake_session(**kw))
    with pytest.raises(InputError, match=exact(f"{tmp_path}: session has no rgb and mask streams; run 'bodystudio "
                                               f"capture silhouettes' first or pass the video file")):
        gp.session_person_frames(tmp_path)


def test_person_frames_of_a_session_folder_are_checked_for_a_person(tmp_path, monkeypatch):
    import bodystudio.capture.session as cs

    monkeypatch.setattr(cs, "open_session", lambda path: fake_session(H=20, W=20))
    pf = gp.person_frames(tmp_path, "0:2")
    assert np.array_equal(pf.frame_ids, [10, 11])  # one column of 20: 5 % of the image
    monkeypatch.setattr(cs, "open_session", lambda path: fake_session(H=20, W=400))
    with pytest.raises(InputError, match=r"covers 0\.25 % of the image"):
        gp.person_frames(tmp_path)


# ------------------------------------------------------------------------------------------ survivors of the first run


def test_check_person_reports_the_percentage_to_two_decimals():
    """441 of 100000 pixels is 0.441 %: "0.44" (a factor of 1.01 would print 0.45)."""
    masks = np.zeros((2, 250, 400), bool)
    masks.reshape(2, -1)[:, :441] = True
    with pytest.raises(InputError, match=r"covers 0\.44 % of the image"):
        gp.check_person(masks, "clip")


def test_person_frames_number_frames_beyond_the_first_ninety(tmp_path, monkeypatch):
    images, _, _ = moving_square(n=5)
    monkeypatch.setattr(gp, "read_video", lambda path, frames=None: (images, 30.0))
    (tmp_path / "long.mp4").write_bytes(b"")
    pf = gp.person_frames(tmp_path / "long.mp4", "995:1000")
    assert np.array_equal(pf.frame_ids, [995, 996, 997, 998, 999])


def test_mattes_are_exactly_the_square_and_drop_a_companion_under_half_its_size():
    """A clean square on a textured set: the matte is the square to the pixel (the 2 px closing does not move or
    trim it, no opening); a second square of a third of its area is dropped (kept: half the largest or more)."""
    images, masks, plate = moving_square()
    got = gp.person_mattes(images, plate=plate)
    assert np.array_equal(got, masks)
    two = images.copy()
    two[:, 36:44, 2:10] = (30, 20, 120)  # 64 px = 0.33 of the square's 196, away from it in every frame
    assert np.array_equal(gp.person_mattes(two, plate=plate), masks)
    big = images.copy()
    big[:, 33:43, 50:60] = (30, 20, 120)  # 100 px = 0.51: kept
    big_masks = masks.copy()
    big_masks[:, 33:43, 50:60] = True
    both = gp.person_mattes(big[:4], plate=plate)
    assert np.array_equal(both, big_masks[:4] | (masks[:4]))


def test_session_is_opened_at_the_given_path(tmp_path, monkeypatch):
    import bodystudio.capture.session as cs

    opened = []
    monkeypatch.setattr(cs, "open_session", lambda path: opened.append(path) or fake_session())
    gp.session_person_frames(tmp_path / "s")
    assert opened == [tmp_path / "s"]


def test_the_two_pixel_closing_fills_a_one_pixel_notch():
    """A 1 px wide, 5 px deep notch cut into the square from its top edge (the set shows through) is closed by
    the 2 px closing; no closing leaves it, a 3 px (cross) closing leaves its mouth."""
    images, masks, plate = moving_square(n=3)
    notched = images.copy()
    for k in range(3):
        c0 = int(np.flatnonzero(masks[k].any(0))[0])
        notched[k, 17:22, c0 + 6] = plate[17:22, c0 + 6]
    assert np.array_equal(gp.person_mattes(notched, plate=plate), masks)
