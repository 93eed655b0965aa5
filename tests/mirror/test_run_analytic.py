"""The mirror loop's per-frame logic (§5 of Real-time Reshaping) on tiny images and stand-in sessions.

A frame without joints, without depth, with too few vertex pairs or an unreadable file passes through
unchanged with its warning; an empty frame teaches the background; a person moved by a known translation
lands exactly where the pairs say, the hole behind is filled from the background model and bystanders stay;
the session side ramps the edit, warm-starts the IK and marks pixels the depth camera never saw.
"""

import logging
import os
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.mirror import run as run_mod
from bodystudio.mirror.compose import confident_background, update_background
from bodystudio.mirror.run import (
    IMAGE_STEPS,
    MIN_PAIRS,
    MLS_ALPHA,
    MLS_RADIUS_PX,
    MirrorInput,
    mirror_frame,
    mirror_stream,
)

H, W = 120, 160
SHIFT = 6


def _scene():
    """A wall (the learnt background), a red person, a blue bystander (another player), the person's pairs
    moved SHIFT px to the right."""
    wall = np.zeros((H, W, 3), np.uint8)
    wall[..., 0] = (np.arange(W)[None] * 1.5).astype(np.uint8)
    wall[..., 1] = 100
    wall[..., 2] = (np.arange(H)[:, None] * 2).astype(np.uint8)
    person = np.zeros((H, W), bool)
    person[30:90, 50:80] = True
    others = np.zeros((H, W), bool)
    others[40:80, 125:145] = True
    rgb = wall.copy()
    rgb[person] = (220, 30, 30)
    rgb[others] = (20, 20, 230)
    ys, xs = np.mgrid[32:90:6, 52:80:6]
    src = np.column_stack([xs.ravel(), ys.ravel()]).astype(float)
    return SimpleNamespace(wall=wall, person=person, others=others, rgb=rgb, src=src, dst=src + [SHIFT, 0.0],
                           background=update_background(None, wall, np.zeros((H, W), bool)))


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_a_frame_without_joints_passes_through_unchanged_with_a_warning(scene):
    inp = MirrorInput(7, scene.rgb, scene.person, scene.others,
                      warning="player 1 is in the mask but no body is tracked", timings_ms={"read": 1.5})
    res, bg = mirror_frame(inp, scene.background)
    assert res.status == "passed_through" and res.warning == inp.warning and res.index == 7
    np.testing.assert_array_equal(res.output, scene.rgb)
    assert res.output is not scene.rgb
    np.testing.assert_array_equal(res.foreground, scene.person)
    np.testing.assert_array_equal(res.warped, scene.person)
    assert res.timings_ms["read"] == 1.5 and res.timings_ms["background"] >= 0 and "warp" not in res.timings_ms
    # the background model learns only away from every player (15 px margin)
    far = confident_background(scene.person | scene.others, 15)
    assert bg.frames == scene.background.frames + 1
    np.testing.assert_array_equal(bg.image[~far], scene.background.image[~far])
    np.testing.assert_array_equal(bg.image[far], scene.wall[far])
    rgb2 = scene.rgb.copy()
    rgb2[~(scene.person | scene.others)] = 9
    res2, bg2 = mirror_frame(MirrorInput(8, rgb2, scene.person, scene.others, warning="x"), scene.background)
    near = ~far
    np.testing.assert_array_equal(bg2.image[near], scene.wall[near])  # the players' surroundings are kept
    assert (np.abs(bg2.image[far].astype(int) - (scene.wall[far] / 2 + 4.5)) <= 1).all()  # rate 0.5


def test_an_empty_frame_passes_through_and_teaches_the_background(scene):
    res, bg = mirror_frame(MirrorInput(0, scene.wall), None)
    assert res.status == "empty" and res.warning is None
    np.testing.assert_array_equal(res.output, scene.wall)
    assert not res.foreground.any() and not res.warped.any()
    assert bg.valid.all() and bg.frames == 1
    np.testing.assert_array_equal(bg.image, scene.wall)
    # another player only (nobody to reshape): empty, and the bystander is not learnt
    res, bg = mirror_frame(MirrorInput(1, scene.rgb, None, scene.others), None)
    assert res.status == "empty"
    np.testing.assert_array_equal(bg.valid, confident_background(scene.others, 15))


@pytest.mark.parametrize("n, ok", [(None, False), (0, False), (MIN_PAIRS - 1, False), (MIN_PAIRS, True)])
def test_too_few_vertex_pairs_pass_through(scene, n, ok):
    src = None if n is None else scene.src[:n]
    dst = None if n is None else scene.dst[:n]
    unseen = np.zeros((H, W), bool)
    unseen[:, :10] = True  # the model has seen this strip; a new colour there must not be learnt
    rgb = scene.rgb.copy()
    rgb[:, :10] = 3
    res, bg = mirror_frame(MirrorInput(3, rgb, scene.person, None, None, src, dst, timings_ms={"read": 1.0},
                                       unseen=unseen), scene.background)
    assert res.index == 3 and res.timings_ms["read"] == 1.0
    np.testing.assert_array_equal(bg.image[:, :10], scene.wall[:, :10])
    if ok:
        assert res.status == "ok" and res.warning is None
    else:
        assert res.status == "passed_through"
        assert res.warning == f"only {n or 0} visible vertex pairs (need {MIN_PAIRS})"
        np.testing.assert_array_equal(res.output, rgb)


def test_a_translated_person_lands_where_the_pairs_say_and_bystanders_stay(scene):
    inp = MirrorInput(4, scene.rgb, scene.person, scene.others, None, scene.src, scene.dst, timings_ms={"ik": 2.0})
    res, bg = mirror_frame(inp, scene.background)
    assert res.status == "ok" and res.warning is None and res.index == 4
    np.testing.assert_array_equal(res.foreground, scene.person)
    shifted = np.roll(scene.person, SHIFT, axis=1)
    np.testing.assert_array_equal(res.warped, shifted)
    inner = cv2.erode(shifted.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert (res.output[inner] == (220, 30, 30)).all()
    hole = scene.person & ~shifted
    np.testing.assert_array_equal(res.output[hole], scene.wall[hole])  # from the background model
    far = ~(cv2.dilate((scene.person | shifted | scene.others).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0)
    np.testing.assert_array_equal(res.output[far], scene.rgb[far])
    assert set(IMAGE_STEPS) <= set(res.timings_ms) and res.timings_ms["ik"] == 2.0
    assert all(res.timings_ms[s] >= 0 for s in IMAGE_STEPS)
    # the model learns away from the refined foreground, the SDK mask and the bystander
    assert bg.frames == scene.background.frames + 1
    near = ~confident_background(scene.person | scene.others, 15)
    np.testing.assert_array_equal(bg.image[near], scene.background.image[near])


def test_bystanders_are_not_erased_from_the_output(scene):
    """Another player (not reshaped) is part of the frame: the mirror shows them as they are. (It used to
    hand compose() ``fg | others`` as the input foreground, so every bystander became a hole and was
    replaced by the background model, or inpainted where the model had never seen behind them.)"""
    inp = MirrorInput(4, scene.rgb, scene.person, scene.others, None, scene.src, scene.dst)
    res, bg = mirror_frame(inp, scene.background)
    assert res.status == "ok"
    np.testing.assert_array_equal(res.output[scene.others], scene.rgb[scene.others])
    # and never learnt as background
    near = ~confident_background(scene.others, 15)
    np.testing.assert_array_equal(bg.image[near], scene.background.image[near])


def test_without_a_background_model_the_holes_are_inpainted(scene):
    res, bg = mirror_frame(MirrorInput(5, scene.rgb, scene.person, None, None, scene.src, scene.dst), None)
    assert res.status == "ok"
    hole = scene.person & ~np.roll(scene.person, SHIFT, axis=1)
    assert not (res.output[hole] == (220, 30, 30)).all(axis=1).all()
    assert bg.frames == 2  # the empty start, then this frame's confident pixels
    np.testing.assert_array_equal(bg.valid, confident_background(scene.person, 15))


def test_the_image_steps_get_the_frames_inputs(scene, monkeypatch):
    """What mirror_frame hands the graph cut, the MLS field and the background update."""
    seen = {}
    real_refine, real_field, real_update = run_mod.refine_foreground, run_mod.mls_warp_field, run_mod.update_background

    def refine(rgb, mask, depth, **kw):
        seen["refine"] = (mask, depth, kw)
        out = real_refine(rgb, mask, depth, **kw)
        out[30:36] = False  # the graph cut took the top of the SDK mask away
        seen["fg"] = out
        return out

    def field(src, dst, shape, **kw):
        seen["field"] = (src, dst, shape, dict(kw))
        kw["dense"] = None  # the stand-in below is no correspondence
        return real_field(src, dst, shape, **kw)

    def update(model, rgb, fg, **kw):
        seen.setdefault("update", []).append((fg, kw))
        return real_update(model, rgb, fg, **kw)

    monkeypatch.setattr(run_mod, "refine_foreground", refine)
    monkeypatch.setattr(run_mod, "mls_warp_field", field)
    monkeypatch.setattr(run_mod, "update_background", update)
    depth = np.where(scene.person, 2.5, 4.0)
    unseen = np.zeros((H, W), bool)
    unseen[:, :5] = True
    groups = np.zeros(len(scene.src), int)
    inp = MirrorInput(6, scene.rgb, scene.person, scene.others, depth, scene.src, scene.dst, pair_groups=groups,
                      unseen=unseen, dense="the dense correspondence")
    mirror_frame(inp, scene.background, "affine", {"band_px": 4})
    mask, d, kw = seen["refine"]
    assert mask is scene.person and d is depth
    assert kw == {"background": scene.background, "unseen": unseen, "band_px": 4}
    src, dst, shape, kw = seen["field"]
    assert src is scene.src and dst is scene.dst and shape == (H, W)
    # the refined foreground too: the warp carries what of it reaches well beyond the fitted body (MIR12l)
    assert kw.pop("foreground") is seen["fg"]
    assert kw == {"kind": "affine", "alpha": MLS_ALPHA, "groups": groups, "radius_px": MLS_RADIUS_PX,
                  "dense": "the dense correspondence"}
    fg, kw = seen["update"][-1]
    assert kw == {"unverified": unseen}
    # the model learns away from the refined foreground, the SDK mask and the other players
    assert (seen["fg"] != scene.person).any()
    np.testing.assert_array_equal(fg, seen["fg"] | scene.person | scene.others)
    seen.clear()
    mirror_frame(MirrorInput(7, scene.rgb, scene.person, None, None, scene.src, scene.dst), scene.background,
                 alpha=1.0)
    assert seen["field"][3]["alpha"] == 1.0 and seen["field"][3]["kind"] == "similarity"
    assert set(seen["refine"][2]) == {"background", "unseen"}
    # a pass-through frame updates with the same unverified mask
    seen.clear()
    mirror_frame(MirrorInput(8, scene.rgb, scene.person, scene.others, warning="w", unseen=unseen), scene.background)
    assert seen["update"][0][1] == {"unverified": unseen} and "refine" not in seen


# --- run.json summary, PNGs, videos ---------------------------------------------------------------------

def test_summary_is_medians_counts_and_rates():
    rows = [{"status": s} for s in ("ok", "ok", "empty", "passed_through", "ok")]
    steps = {"read": [1.0, 3.0, 2.0], "foreground": [4.0, 6.0, 5.0], "warp": [1.0, 1.0, 4.0], "compose": [],
             "write": [9.0]}
    s = run_mod._summary(rows, steps, 2.5)
    assert s == {"frames": 5, "n_ok": 3, "n_empty": 1, "n_passed_through": 1, "n_warnings": 1, "n_subject_missing": 0,
                 "ms_per_frame": {"read": 2.0, "foreground": 5.0, "warp": 1.0, "write": 9.0},
                 "ms_per_frame_statistic": "median", "image_steps_ms": 6.0, "image_steps_fps": 1e3 / 6.0,
                 "wall_s": 2.5, "fps_wall": 2.0}
    fast = run_mod._summary([{"status": "ok"}], {"warp": [0.5]}, 0.5)
    assert fast["image_steps_fps"] == 2000.0 and fast["fps_wall"] == 2.0
    none = run_mod._summary([], {"read": [1.0]}, 0.0)
    assert none["image_steps_fps"] is None and none["fps_wall"] is None and none["image_steps_ms"] == 0.0


def test_png_frames_are_rgb_and_lossless():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (9, 11, 3), dtype=np.uint8)
    # fast PNGs (MIR12j): deflate level 1, Huffman only, the Up filter on every row (not libpng's adaptive choice)
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
              cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]
    assert run_mod._png(rgb) == cv2.imencode(".png", rgb[..., ::-1], params)[1].tobytes()
    assert run_mod._png(rgb) != cv2.imencode(".png", rgb[..., ::-1])[1].tobytes()
    back = cv2.imdecode(np.frombuffer(run_mod._png(rgb), np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(back[..., ::-1], rgb)
    gray = rng.integers(0, 256, (9, 11), dtype=np.uint8)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(run_mod.cv2, "imencode", lambda *a: (False, None))
        with pytest.raises(FileFormatError, match="^cannot encode a PNG frame$"):
            run_mod._png(gray)
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(run_mod._png(gray), np.uint8), cv2.IMREAD_UNCHANGED),
                                  gray)
    # masks: no filter, run-length deflate
    mask_params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
                   cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
    assert run_mod._png(gray) == cv2.imencode(".png", gray, mask_params)[1].tobytes()


def test_video_paths(tmp_path):
    assert run_mod.video_paths(None) == []
    out = tmp_path / "out.MP4"
    assert run_mod.video_paths(out) == [("output", out), ("side_by_side", tmp_path / "out_side_by_side.mp4")]
    assert run_mod.video_paths(str(out), side_by_side=False) == [("output", out)]
    with pytest.raises(InputError, match=r"--out .*out\.avi: the video must be an \.mp4 file"):
        run_mod.video_paths(tmp_path / "out.avi")
    (tmp_path / "x_side_by_side.mp4").mkdir()
    with pytest.raises(InputError, match="^video .*x_side_by_side.mp4: is a folder"):
        run_mod.video_paths(tmp_path / "x.mp4")
    assert run_mod.video_paths(tmp_path / "x.mp4", side_by_side=False) == [("output", tmp_path / "x.mp4")]


def _tiny_inputs(n, h=16, w=24):
    return [MirrorInput(i, np.full((h, w, 3), 10 * i, np.uint8), edit_fraction=0.5 * i,
                        timings_ms={"read": 0.12345 * (i + 1)}) for i in range(n)]


def test_stream_passes_a_failing_frame_through_and_commits_the_rest(tmp_path, monkeypatch, caplog):
    real = run_mod.mirror_frame

    def flaky(inp, background, kind, options):
        if inp.index == 1:
            raise InputError("the frame's depth is unreadable")
        return real(inp, background, kind, options)

    monkeypatch.setattr(run_mod, "mirror_frame", flaky)
    run = tmp_path / "run"
    with caplog.at_level(logging.WARNING, logger="bodystudio.mirror.run"):
        doc = mirror_stream(_tiny_inputs(3), run, None, fps=25.0, kind="rigid", manifest={"edits": {"taller": 0.1}},
                            preview=tmp_path / "live.png")
    assert [(f["index"], f["status"], f["warning"]) for f in doc["frames"]] == [
        (0, "empty", None), (1, "passed_through", "the frame's depth is unreadable"), (2, "empty", None)]
    assert [r.getMessage() for r in caplog.records if r.name == "bodystudio.mirror.run"] == [
        "frame 1 passes through: the frame's depth is unreadable"]
    assert [f["edit_fraction"] for f in doc["frames"]] == [0.0, 0.5, 1.0]
    assert doc["frames"][0]["ms"]["read"] == 0.123 and doc["frames"][2]["ms"]["read"] == 0.37
    assert doc["kind"] == "rigid" and doc["fps"] == 25.0 and doc["videos"] == {} and doc["edits"] == {"taller": 0.1}
    assert doc["format"] == "bodystudio-mirror-run" and doc["version"] == 1
    assert doc["summary"]["frames"] == 3 and doc["summary"]["n_warnings"] == 1
    for i in range(3):
        out = cv2.imread(str(run / "frames" / f"{i:05d}.png"))
        assert (out == 10 * i).all()
        for sub in ("foreground", "warped"):
            assert not cv2.imread(str(run / "masks" / sub / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE).any()
    assert (cv2.imread(str(tmp_path / "live.png")) == 20).all()  # the last frame
    with pytest.raises(InputError, match="fps must lie in 1..240, got 0.5"):
        mirror_stream(_tiny_inputs(1), tmp_path / "r2", None, fps=0.5)
    with pytest.raises(InputError, match="fps must lie in 1..240, got 241"):
        mirror_stream(_tiny_inputs(1), tmp_path / "r2", None, fps=241)
    with pytest.raises(InputError, match="--warp 'tps'; valid: "):
        mirror_stream(_tiny_inputs(1), tmp_path / "r2", None, kind="tps")
    assert not (tmp_path / "r2").exists()


def test_stream_writes_the_output_and_side_by_side_videos(tmp_path):
    import imageio_ffmpeg

    run_mod_doc = mirror_stream(_tiny_inputs(2), tmp_path / "run", tmp_path / "v.mp4", fps=12.0, side_by_side=True)
    assert run_mod_doc["videos"] == {"output": str(tmp_path / "v.mp4"),
                                     "side_by_side": str(tmp_path / "v_side_by_side.mp4")}
    for name, width in (("v.mp4", 24), ("v_side_by_side.mp4", 48)):
        reader = imageio_ffmpeg.read_frames(str(tmp_path / name))
        meta = next(reader)
        assert tuple(meta["size"]) == (width, 16) and meta["fps"] == 12.0
        assert sum(1 for _ in reader) == 2
    mirror_stream(_tiny_inputs(1), tmp_path / "run2", tmp_path / "w.mp4", side_by_side=False)
    assert (tmp_path / "w.mp4").is_file() and not (tmp_path / "w_side_by_side.mp4").exists()


# --- the session side ---------------------------------------------------------------------------------

CH, CW = 12, 16


class _Frames:
    """Stand-ins for read_mirror_frame / register_depth_to_color and the body steps (they record their calls)."""

    def __init__(self, spec):
        self.spec = spec  # index -> dict(kind=..., ...)
        self.ik_calls, self.bodies = [], []
        self.untwisted_with = set()  # the bone lists the run untwists the IK's poses at

    def read(self, session, i):
        s = self.spec[i]
        if s.get("unreadable"):
            raise FileFormatError(f"frame {i}: broken PNG")
        # the frame index in the first joint only: the body stands still (the run follows it by its joints)
        positions = np.zeros((25, 3))
        positions[0, 0] = float(i)
        body = None if s.get("untracked") else SimpleNamespace(player=1, names=tuple(f"j{k}" for k in range(25)),
                                                               positions=positions, tracked=np.ones(25, bool))
        player = np.zeros((CH, CW), np.uint8)
        player[s.get("person", slice(2, 6)), 4:8] = 1
        player[8:10, 12:14] = 2
        depth = np.zeros((CH, CW)) if s.get("no_depth") else np.ones((CH, CW))
        seen = s.get("seen", (slice(None), slice(0, CW)))
        return SimpleNamespace(rgb=np.full((CH, CW, 3), i, np.uint8), depth_m=depth, player=player, seen=seen,
                               body=lambda p: body if p == 1 else None, bodies=() if body is None else (body,))

    def ik(self, skeleton, positions, tracked, version, previous=None):
        assert skeleton == "sk" and version == "v2" and tracked is not None and tracked.dtype == bool
        self.ik_calls.append((positions[0, 0], previous))
        if positions[0, 0] in self.spec_fail:
            raise InputError("pelvis not tracked")
        return f"pose{int(positions[0, 0])}"


class _ColourOnly:
    """The session's frame ``i`` as the run reads its colour alone after the whole frame failed to read: readable only
    where the spec says ``colour_ok`` (a damaged depth / mask / joints file beside a good colour image)."""

    def __init__(self, i, spec):
        self.i, self.spec = i, spec

    @property
    def kinect_rgb(self):
        if not self.spec.get("colour_ok"):
            raise FileFormatError(f"frame {self.i}: broken colour PNG")
        return np.full((CH, CW, 3), 40 + self.i, np.uint8)


def _session_inputs(monkeypatch, spec, ramp_frames=3, fail=(), frames=None, player=1):
    from bodystudio.mirror import frames as frames_mod
    from bodystudio.mirror import reshape as reshape_mod
    from bodystudio.mirror import track as track_mod

    f = _Frames(spec)
    f.spec_fail = set(fail)
    current = {}
    camera = SimpleNamespace(height=CH, width=CW)

    def read(sess, i):
        assert sess is session
        fr = f.read(sess, i)
        current["seen"] = fr.seen
        return fr

    def register(depth, player, sensor):
        assert sensor is session.kinect
        d = np.zeros((CH, CW))
        if depth.any():
            d[current["seen"]] = 0.8
        return d, player

    def pairs(Vs, Vt, faces, cam, n, rim_cos=None, dense=False, closed=False):
        assert n == run_mod.N_HANDLES and rim_cos == run_mod.RIM_COS and cam is camera and faces is body.faces
        assert closed  # the model's bodies: front faces only
        return SimpleNamespace(src_uv=np.zeros((20, 2)) + Vs[0, 0], dst_uv=np.zeros((20, 2)) + Vt[0, 0],
                               dense="dense" if dense else None)

    def rig(b, target_rest, m, coeffs):
        assert b is body and m is model
        return ("rig", float(coeffs[0]))

    def posed(b, target_rest, pose, target_rig=None):
        assert b is body and target_rig == ("rig", pytest.approx((target_rest[0, 0] - 1.0) / 9.0))
        f.bodies.append((target_rest[0, 0], pose))
        return b.vertices, target_rest

    monkeypatch.setattr(frames_mod, "read_mirror_frame", read)
    monkeypatch.setattr(frames_mod, "register_depth_to_color", register)
    monkeypatch.setattr(track_mod, "ik_pose", f.ik)

    def untwisted(skeleton, pose, bones):  # MIR12p: the IK's limbs untwisted on the body's skeleton, marked "u"
        assert skeleton == "sk"
        f.untwisted_with.add(tuple(bones))
        return "u" + pose

    monkeypatch.setattr(track_mod, "untwisted_pose", untwisted)

    def upright(skeleton, pose):  # MIR12s: the bodies' pose with the root's tilt moved into the pelvis, marked "r"
        assert skeleton == "sk"
        return "r" + pose

    monkeypatch.setattr(track_mod, "upright_root", upright)

    def target(m, coeffs, edits):
        assert m is model
        return coeffs + edits["taller"]

    monkeypatch.setattr(reshape_mod, "target_coeffs", target)
    monkeypatch.setattr(reshape_mod, "posed_source_and_target", posed)
    monkeypatch.setattr(reshape_mod, "target_skeleton", rig)
    monkeypatch.setattr(run_mod, "warp_pairs", pairs)
    session = SimpleNamespace(path="S", frame_ids=sorted(spec), kinect=SimpleNamespace(color=camera, version="v2"),
                              frame=lambda i: _ColourOnly(i, spec[i]))
    body = SimpleNamespace(coeffs=np.zeros(1), vertices=np.full((3, 3), 1.0), skeleton="sk", faces="faces")
    model = SimpleNamespace(vertices=lambda c: np.full((3, 3), 1.0 + 9.0 * c[0]))
    if ramp_frames is None:  # the defaults: player 1, 30 ramp frames
        out = list(run_mod.session_inputs(session, body, model, {"taller": 1.0}))
    else:
        out = list(run_mod.session_inputs(session, body, model, {"taller": 1.0}, player, ramp_frames, frames))
    return out, f


def test_session_inputs_warn_per_frame_and_ramp_the_edit(monkeypatch):
    spec = {0: {"untracked": True, "person": slice(0, 0)},  # nobody: no warning (an empty frame)
            1: {"untracked": True},  # in the mask, not tracked
            2: {"no_depth": True},
            3: {"person": slice(0, 0)},  # tracked, empty mask
            4: {}, 5: {}, 6: {}, 7: {}, 8: {}}
    out, f = _session_inputs(monkeypatch, spec, ramp_frames=3, fail=(6,))
    assert [o.index for o in out] == list(range(9))
    assert out[0].warning is None and out[0].src_uv is None
    assert out[1].warning == "player 1 is in the mask but no body is tracked"
    assert out[2].warning == "depth missing (no depth measurement in the frame)"
    assert out[3].warning == "body 1 is tracked but its player mask is empty"
    assert out[6].warning == "tracking failed: pelvis not tracked"
    ok = [o for o in out if o.warning is None and o.src_uv is not None]
    assert [o.index for o in ok] == [4, 5, 7, 8]
    # the edit is reached over ramp_frames tracked frames: V_S + s (V_T - V_S), V_T = 10 here
    assert [o.edit_fraction for o in ok] == pytest.approx([1 / 3, 2 / 3, 1.0, 1.0])
    assert [t for t, _ in f.bodies] == pytest.approx([4.0, 7.0, 10.0, 10.0])
    # the untwisted poses, with an upright root for the bodies (MIR12s)
    assert [p for _, p in f.bodies] == ["rupose4", "rupose5", "rupose7", "rupose8"]
    assert ok[0].dst_uv[0, 0] == pytest.approx(4.0) and ok[0].src_uv[0, 0] == 1.0
    np.testing.assert_array_equal(ok[0].depth_color, np.full((CH, CW), 0.8))
    assert all(o.dense == "dense" for o in ok)  # the default correspondence is the dense one, passed on
    # the IK is warm-started from the last successful pose, untwisted at the run's limbs (MIR12p)
    assert f.ik_calls == [(4.0, None), (5.0, "upose4"), (6.0, "upose5"), (7.0, "upose5"), (8.0, "upose7")]
    assert f.untwisted_with == {run_mod.UNTWIST_BONES + ("foot_l", "foot_r")}  # and the feet (mir12aa)
    # masks: the person, the other players
    assert out[4].person_mask.sum() == 16 and out[4].others_mask.sum() == 4
    assert not (out[4].person_mask & out[4].others_mask).any()
    assert out[4].rgb[0, 0, 0] == 4 and set(out[4].timings_ms) == {"read", "register", "ik", "bodies", "pairs"}


def test_session_inputs_untwist_the_feet_unless_told_not_to(monkeypatch):
    """mir12aa: ``run.UNTWIST_FEET`` (on by default) adds the feet to the limbs each IK pose is untwisted at."""
    from bodystudio.mirror import track as track_mod

    assert run_mod.UNTWIST_FEET is True
    _, f = _session_inputs(monkeypatch, {0: {}, 1: {}}, ramp_frames=1)
    assert f.untwisted_with == {run_mod.UNTWIST_BONES + track_mod.UNTWIST_FEET_BONES}
    assert f.ik_calls == [(0.0, None), (1.0, "upose0")]
    monkeypatch.setattr(run_mod, "UNTWIST_BONES", ())  # the feet alone
    _, f = _session_inputs(monkeypatch, {0: {}}, ramp_frames=1)
    assert f.untwisted_with == {("foot_l", "foot_r")}
    monkeypatch.setattr(run_mod, "UNTWIST_FEET", False)  # neither: the IK's pose as it is
    _, f = _session_inputs(monkeypatch, {0: {}, 1: {}}, ramp_frames=1)
    assert f.untwisted_with == set() and f.ik_calls == [(0.0, None), (1.0, "pose0")]


def test_session_inputs_ramp_zero_and_unreadable_frames(monkeypatch):
    spec = {0: {"unreadable": True}, 1: {}, 2: {"unreadable": True}, 3: {}}
    out, _ = _session_inputs(monkeypatch, spec, ramp_frames=0)
    assert [o.index for o in out] == [0, 1, 2, 3]
    assert out[0].warning == "frame unreadable: frame 0: broken PNG"
    assert out[0].rgb.shape == (CH, CW, 3) and out[0].rgb.dtype == np.uint8 and not out[0].rgb.any()
    assert out[2].warning.startswith("frame unreadable") and (out[2].rgb == 1).all()  # the last good frame
    # rel6a: a frame whose depth (mask, joints) is damaged shows its own colour, not the last frame's (frozen)
    own, _ = _session_inputs(monkeypatch, {0: {}, 1: {"unreadable": True, "colour_ok": True}}, ramp_frames=0)
    assert own[1].warning == "frame unreadable: frame 1: broken PNG" and (own[1].rgb == 41).all()
    assert [o.edit_fraction for o in out if o.src_uv is not None] == [1.0, 1.0]
    # only the given frames
    out, _ = _session_inputs(monkeypatch, spec, frames=[3, 1])
    assert [o.index for o in out] == [3, 1] and out[0].edit_fraction == pytest.approx(1 / 3)
    out, _ = _session_inputs(monkeypatch, spec, ramp_frames=None)
    assert [o.edit_fraction for o in out if o.src_uv is not None] == pytest.approx([1 / 30, 2 / 30])


def test_pixels_the_depth_camera_never_saw_are_marked_unseen(monkeypatch):
    block = (slice(4, 8), slice(6, 10))
    spec = {0: {"seen": block}, 1: {"seen": (slice(None), slice(14, CW))}, 2: {"seen": (slice(0, 0), slice(0, 0))}}
    out, _ = _session_inputs(monkeypatch, spec)
    # what frame 0 saw, grown by 2 px on every side (a 5x5 dilation) is not unseen
    expect = np.ones((CH, CW), bool)
    expect[2:10, 4:12] = False
    np.testing.assert_array_equal(out[0].unseen, expect)
    expect[:, 12:] = False
    np.testing.assert_array_equal(out[1].unseen, expect)  # what was seen stays seen
    np.testing.assert_array_equal(out[2].unseen, expect)


def _stand_in_clock(start: int = 100):
    """``run_mod.time`` with a wall clock of 1 s and a CPU clock of 2 s a reading (each its own counter): a step timed
    on both is 1000 ms wall and 2000 ms CPU."""
    wall, cpu = iter(range(start, 100000)), iter(range(start, 100000))
    return SimpleNamespace(perf_counter=lambda: float(next(wall)), process_time=lambda: 2.0 * next(cpu))


def test_session_inputs_for_another_player_and_their_timings(monkeypatch):
    # player 2 (the 2x2 block; not tracked in the stand-in frames): player 1's pixels are the others
    out, _ = _session_inputs(monkeypatch, {0: {}}, player=2)
    assert out[0].person_mask.sum() == 4 and out[0].others_mask.sum() == 16
    assert out[0].warning == "player 2 is in the mask but no body is tracked"
    monkeypatch.setattr(run_mod, "time", _stand_in_clock())
    out, _ = _session_inputs(monkeypatch, {0: {}, 1: {}})
    assert out[0].timings_ms == {"read": 1000.0, "register": 1000.0, "ik": 1000.0, "bodies": 1000.0,
                                 "pairs": 1000.0}
    assert out[0].cpu_ms == {k: 2000.0 for k in out[0].timings_ms}  # CPU ms booked step by step beside them


def test_session_inputs_need_a_kinect(monkeypatch):
    with pytest.raises(InputError, match="^S: not a Kinect session \\(no kinect/calibration.json\\); the mirror needs "
                       "Kinect colour, depth, player mask and joints$"):
        list(run_mod.session_inputs(SimpleNamespace(path="S", kinect=None), None, None, {}))


def test_check_edits_and_missing_stage_modules(monkeypatch):
    assert run_mod.check_edits({"taller": 0.1}) == {"taller": 0.1}
    with pytest.raises(InputError, match=r"edit taller=0.5 is out of range"):  # the reshape step's ranges
        run_mod.check_edits({"taller": 0.5})
    with pytest.raises(InputError, match="edit heavier is not a finite number; give a value such as --heavier 0.05"):
        run_mod.check_edits({"taller": 0.1, "heavier": float("inf")})
    with pytest.raises(InputError, match="unknown edit\\(s\\) bigger, wider; valid: taller, heavier"):
        run_mod.check_edits({"wider": 1.0, "bigger": 2.0})
    with pytest.raises(InputError, match="^this bodystudio has no mirror nosuch step \\(bodystudio.mirror.nosuch\\); "
                       "install the complete mirror stage$"):
        run_mod._stage_module("nosuch")
    import bodystudio.mirror.reshape as reshape

    monkeypatch.delattr(reshape, "check_edits")
    assert run_mod.check_edits({"taller": 1}) == {"taller": 1.0}


def _wired(monkeypatch, got):
    """run_mirror with its steps replaced by recorders."""
    def load(session, source, player=1):
        got["load"] = (session, source) if player == 1 else (session, source, player)
        return "body", "model"

    def inputs(*args):
        got["inputs"] = args
        return "INPUTS"

    monkeypatch.setattr(run_mod, "load_source", load)
    monkeypatch.setattr(run_mod, "session_inputs", inputs)

    def stream(inputs, run_dir, out_video, fps, side_by_side, kind, manifest, progress, total, preview=None,
               video_preset="veryfast"):
        got["stream"] = dict(inputs=inputs, run_dir=run_dir, out_video=out_video, fps=fps, sbs=side_by_side, kind=kind,
                             manifest=manifest, progress=progress, total=total, preview=preview)
        if video_preset != "veryfast":
            got["stream"]["video_preset"] = video_preset
        return "DOC"

    monkeypatch.setattr(run_mod, "mirror_stream", stream)


def _fake_session(tmp_path, **changes):
    (tmp_path / "mirror").mkdir(exist_ok=True)
    for name in ("source_body.npz", "source_body_player2.npz", "source_body_player6.npz"):
        (tmp_path / "mirror" / name).write_bytes(b"x")
    fields = dict(path=tmp_path, kinect="kinect", metadata={"fps": 15}, manifest={"run": {"run_id": "r1"}},
                  frame_ids=[0, 1, 2], files={})
    fields.update(changes)
    return SimpleNamespace(**fields)


def test_run_mirror_checks_options_then_wires_the_steps(tmp_path, monkeypatch):
    from bodystudio.mirror.run import run_mirror

    session = _fake_session(tmp_path)
    for kw, phrase in (({"player": 0}, "--player 0: a Kinect player id is 1..6"),
                       ({"player": 7}, "--player 7"),
                       ({"ramp_frames": -1}, "--ramp-frames -1: use 0..10000"),
                       ({"ramp_frames": 10001}, "--ramp-frames 10001"),
                       ({"kind": "tps"}, "--warp 'tps'; valid: affine, similarity, rigid$")):
        with pytest.raises(InputError, match=phrase):
            run_mirror(session, {"taller": 0.1}, None, **kw)
    with pytest.raises(InputError, match="must be an .mp4"):
        run_mirror(session, {"taller": 0.1}, tmp_path / "o.avi")
    with pytest.raises(InputError, match=f"{tmp_path}: not a Kinect session \\(no kinect/calibration.json\\); the "
                       "mirror needs Kinect colour, depth, player mask and joints$"):
        run_mirror(_fake_session(tmp_path, kinect=None), {}, None)
    with pytest.raises(FileFormatError, match="nope.npz: source body not found"):
        run_mirror(session, {}, None, source=tmp_path / "nope.npz")
    for fps in ("fast", 0.5, 0.99, 240.5, 500):
        with pytest.raises(InputError, match=f"session metadata fps {fps!r} is not a frame rate in 1..240"):
            run_mirror(_fake_session(tmp_path, metadata={"fps": fps}), {}, None)
    with pytest.raises(InputError, match="unknown edit"):
        run_mirror(session, {"wider": 1.0}, None)
    # a side-by-side video that cannot be written is refused before any work, unless not asked for
    (tmp_path / "v_side_by_side.mp4").mkdir()
    with pytest.raises(InputError):
        run_mirror(session, {}, tmp_path / "v.mp4")
    got = {}
    _wired(monkeypatch, got)
    assert run_mirror(session, {}, tmp_path / "v.mp4", side_by_side=False) == "DOC"
    assert got["stream"]["out_video"] == tmp_path / "v.mp4" and got["stream"]["sbs"] is False
    got.clear()
    assert run_mirror(session, {"taller": 0.1}, None, progress=False, player=2, kind="rigid", ramp_frames=5,
                      frames=[2, 0], side_by_side=False) == "DOC"
    assert got["inputs"] == (session, "body", "model", {"taller": 0.1}, 2, 5, [2, 0], run_mod.CORRESPONDENCE,
                             True)
    assert got["load"] == (session, None, 2)  # player 2's own file (source_body_player2.npz)
    s = got["stream"]
    assert s["inputs"] == "INPUTS" and s["run_dir"] == tmp_path / "mirror" / "run" and s["fps"] == 15.0
    assert s["kind"] == "rigid" and s["total"] == 2 and s["preview"] is None and s["progress"] is False
    assert s["sbs"] is False
    assert s["manifest"] == {"session": str(tmp_path.resolve()), "session_run_id": "r1",
                             "session_fingerprint": None, "live": None,
                             "edits": {"taller": 0.1}, "player": 2, "ramp_frames": 5,
                             "correspondence": run_mod.CORRESPONDENCE, "refine_pose": True, "video_preset": "veryfast",
                             "source_fingerprint": None}
    # the defaults, and the limits of each range accepted
    got.clear()
    run_mirror(_fake_session(tmp_path, metadata=None, manifest={}), {}, None, run_dir=tmp_path / "r", player=6,
               ramp_frames=10000)
    s = got["stream"]
    assert s["fps"] == 30.0 and s["total"] == 3 and s["run_dir"] == tmp_path / "r"
    assert s["sbs"] is True and s["progress"] is True and s["kind"] == "similarity"
    assert s["manifest"]["session_run_id"] is None and got["inputs"][4:7] == (6, 10000, [0, 1, 2])
    for fps in (1.0, 240.0):
        run_mirror(_fake_session(tmp_path, metadata={"fps": fps}), {}, None, ramp_frames=0, player=1)
        assert got["stream"]["fps"] == fps
    run_mirror(session, {}, None)
    assert got["inputs"][4:6] == (1, 30)  # player 1, a 30-frame ramp by default
    assert got["inputs"][8] is True  # --refine-pose is on by default (MIRFAST)
    run_mirror(session, {}, None, refine_pose=False)
    assert got["inputs"][8] is False and got["stream"]["manifest"]["refine_pose"] is False
    with pytest.raises(InputError, match="^--correspondence 'tps'; valid: dense, mls$"):
        run_mirror(session, {}, None, correspondence="tps")
    # the x264 preset of the videos (MIR12j): checked before anything runs, passed to the stream, kept in run.json
    with pytest.raises(InputError, match="^--video-preset 'quick'; valid: ultrafast, superfast, veryfast, faster, "):
        run_mirror(session, {}, None, video_preset="quick")
    run_mirror(session, {}, None, video_preset="ultrafast")
    assert got["stream"]["video_preset"] == "ultrafast" and got["stream"]["manifest"]["video_preset"] == "ultrafast"
    # a source body given as an object is not looked for on disk
    (tmp_path / "mirror" / "source_body.npz").unlink()
    with pytest.raises(FileFormatError, match="source_body.npz: source body not found; run 'bodystudio mirror init "
                       f"{tmp_path}' first \\(or give --source\\)"):
        run_mirror(session, {}, None)
    src = object()
    run_mirror(session, {}, None, source=src)
    assert got["load"][1] is src


def test_run_mirror_opens_a_session_path(tmp_path, monkeypatch):
    import bodystudio.capture.session as session_mod
    from bodystudio.mirror.run import run_mirror

    session = _fake_session(tmp_path)
    opened = []
    monkeypatch.setattr(session_mod, "open_session", lambda p: opened.append(p) or session)
    got = {}
    _wired(monkeypatch, got)
    run_mirror(str(tmp_path), {}, None)
    assert opened == [str(tmp_path)] and got["inputs"][0] is session and got["load"][0] is session


def test_run_mirror_live_reads_the_live_folder(tmp_path, monkeypatch):
    from bodystudio.mirror.run import run_mirror

    session = _fake_session(tmp_path)
    live = tmp_path / "live"
    live_session = SimpleNamespace(kinect="live kinect", path=live)
    calls = {}
    monkeypatch.setattr(run_mod, "live_session", lambda folder: calls.setdefault("session", folder) and live_session)
    monkeypatch.setattr(run_mod, "live_frame_ids", lambda folder, timeout: calls.setdefault("ids", (folder, timeout))
                        and "IDS")
    got = {}
    _wired(monkeypatch, got)
    run_mirror(session, {}, None, live=live, frames=[1])
    assert calls == {"session": live, "ids": (live, 5.0)}
    assert got["inputs"][0] is live_session and got["inputs"][6] == "IDS"
    s = got["stream"]
    assert s["total"] is None and s["preview"] == tmp_path / "mirror" / "run" / "live_latest.png"
    assert s["manifest"]["live"] == str(live.resolve())
    calls.clear()
    run_mirror(session, {}, None, live=str(live), live_timeout_s=0.5, run_dir=tmp_path / "r")
    assert calls["ids"] == (str(live), 0.5) and got["stream"]["preview"] == tmp_path / "r" / "live_latest.png"
    monkeypatch.setattr(run_mod, "live_session", lambda folder: SimpleNamespace(kinect=None, path=live))
    with pytest.raises(InputError, match="not a Kinect session"):
        run_mirror(session, {}, None, live=live)


def test_load_source_finds_the_model_by_size(tmp_path, monkeypatch):
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror.init import SourceBody, refit_skeleton, save_source_body

    model = load_statistical_model("2k", progress=False)
    c = np.zeros(model.n_components)
    src = SourceBody(c, model.vertices(c), refit_skeleton(model, c), (4, 5), 1.5)
    session = SimpleNamespace(path=tmp_path)
    body, m = run_mod.load_source(session, src)
    assert len(m.mean) == len(model.mean) and body.weights is not None and body.faces is not None
    assert body.skeleton is src.skeleton and body.frames_used == (4, 5) and body.residual_mm == 1.5
    (tmp_path / "mirror").mkdir()
    save_source_body(tmp_path / "mirror" / "source_body.npz", src)
    body2, _ = run_mod.load_source(session)
    np.testing.assert_array_equal(body2.vertices, src.vertices)
    save_source_body(tmp_path / "other.npz", src)
    body3, _ = run_mod.load_source(session, str(tmp_path / "other.npz"))
    np.testing.assert_array_equal(body3.coeffs, c)
    for missing in (tmp_path / "missing.npz", str(tmp_path / "missing.npz")):
        with pytest.raises(FileFormatError, match=f"missing.npz: source body not found; run 'bodystudio mirror init "
                           f"{tmp_path}' first \\(or give --source\\)$"):
            run_mod.load_source(session, missing)
    import bodystudio.body.statistical as statistical

    asked = []
    real = statistical.load_statistical_model
    monkeypatch.setattr(statistical, "load_statistical_model", lambda r, **kw: asked.append((r, kw)) or real(r, **kw))
    run_mod.load_source(session, src)
    assert asked == [("6k", {"progress": False}), ("2k", {"progress": False})]
    odd = SourceBody(c, model.vertices(c)[:-1], src.skeleton, (0,), 1.0)
    with pytest.raises(InputError, match="source body of 2501 vertices matches no statistical model \\(6k, 2k\\); "
                       "rerun 'bodystudio mirror init'$"):
        run_mod.load_source(session, odd)


# --- live mode ------------------------------------------------------------------------------------------

def _touch(root, rel, age_s=0.0):
    p = root / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(b"x")
    if age_s:
        t = time.time() - age_s
        os.utime(p, (t, t))


def test_live_session_files_and_frames(tmp_path):
    from bodystudio.capture.session import KINECT_CALIBRATION, stream_path

    with pytest.raises(InputError, match="^--live 0: reading a camera device needs a Kinect SDK bridge, which "
                       "bodystudio does not have; let the recorder write frames into a folder and pass that folder$"):
        run_mod.live_session("0")
    with pytest.raises(InputError, match="--live /dev/video0: reading a camera device"):
        run_mod.live_session("/dev/video0")
    with pytest.raises(InputError, match="no such folder"):
        run_mod.live_session(tmp_path / "none")
    with pytest.raises(InputError, match=f"no {KINECT_CALIBRATION}; the recorder must write the sensor calibration "
                       "first \\(the session layout's kinect/ folder\\)$"):
        run_mod.live_session(tmp_path)
    _touch(tmp_path, KINECT_CALIBRATION)
    for i in (3, 11, 2):
        _touch(tmp_path, stream_path("kinect_rgb", i))
    _touch(tmp_path, "kinect/rgb/notes.png")
    s = run_mod.live_session(tmp_path)
    files = s.manifest["files"]
    assert KINECT_CALIBRATION in files and stream_path("kinect_rgb", 3) in files and "nope" not in files
    assert 5 not in files and files[KINECT_CALIBRATION] is None
    with pytest.raises(KeyError, match="kinect/none.json"):
        files["kinect/none.json"]
    assert len(files) == 5 and sorted(files) == list(files)
    frames = s.manifest["frames"]
    assert list(frames) == [2, 3, 11] and 3 in frames and 4 not in frames
    assert s.manifest["cameras"] == [] and s.manifest["metadata"] == {} and s.manifest["streams"] == []
    assert s.path == tmp_path


def test_live_frame_ids_wait_for_joints_or_the_next_frame_or_settling(tmp_path):
    from bodystudio.capture.session import stream_path

    def frame(i, joints=True, age_s=0.0):
        for stream in ("kinect_rgb", "kinect_depth", "kinect_player") + (("kinect_joints",) if joints else ()):
            _touch(tmp_path, stream_path(stream, i), age_s)

    assert list(run_mod.live_frame_ids(tmp_path, timeout_s=0.05, poll_s=0.01)) == []
    frame(4)
    frame(5, joints=False)  # complete but no joints, fresh: waits for settling or frame 6
    assert list(run_mod.live_frame_ids(tmp_path, timeout_s=0.1, poll_s=0.01, settle_s=60)) == [4]
    assert list(run_mod.live_frame_ids(tmp_path, timeout_s=0.1, poll_s=0.01, settle_s=0.0)) == [4, 5]
    _touch(tmp_path, stream_path("kinect_rgb", 6))  # frame 6 started: 5 is done
    assert list(run_mod.live_frame_ids(tmp_path, timeout_s=0.1, poll_s=0.01, settle_s=60)) == [4, 5]
    frame(6, joints=False, age_s=10)  # old enough: settled
    assert list(run_mod.live_frame_ids(tmp_path, timeout_s=0.1, poll_s=0.01, settle_s=5)) == [4, 5, 6]


def test_live_frame_ids_with_a_stand_in_clock(tmp_path, monkeypatch):
    """The recorder writes frames while the reader sleeps: frame 0 appears during the first poll, frame 1
    (without joints) later and settles 0.3 s after its colour image; then 5 s without a new frame end it."""
    from bodystudio.capture.session import stream_path

    base = time.time() - 100.0
    clock = {"t": 0.0, "sleeps": 0}
    writes = {}

    def write(i, joints, streams=("kinect_rgb", "kinect_depth", "kinect_player")):
        for stream in streams + (("kinect_joints",) if joints else ()):
            _touch(tmp_path, stream_path(stream, i))
            p = tmp_path / stream_path(stream, i)
            os.utime(p, (base + clock["t"], base + clock["t"]))

    def sleep(s):
        clock["t"] += s
        clock["sleeps"] += 1
        for at, action in list(writes.items()):
            if clock["t"] >= at:
                action()
                del writes[at]

    fake = SimpleNamespace(time=lambda: base + clock["t"], monotonic=lambda: 1000.0 + clock["t"], sleep=sleep)
    monkeypatch.setattr(run_mod, "time", fake)
    # nothing arrives: 5 s of 20 ms polls
    assert list(run_mod.live_frame_ids(tmp_path)) == []
    assert 249 <= clock["sleeps"] <= 251
    clock.update(t=0.0, sleeps=0)
    writes[0.0] = lambda: write(0, joints=True)
    writes[1.0] = lambda: write(1, joints=False)
    ids = run_mod.live_frame_ids(tmp_path)
    assert next(ids) == 0 and clock["t"] < 0.05  # with its joints: taken at once
    assert next(ids) == 1 and 1.3 <= clock["t"] <= 1.35  # settled 0.3 s after it was written
    assert list(ids) == [] and 6.3 <= clock["t"] <= 6.4
    # a frame with joints is taken at once; one whose colour image is old but depth fresh has settled
    write(2, joints=True)
    write(3, joints=False, streams=("kinect_rgb",))
    clock["t"] += 10.0
    write(3, joints=False, streams=("kinect_depth", "kinect_player"))
    t0 = clock["t"]
    ids = run_mod.live_frame_ids(tmp_path, settle_s=5.0)
    assert next(ids) == 0 and next(ids) == 1 and next(ids) == 2 and next(ids) == 3 and clock["t"] == t0


def test_stream_run_block_lock_progress_and_background_carried(tmp_path, monkeypatch):
    """run.json's run block (command, producer), the lock and staging beside run.json while frames are written,
    the progress bar's task, and one background model carried from frame to frame with the kind and the
    foreground options."""
    import bodystudio.capture.session as session_mod
    from bodystudio.runfolder import OutputLockedError, RunLayout, RunWriter

    run = tmp_path / "run"
    seen = []
    real = run_mod.mirror_frame

    def frame(inp, background, kind, options):
        seen.append(dict(background=background, kind=kind, options=options, lock=(run / ".lock").exists(),
                         staging=(run / ".staging").is_dir()))
        return real(inp, background, kind, options)

    bars = []

    class Bar:
        def __init__(self, enabled):
            self.enabled, self.tasks, self.advanced = enabled, [], 0
            bars.append(self)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def add_task(self, name, total=None):
            self.tasks.append((name, total))
            return "task"

        def advance(self, task):
            assert task == "task"
            self.advanced += 1

    monkeypatch.setattr(run_mod, "mirror_frame", frame)
    monkeypatch.setattr(session_mod, "progress_bar", Bar)
    first = update_background(None, np.full((16, 24, 3), 5, np.uint8), np.zeros((16, 24), bool))
    doc = mirror_stream(_tiny_inputs(3), run, None, kind="affine", foreground_options={"band_px": 3}, progress=True,
                        total=3, background=first)
    assert doc["run"]["command"] == "bodystudio mirror run"
    assert doc["run"]["producer"] == {"stage": "mirror", "kind": "affine"}
    assert all(s["lock"] and s["staging"] for s in seen)
    assert not (run / ".lock").exists() and not (run / ".staging").exists()
    assert [(s["kind"], s["options"]) for s in seen] == [("affine", {"band_px": 3})] * 3
    assert seen[0]["background"] is first and seen[1]["background"].frames == first.frames + 1
    assert seen[2]["background"].frames == first.frames + 2
    assert bars[0].enabled is True and bars[0].tasks == [("mirror", 3)] and bars[0].advanced == 3
    doc = mirror_stream(_tiny_inputs(1), run, None, command="bodystudio mirror run --live")
    assert doc["run"]["command"] == "bodystudio mirror run --live" and doc["fps"] == 30.0
    assert bars[1].enabled is False and bars[1].tasks == [("mirror", None)]
    assert seen[-1]["kind"] == "similarity" and seen[-1]["options"] is None and seen[-1]["background"] is None
    # a second writer is refused, naming the run folder to recover
    with RunWriter(RunLayout(run, "run.json", ".", "elsewhere"), "other"), \
            pytest.raises(OutputLockedError, match=f"run `bodystudio recover {run}`$"):
        mirror_stream(_tiny_inputs(1), run, None)


def test_stream_limits_defaults_and_failed_frame_masks(tmp_path, monkeypatch):
    for fps in (1.0, 240.0):
        assert mirror_stream(_tiny_inputs(1), tmp_path / f"r{fps}", None, fps=fps)["fps"] == fps
    with pytest.raises(InputError, match="^--warp 'tps'; valid: affine, similarity, rigid$"):
        mirror_stream(_tiny_inputs(1), tmp_path / "r", None, kind="tps")
    doc = mirror_stream(_tiny_inputs(1), tmp_path / "v", tmp_path / "v.mp4")
    assert set(doc["videos"]) == {"output", "side_by_side"} and (tmp_path / "v_side_by_side.mp4").is_file()

    def broken(inp, background, kind, options):
        raise InputError("bad frame")

    monkeypatch.setattr(run_mod, "mirror_frame", broken)
    run = tmp_path / "b"
    mirror_stream(_tiny_inputs(1), run, None)
    for sub in ("foreground", "warped"):
        mask = cv2.imread(str(run / "masks" / sub / "00000.png"), cv2.IMREAD_UNCHANGED)
        assert mask.shape == (16, 24) and mask.dtype == np.uint8 and not mask.any()


def test_step_timings_are_milliseconds_of_each_step(scene, monkeypatch):
    """With a stand-in clock that ticks one second per reading, every timed step takes 1000 ms."""
    monkeypatch.setattr(run_mod, "time", _stand_in_clock())
    res, _ = mirror_frame(MirrorInput(1, scene.rgb, scene.person, None, None, scene.src, scene.dst,
                                      timings_ms={"read": 2.5}, cpu_ms={"read": 1.5}), scene.background)
    assert res.timings_ms == {"read": 2.5, **{s: 1000.0 for s in IMAGE_STEPS}}
    assert res.cpu_ms == {"read": 1.5, **{s: 2000.0 for s in IMAGE_STEPS}}
    res, _ = mirror_frame(MirrorInput(2, scene.rgb, scene.person, warning="w"), scene.background)
    assert res.timings_ms == {"background": 1000.0} and res.cpu_ms == {"background": 2000.0}


def test_stream_writes_the_masks_and_times_each_write(scene, tmp_path, monkeypatch):
    """An ok frame's refined and warped masks as 0/255 PNGs; with a stand-in clock the write step, the
    summary's step medians and the wall time come out exactly."""
    inp = MirrorInput(0, scene.rgb, scene.person, None, None, scene.src, scene.dst)
    run = tmp_path / "run"
    monkeypatch.setattr(run_mod, "time", _stand_in_clock())
    doc = mirror_stream([inp], run, None, background=scene.background)
    fg = cv2.imread(str(run / "masks" / "foreground" / "00000.png"), cv2.IMREAD_UNCHANGED)
    warped = cv2.imread(str(run / "masks" / "warped" / "00000.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(fg, scene.person.astype(np.uint8) * 255)
    np.testing.assert_array_equal(warped, np.roll(scene.person, SHIFT, axis=1).astype(np.uint8) * 255)
    assert doc["frames"][0]["ms"]["write"] == 1000.0
    assert doc["summary"]["ms_per_frame"]["write"] == 1000.0 and doc["summary"]["ms_per_frame"]["warp"] == 1000.0
    # start, 6 image-step readings, 2 write readings, end: 9 s
    assert doc["summary"]["wall_s"] == 9.0
    # the same readings on the CPU clock (2 s each); no video: no encoder CPU, end to end is the steps' sum
    s = doc["summary"]
    assert doc["frames"][0]["cpu_ms"]["write"] == 2000.0 and s["cpu_ms_per_frame"]["warp"] == 2000.0
    assert s["cpu_s"] == 18.0 and s["encoder_cpu_ms_per_frame"] is None
    assert s["end_to_end_cpu"] == {"ms": 12000.0, "fps": 1e3 / 12000.0, "ms_without_io": 10000.0,
                                   "fps_without_io": 0.1}
    assert s["end_to_end_wall"]["ms"] == 6000.0 and s["end_to_end_wall"]["ms_without_io"] == 5000.0
    with pytest.raises(InputError, match=f"^{tmp_path / 'none'}: no frames to process; check the session's frames "
                       "or --frames$"):
        mirror_stream([], tmp_path / "none", None)
