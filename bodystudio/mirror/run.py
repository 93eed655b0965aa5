"""The mirror loop (§5 of Real-time Reshaping of Humans): per frame IK, bodies, foreground, warp, composition.

:func:`run_mirror` reads a mirror session (or, live, a folder that a recorder is filling), and per frame:
poses the source body by IK against the Kinect joints (§5.2) and the target body with the same pose
(Eq. 4, reached gradually), projects a sparse set of visible vertex pairs, refines the player mask by a
graph cut (§5.3), warps the foreground by MLS (Eq. 5) and composes it over the background model (§5.5).
A frame that cannot be processed (no body tracked, joints or depth missing, an unreadable file) passes
through unchanged, with a warning counted in ``run.json``; a run never stops for one bad frame.

Outputs, committed as one unit through :mod:`bodystudio.runfolder` (``RUN/run.json`` written last):
``RUN/frames/00000.png`` (output frames), ``RUN/masks/foreground/00000.png`` (refined input foreground),
``RUN/masks/warped/00000.png`` (warped foreground, the mirror's person), the video (``out_video``, H.264
through imageio-ffmpeg) and, with ``side_by_side``, ``<out>_side_by_side.mp4`` (input | output).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bodystudio.errors import BodyStudioError, FileFormatError, InputError
from bodystudio.fileio import X264_PRESETS, Mp4Writer, atomic_write
from bodystudio.mirror import track as _track
from bodystudio.mirror.compose import BackgroundModel, compose, update_background
from bodystudio.mirror.foreground import refine_foreground
from bodystudio.mirror.warp import (
    CORRESPONDENCES,
    MLS_KINDS,
    actors_warp_pairs,
    mls_warp_field,
    warp_foreground,
    warp_pairs,
)

log = logging.getLogger(__name__)

RUN_JSON = "run.json"
RUN_FORMAT = "bodystudio-mirror-run"
RUN_VERSION = 1
#: Per-frame steps timed by the run, in order (session side, then the image steps, then output).
STEPS = ("read", "register", "ik", "refine_pose", "bodies", "pairs", "foreground", "warp_field", "warp", "compose",
         "background", "write")
IMAGE_STEPS = ("foreground", "warp_field", "warp", "compose", "background")
#: Fewest vertex pairs the warp is trusted with.
MIN_PAIRS = 12
#: MLS weight exponent used by the mirror: ``w_i = 1 / |x - t_i|^(2 alpha)``. Eq. 5 has alpha = 1; alpha = 2
#: keeps the warp more local and scored better with 800 candidate vertices (warp_iou with true vertices,
#: rendered frame +10 % / -10 % stature: 0.956 / 0.922 -> 0.961 / 0.951; MIR-SYNTH v1 session, side-on
#: walk: 0.883 -> 0.905), at 5.4 instead of 4.6 ms per field.
MLS_ALPHA = 2.0
#: Candidate vertices of the warp: ``N_HANDLES`` evenly spread ids plus the target's rim vertices (seen at more
#: than acos(RIM_COS) = 73 degrees), which draw the outline the warp_iou scores. MIR-SYNTH subjects 41 (walk-in,
#: arms_raise, +17 cm +15 kg) and 42 (walk, -17 cm -15 kg), true vertices: warp_iou 0.882 / 0.887 (800
#: evenly spread) -> 0.908 / 0.916; the fitted pipeline 0.855 / 0.827 -> 0.870 / 0.847 (docs/mirror.md).
N_HANDLES = 400
RIM_COS = 0.3
#: MLS weights are summed over the handles within this radius of a grid node (alpha 2: 1/d^4 falls fast):
#: the field of ~1200 pairs in 6 instead of 14 ms with the same warp_iou (docs/mirror.md).
MLS_RADIUS_PX = 32.0
#: The warp's correspondence by default (``warp.CORRESPONDENCES``): ``dense``, the target body rasterised with
#: each pixel mapped to the same surface point of the source body and its outline onto the source's outline
#: (1 px beyond it since MIR12k; MLS farther out before); ``mls``, Eq. 5 from the vertex pairs only. MIR-SYNTH
#: sessions 41 / 42 (docs/mirror.md):
#: true-vertex ceiling 0.905 / 0.915 -> 0.958 / 0.981, the pipeline 0.869 / 0.855 -> 0.887 / 0.878, end to end
#: (41 / 42 / 43) 0.876 / 0.863 / 0.858 -> 0.893 / 0.886 / 0.883, for ~6-7 ms more per frame (6k bodies).
CORRESPONDENCE = "dense"
#: Gauss-Newton steps of the pose refinement (``mirror run --refine-pose``) per frame when the run reshapes one player;
#: one per player when it reshapes several (:func:`refine_steps`). MIR12k: the dense warp without MLS outside the
#: body (``warp.OUTLINE_BAND_PX``) took 2.7 ms CPU off a one-actor frame and 5.2 off a two-actor one; a second
#: step (~2.6 ms an actor) fits a one-player run in that, not two players' at 30 fps. End to end on sessions
#: 41 / 42 / 43 (one reshaped player each): warp_iou +0.003 / +0.006 / +0.003 (docs/mirror.md).
REFINE_STEPS_ONE_PLAYER = 2


#: Depth points of E_depth per Gauss-Newton step when the run reshapes one player (the refinement's default, 400, when
#: it reshapes several, and in ``mirror init``). MIR12n: the refined pose's error is mostly this frame's noise (started
#: at the true pose with the true shape and mask, two steps move it 5.6 mm away); 2000 points take that to 4.9 mm
#: (8000: 4.9) and warp_iou +0.0012 / +0.0009 / +0.0010 on sessions 42 / 41 / 43, +0.0000 / +0.0003 on the held-out
#: 45 / 46, for ~1.1 ms CPU a step, which a one-player run has (docs/mirror.md).
REFINE_DEPTH_SAMPLES_ONE_PLAYER = 2000


#: True: a run that reshapes one player registers both posed bodies in the image plane to the player's refined
#: foreground before the warp (:func:`bodystudio.mirror.image_plane.register_to_outline`: per-bone 2D translations
#: from the source outline's offsets; the bodies' pairs are made again); several players never. MIR12p: end to end
#: 42 / 41 / 43 warp_iou +0.0010 / +0.0009 / +0.0006, held out 45 / 46 / 47 / 48 +0.0005 / +0.0007 / -0.0001 /
#: +0.0004 for a second pairing a frame: off then. mir12u, on the 14 sessions re-made with the fixed renderer and
#: this stop's defaults: +0.0003 to +0.0012 on every one (42 0.9492 -> 0.9501), for +4.8 ms a frame (the pairs step
#: 2.8 -> 7.7 ms on 42, quiet machine, BLAS held to one thread): on (docs/mirror.md).
REGISTER_OUTLINE_ONE_PLAYER = True
#: Trunk bones whose E_trunk centre follows the run's own running mean of their bend (the subject's static posture,
#: :func:`bodystudio.mirror.refine.updated_posture`, over POSTURE_WINDOW frames) instead of the rest pose; () holds
#: them at the rest pose. MIR12q: displacement error 42 / 41 / 43 / 52 / 53 3.30 / 2.87 / 2.70 / 5.68 / 2.87 ->
#: 3.26 / 2.95 / 2.62 / 5.24 / 2.85 mm with the three below (off then). mir12ae: on, with :data:`PELVIS_TILT_RAD`
#: (the two together, on the settled init's bodies with the SDK knee angle): end to end 52 0.9463 -> 0.9484, the 15
#: held-out sessions -0.0003 to +0.0009 (docs/mirror.md, "Session 52 through the run's pose").
POSTURE_BONES: tuple[str, ...] = ("spine_02", "neck_01", "head")
POSTURE_WINDOW = 30
#: The limbs whose twist each frame's IK pose drops before the refinement and the bodies
#: (:func:`bodystudio.mirror.track.untwisted_pose`; () keeps the IK's warm-started twist, as before MIR12p).
UNTWIST_BONES = _track.UNTWIST_BONES
#: True: the feet are untwisted too (:data:`bodystudio.mirror.track.UNTWIST_FEET_BONES`, after UNTWIST_BONES): the
#: IK's warm-started foot twist drifts on a walk as the limbs' did before MIR12p. mir12aa: the feet's twist error on
#: the ten walking sessions 4.2 -> 1.6 degrees, warp_iou 52 / 57 (tuning) +0.0002 / +0.0001, +0.0000 to +0.0007 on the
#: 14 held-out sessions but 43 (-0.00001), 48 (240 frames) the most; 0.02 ms a frame and actor (docs/mirror.md).
UNTWIST_FEET = True


def untwist_bones() -> tuple[str, ...]:
    """The bones each frame's IK pose is untwisted at in the run: :data:`UNTWIST_BONES`, plus the feet with
    :data:`UNTWIST_FEET`."""
    return tuple(UNTWIST_BONES) + (_track.UNTWIST_FEET_BONES if UNTWIST_FEET else ())
#: True: the bodies are posed with the root turned about the vertical only, its tilt moved into the pelvis
#: (:func:`bodystudio.mirror.track.upright_root`: the source's posed vertices stay, the target's no longer turn with
#: the root's tilt, a gauge of the source fit). MIR12s: end to end 52 0.9287 -> 0.9338, 41 / 42 / 43 +0.0005 /
#: +0.0001 / +0.0007, 13 of 14 sessions hold or gain, 48 -0.0002; 0.03 ms a frame and actor (docs/mirror.md).
UPRIGHT_ROOT = True
#: E_upright's scale in the run's pose refinement (:attr:`bodystudio.mirror.refine.RefineWeights.pelvis_tilt_rad`,
#: radians; e.g. :data:`bodystudio.mirror.refine.PELVIS_TILT_RAD`): the pelvis held near upright, so that a stooping
#: person's bend goes into the spine rather than into a tilt of the pelvis that turns the target with it; None: off
#: (mir12ad). The default since mir12ae, 1.5 degrees (= ``refine.PELVIS_TILT_RAD``), with :data:`POSTURE_BONES`:
#: the stoop E_upright keeps out of the pelvis is held in the spine at the subject's own posture (docs/mirror.md).
PELVIS_TILT_RAD: float | None = float(np.radians(1.5))


def refine_steps(n_players: int) -> int:
    """Gauss-Newton steps of each player's pose refinement in a run that reshapes ``n_players`` players."""
    return REFINE_STEPS_ONE_PLAYER if int(n_players) == 1 else 1


def refine_weights(n_players: int):
    """The pose refinement's :class:`~bodystudio.mirror.refine.RefineWeights` in a run that reshapes ``n_players``
    players: :data:`REFINE_DEPTH_SAMPLES_ONE_PLAYER` depth points for one, the defaults for several."""
    from bodystudio.mirror.refine import RefineWeights

    tilt = {"pelvis_tilt_rad": PELVIS_TILT_RAD} if PELVIS_TILT_RAD is not None else {}
    if int(n_players) == 1:
        return RefineWeights(depth_samples=REFINE_DEPTH_SAMPLES_ONE_PLAYER, **tilt)
    return RefineWeights(**tilt)


@dataclass(frozen=True, eq=False)
class MirrorInput:
    """What the image steps need for one frame (colour camera, 640x480 for a Kinect).

    ``person_mask`` is the player mask of the person to reshape mapped into colour (None: not in view);
    ``others_mask`` other players' pixels (never learnt as background); ``src_uv``/``dst_uv`` the
    projected source/target vertex pairs (None when the body steps failed: ``warning`` says why).
    """

    index: int
    rgb: np.ndarray
    person_mask: np.ndarray | None = None
    others_mask: np.ndarray | None = None
    depth_color: np.ndarray | None = None
    src_uv: np.ndarray | None = None
    dst_uv: np.ndarray | None = None
    warning: str | None = None
    timings_ms: dict = field(default_factory=dict)
    pair_groups: np.ndarray | None = None  # (m,) person of each pair when several are reshaped
    unseen: np.ndarray | None = None  # (H, W) bool colour pixels outside the depth camera's view
    edit_fraction: float | None = None  # how far the gradual edit has come (1 = the full edit)
    dense: object | None = None  # warp.DenseCorrespondence of the bodies (the dense warp), None: MLS only
    # ``late_pairs(foreground, timings) -> warp.WarpPairs``: the pose refinement, bodies and pairs, which need
    # the refined foreground of the frame (``--refine-pose``); src_uv/dst_uv/dense are then None until called
    late_pairs: Callable | None = None
    players: tuple | None = None  # the players reshaped in this frame when the run reshapes several (else None)
    # per reshaped player (the run's order), the Kinect id it holds in this frame (None: not found); the SDK renumbers
    # a person it lost and two crossing actors can swap ids (capture.subject.SubjectFollower)
    tracked_as: tuple | None = None
    subject_missing: bool = False  # a reshaped player not found while the tracker reports other people
    person_labels: np.ndarray | None = None  # (H, W) uint8 the player of each person_mask pixel (several players)
    # the steps' CPU ms (``time.process_time``, all threads of the process) next to ``timings_ms``' wall ms; the
    # frame's steps (late_pairs' too) add theirs to this same dict
    cpu_ms: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class FrameResult:
    """One output frame: image, the refined input foreground, the warped foreground, status and timings."""

    index: int
    output: np.ndarray
    foreground: np.ndarray
    warped: np.ndarray
    status: str  # "ok", "empty" (nobody in view: passes through) or "passed_through" (warning)
    warning: str | None
    timings_ms: dict
    cpu_ms: dict = field(default_factory=dict)  # the steps' CPU ms (process_time) next to timings_ms' wall ms


def mirror_frame(inp: MirrorInput, background: BackgroundModel | None, kind: str = "similarity",
                 foreground_options: dict | None = None,
                 alpha: float = MLS_ALPHA) -> tuple[FrameResult, BackgroundModel]:
    """The image steps of §5.3-§5.5 on one frame; returns the result and the updated background model.

    A frame without a person (and without a warning) passes through and teaches the background model;
    a frame with a warning passes through unchanged (the background model learns only where no player is).
    """
    rgb = inp.rgb
    H, W = rgb.shape[:2]
    timings = dict(inp.timings_ms)
    cpu = inp.cpu_ms  # the frame's own dict: late_pairs books its steps' CPU there too
    empty = np.zeros((H, W), bool)
    others = empty if inp.others_mask is None else inp.others_mask
    person = empty if inp.person_mask is None else inp.person_mask
    has_person = bool(person.any())
    if inp.warning is None and has_person and inp.late_pairs is None and \
            (inp.src_uv is None or len(inp.src_uv) < MIN_PAIRS):
        inp = _too_few_pairs(inp)
    if inp.warning is not None or not has_person:
        t, c = time.perf_counter(), time.process_time()
        background = update_background(background, rgb, person | others, unverified=inp.unseen)
        timings["background"] = (time.perf_counter() - t) * 1e3
        cpu["background"] = (time.process_time() - c) * 1e3
        status = "passed_through" if inp.warning is not None else "empty"
        result = FrameResult(inp.index, rgb.copy(), person.copy(), person.copy(), status, inp.warning, timings, cpu)
        return result, background
    if background is None:
        background = update_background(None, rgb, np.ones((H, W), bool))  # nothing learnt yet: inpaint holes
    t0, c0 = time.perf_counter(), time.process_time()
    options = dict(foreground_options or {})
    if inp.person_labels is not None:  # several players: each band pixel's depth against its own player's
        options["labels"] = inp.person_labels
    fg = refine_foreground(rgb, person, inp.depth_color, background=background, unseen=inp.unseen, **options)
    t1, c1 = time.perf_counter(), time.process_time()
    timings["foreground"] = (t1 - t0) * 1e3
    cpu["foreground"] = (c1 - c0) * 1e3
    if inp.late_pairs is not None:  # its own steps (refine_pose, bodies, pairs) time themselves
        pairs = inp.late_pairs(fg, timings)
        groups = getattr(pairs, "groups", None)
        inp = MirrorInput(inp.index, rgb, inp.person_mask, inp.others_mask, inp.depth_color, pairs.src_uv,
                          pairs.dst_uv, None, timings, inp.pair_groups if groups is None else groups, inp.unseen,
                          inp.edit_fraction, pairs.dense, players=inp.players, person_labels=inp.person_labels,
                          cpu_ms=cpu)
        if len(pairs.src_uv) < MIN_PAIRS:
            return mirror_frame(_too_few_pairs(inp), background, kind, foreground_options, alpha)
        t1, c1 = time.perf_counter(), time.process_time()
    warp_field = mls_warp_field(inp.src_uv, inp.dst_uv, (H, W), kind=kind, alpha=alpha, groups=inp.pair_groups,
                                radius_px=MLS_RADIUS_PX, dense=inp.dense, foreground=fg)
    t2, c2 = time.perf_counter(), time.process_time()
    warped_rgb, alpha = warp_foreground(rgb, fg, warp_field)
    t3, c3 = time.perf_counter(), time.process_time()
    out = compose(warped_rgb, alpha, background, rgb, fg)  # bystanders (others) stay as they are
    t4, c4 = time.perf_counter(), time.process_time()
    background = update_background(background, rgb, fg | person | others, unverified=inp.unseen)
    t5, c5 = time.perf_counter(), time.process_time()
    for step, a, b, ca, cb in zip(IMAGE_STEPS[1:], (t1, t2, t3, t4), (t2, t3, t4, t5), (c1, c2, c3, c4),
                                  (c2, c3, c4, c5), strict=True):
        timings[step] = (b - a) * 1e3
        cpu[step] = (cb - ca) * 1e3
    return FrameResult(inp.index, out, fg, alpha > 0.5, "ok", None, timings, cpu), background


def _too_few_pairs(inp: MirrorInput) -> MirrorInput:
    return MirrorInput(inp.index, inp.rgb, inp.person_mask, inp.others_mask, inp.depth_color, None, None,
                       f"only {0 if inp.src_uv is None else len(inp.src_uv)} visible vertex pairs "
                       f"(need {MIN_PAIRS})", inp.timings_ms, inp.pair_groups, inp.unseen, cpu_ms=inp.cpu_ms)


# ---------------------------------------------------------------------------------------------- outputs

#: PNG encoder settings of the run's outputs (lossless: the same pixels as any other setting, tested). Output
#: frames: the Up filter on every row and Huffman-only deflate. libpng's adaptive filter choice, which tries all five
#: filters on every row, was half the encoder's time: 640x480 output frames of session 43 in 8.0 instead of 15.1 ms
#: CPU, 488 instead of 468 kB. Masks (0 / 255): no filter and run-length deflate, 0.4 instead of 3.0 ms, 1.7 instead
#: of 39 kB (MIR12j, docs/mirror.md "Reading and writing").
PNG_FRAME_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
                    cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP)
PNG_MASK_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
                   cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE)


def _png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB output frame (:data:`PNG_FRAME_PARAMS`) or a grey mask (:data:`PNG_MASK_PARAMS`)."""
    params = list(PNG_MASK_PARAMS if image.ndim == 2 else PNG_FRAME_PARAMS)
    ok, data = cv2.imencode(".png", image if image.ndim == 2 else image[..., ::-1], params)
    if not ok:
        raise FileFormatError("cannot encode a PNG frame")
    return data.tobytes()


#: The steps that read the session and write the outputs (the rest is the mirror's compute).
IO_STEPS = ("read", "write")


def end_to_end(ms: Mapping[str, float], encoder_ms: float | None = None) -> dict:
    """Milliseconds and frames per second of a frame end to end, from per-step ``ms`` (medians of one clock), with
    the reading and writing (``IO_STEPS``, plus ``encoder_ms`` per frame: the video encoder's own process) and
    without them (the compute steps alone, what the benchmark's fps counts)."""
    with_io = float(sum(ms.values())) + (encoder_ms or 0.0)
    without = float(sum(v for k, v in ms.items() if k not in IO_STEPS))
    return {"ms": with_io, "fps": 1e3 / with_io if with_io > 0 else None,
            "ms_without_io": without, "fps_without_io": 1e3 / without if without > 0 else None}


def _summary(results: list[dict], steps_ms: dict[str, list[float]], wall_s: float,
             steps_cpu_ms: dict[str, list[float]] | None = None, cpu_s: float | None = None,
             encoder_cpu_s: float | None = None) -> dict:
    # medians: the first frames carry the numba compilation and the video encoder's start
    ms = {k: float(np.median(v)) for k, v in steps_ms.items() if v}
    image_ms = sum(ms.get(k, 0.0) for k in IMAGE_STEPS)
    counts = {s: sum(r["status"] == s for r in results) for s in ("ok", "empty", "passed_through")}
    n = len(results)
    out = {"frames": n, **{f"n_{k}": v for k, v in counts.items()},
           "n_warnings": counts["passed_through"],
           # frames where a reshaped player was not found while the tracker reported other people (passed through
           # for one player; left out of the frame when several are reshaped)
           "n_subject_missing": sum(bool(r.get("subject_missing")) for r in results),
           "ms_per_frame": ms, "ms_per_frame_statistic": "median",
           "image_steps_ms": image_ms, "image_steps_fps": 1e3 / image_ms if image_ms > 0 else None,
           "wall_s": wall_s, "fps_wall": n / wall_s if wall_s > 0 else None}
    if steps_cpu_ms is not None:
        cpu = {k: float(np.median(v)) for k, v in steps_cpu_ms.items() if v}
        encoder_ms = None if encoder_cpu_s is None else encoder_cpu_s * 1e3 / max(n, 1)
        out.update({
            # the same steps in CPU ms of this process (time.process_time): what one core pays, whatever the load
            "cpu_ms_per_frame": cpu,
            # the video encoder (ffmpeg, its own process) in CPU ms per frame, its start and end included
            "encoder_cpu_ms_per_frame": encoder_ms,
            # a frame end to end, with and without reading and writing: CPU (one core) and wall (medians summed)
            "end_to_end_cpu": end_to_end(cpu, encoder_ms), "end_to_end_wall": end_to_end(ms),
            # the whole loop's CPU: the set-up of the first frame and numba's compilation on a fresh install included
            # (~25 s on session 43), so no frame rate is made of it
            "cpu_s": cpu_s})
    return out


def _children_cpu_s() -> float:
    """CPU seconds of this process's finished child processes (the video encoders once closed)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def check_video_preset(preset: str) -> str:
    """``preset`` if it is an x264 preset (``fileio.X264_PRESETS``), else a one-line InputError. ``veryfast``, the
    default, is the video of earlier runs; ``ultrafast`` encodes session 43's frames in 3.3 instead of 7.6 ms CPU of
    the encoder at the same PSNR (33.7 / 33.4 dB) in a 3.3 times larger file (docs/mirror.md)."""
    if preset not in X264_PRESETS:
        raise InputError(f"--video-preset {preset!r}; valid: {', '.join(X264_PRESETS)} (fastest first)")
    return preset


def video_paths(out_video, side_by_side: bool = True) -> list[tuple[str, Path]]:
    """``[("output", out.mp4), ("side_by_side", out_side_by_side.mp4)]``, each checked writable (one-line errors)."""
    from bodystudio.runfolder import check_output_destination

    if out_video is None:
        return []
    out_video = Path(out_video)
    if out_video.suffix.lower() != ".mp4":
        raise InputError(f"--out {out_video}: the video must be an .mp4 file")
    videos = [("output", out_video)]
    if side_by_side:
        videos.append(("side_by_side", out_video.with_name(out_video.stem + "_side_by_side.mp4")))
    for _, path in videos:
        check_output_destination(path, "video")
    return videos


def mirror_stream(inputs: Iterable[MirrorInput], run_dir: str | Path, out_video: str | Path | None = None,
                  fps: float = 30.0, side_by_side: bool = True, kind: str = "similarity", manifest: dict | None = None,
                  progress: bool = False, total: int | None = None, command: str = "bodystudio mirror run",
                  foreground_options: dict | None = None, background: BackgroundModel | None = None,
                  preview: str | Path | None = None, video_preset: str = "veryfast") -> dict:
    """Run the image steps over ``inputs`` and commit frames, masks, video(s) and ``run.json`` as one unit.

    Returns the ``run.json`` content. A frame whose processing raises a user-level error passes
    through with that warning; nothing is published if the run itself fails (the previous run stays).
    ``preview``: a PNG rewritten (atomically) with every output frame, for a live display. ``video_preset``:
    the x264 preset of the videos (:func:`check_video_preset`).
    """
    from bodystudio.runfolder import RunLayout, RunWriter

    if kind not in MLS_KINDS:
        raise InputError(f"--warp {kind!r}; valid: {', '.join(MLS_KINDS)}")
    if not 1.0 <= float(fps) <= 240.0:
        raise InputError(f"fps must lie in 1..240, got {fps}")
    check_video_preset(video_preset)
    run_dir = Path(run_dir)
    videos = video_paths(out_video, side_by_side)
    layout = RunLayout(run_dir, RUN_JSON, ".", str(run_dir))
    results: list[dict] = []
    steps_ms: dict[str, list[float]] = {s: [] for s in STEPS}
    steps_cpu_ms: dict[str, list[float]] = {s: [] for s in STEPS}
    writers: dict[str, Mp4Writer] = {}
    t_start, c_start = time.perf_counter(), time.process_time()
    children_start = _children_cpu_s()
    from bodystudio.capture.session import progress_bar

    with RunWriter(layout, command, {"stage": "mirror", "kind": kind}) as w, progress_bar(progress) as bar:
        task = bar.add_task("mirror", total=total)
        try:
            for inp in inputs:
                try:
                    res, background = mirror_frame(inp, background, kind, foreground_options)
                except BodyStudioError as exc:  # one bad frame never stops the run
                    res = FrameResult(inp.index, inp.rgb.copy(), np.zeros(inp.rgb.shape[:2], bool),
                                      np.zeros(inp.rgb.shape[:2], bool), "passed_through", str(exc),
                                      dict(inp.timings_ms), dict(inp.cpu_ms))
                if res.warning:
                    log.warning("frame %d passes through: %s", res.index, res.warning)
                t, c = time.perf_counter(), time.process_time()
                name = f"{res.index:05d}.png"
                w.write_bytes(f"frames/{name}", _png(res.output))
                w.write_bytes(f"masks/foreground/{name}", _png(res.foreground.astype(np.uint8) * 255))
                w.write_bytes(f"masks/warped/{name}", _png(res.warped.astype(np.uint8) * 255))
                for key, path in videos:
                    frame = res.output if key == "output" else np.hstack([inp.rgb, res.output])
                    if key not in writers:  # absolute: a relative --out is the user's cwd, not the run folder
                        writers[key] = Mp4Writer(w.path_for(Path(path).absolute()), (frame.shape[1], frame.shape[0]),
                                                 fps, video_preset)
                    writers[key].write(frame)
                if preview is not None:
                    with atomic_write(preview, "wb") as f:
                        f.write(_png(res.output))
                res.timings_ms["write"] = (time.perf_counter() - t) * 1e3
                res.cpu_ms["write"] = (time.process_time() - c) * 1e3
                for step, value in res.timings_ms.items():
                    steps_ms.setdefault(step, []).append(value)
                for step, value in res.cpu_ms.items():
                    steps_cpu_ms.setdefault(step, []).append(value)
                record = {"index": res.index, "status": res.status, "warning": res.warning,
                          "edit_fraction": inp.edit_fraction,
                          "ms": {k: round(v, 3) for k, v in res.timings_ms.items()},
                          "cpu_ms": {k: round(v, 3) for k, v in res.cpu_ms.items()}}
                if inp.players is not None:  # a run of several players: who was reshaped in this frame
                    record["players"] = list(inp.players) if res.status == "ok" else []
                if inp.tracked_as is not None:  # the Kinect id each reshaped player held (None: not found)
                    record["tracked_as"] = list(inp.tracked_as)
                if inp.subject_missing:
                    record["subject_missing"] = True
                results.append(record)
                bar.advance(task)
        finally:
            for writer in writers.values():
                writer.close()
        if not results:
            raise InputError(f"{run_dir}: no frames to process; check the session's frames or --frames")
        summary = _summary(results, steps_ms, time.perf_counter() - t_start, steps_cpu_ms,
                           time.process_time() - c_start, _children_cpu_s() - children_start if writers else None)
        doc = {"format": RUN_FORMAT, "version": RUN_VERSION, **(manifest or {}), "kind": kind, "fps": fps,
               "videos": {k: str(p) for k, p in videos}, "summary": summary, "frames": results}
        return w.commit(doc)


# ---------------------------------------------------------------------------------------------- session side

def source_body_path(session_path, player: int = 1) -> Path:
    """Where ``bodystudio mirror init --player N`` writes player N's source body: ``SESSION/mirror/source_body.npz``
    for player 1 (the file of single-player sessions), ``SESSION/mirror/source_body_player{N}.npz`` for another.
    Each file also records its player (:func:`source_body_player`), so no run pairs a player with another's body."""
    name = "source_body.npz" if int(player) == 1 else f"source_body_player{int(player)}.npz"
    return Path(session_path) / "mirror" / name


def source_body_player(path) -> int | None:
    """The player a source body file was fitted to: its ``player`` entry (``mirror init`` writes it), else the
    ``player`` of the summary beside it (``source_body.json`` of older inits), None when neither says."""
    import json
    import zipfile

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "player" in z.files:
                return int(z["player"])
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return None  # load_source_body names what is wrong with the file
    try:
        player = json.loads(path.with_suffix(".json").read_text(encoding="utf-8")).get("player")
    except (OSError, ValueError, AttributeError):
        return None
    return int(player) if isinstance(player, int) and not isinstance(player, bool) else None


def check_source_player(path, player: int) -> None:
    """One-line InputError when the source body file ``path`` records another player than ``player``."""
    recorded = source_body_player(path)
    if recorded is not None and recorded != int(player):
        raise InputError(f"{path}: the source body of player {recorded}, not of player {player}; run 'bodystudio "
                         f"mirror init SESSION --player {player}' (it writes "
                         f"mirror/{source_body_path('.', player).name}) or give player {player}'s body")


def load_source(session, source=None, player: int = 1):
    """The source body (with skin weights and faces) and its statistical model, from ``source`` (a SourceBody
    or an .npz path) or ``player``'s file in the session (:func:`source_body_path`); a file that records another
    player is refused (:func:`check_source_player`)."""
    from bodystudio.body.statistical import load_statistical_model

    path = source_body_path(session.path, player) if source is None else Path(source) \
        if isinstance(source, (str, os.PathLike)) else source
    if isinstance(path, Path) and not path.is_file():
        raise FileFormatError(f"{path}: source body not found; run 'bodystudio mirror init {session.path}"
                              f"{'' if int(player) == 1 else f' --player {int(player)}'}' first (or give --source)")
    if isinstance(path, Path):
        check_source_player(path, player)
    init = _stage_module("init")
    SourceBody, load_source_body = init.SourceBody, init.load_source_body
    body = source if isinstance(source, SourceBody) else load_source_body(path)
    for resolution in ("6k", "2k"):
        model = load_statistical_model(resolution, progress=False)
        if len(model.mean) == len(body.vertices) and len(model.stddev) == len(body.coeffs):
            return SourceBody(body.coeffs, body.vertices, body.skeleton, body.frames_used, body.residual_mm,
                              model.weights, model.faces), model
    raise InputError(f"{path}: source body of {len(body.vertices)} vertices matches no statistical model "
                     "(6k, 2k); rerun 'bodystudio mirror init'")


def frame_pairs(sources, targets, faces, camera, correspondence: str = CORRESPONDENCE):
    """The warp's constraints of one frame (:class:`bodystudio.mirror.warp.WarpPairs`) from the posed source and
    target bodies of the actors reshaped (lists, one body each, the same ``faces``): one actor's by
    :func:`~bodystudio.mirror.warp.warp_pairs`, several actors' in one call
    (:func:`~bodystudio.mirror.warp.actors_warp_pairs`: one z-buffer per body, ``groups`` says whose each pair
    is). The run and ``benchmarks/bench_mirror.py`` both call this."""
    dense = correspondence == "dense"
    # the statistical model's bodies are closed and wound outwards: their z-buffers need only the triangles facing
    # the camera (warp.front_render, MIRFAST3)
    if len(sources) == 1:
        return warp_pairs(sources[0], targets[0], faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=dense, closed=True)
    return actors_warp_pairs(sources, targets, faces, camera, N_HANDLES, rim_cos=RIM_COS, dense=dense, closed=True)


def registered_pairs(pairs, Vs: np.ndarray, Vt: np.ndarray, faces, weights, parents, camera, foreground,
                     correspondence: str = CORRESPONDENCE):
    """One player's warp constraints after the bodies' registration to the refined ``foreground`` (MIR12p,
    :data:`REGISTER_OUTLINE_ONE_PLAYER`): the posed source ``Vs`` and target ``Vt`` moved in the image plane by
    :func:`bodystudio.mirror.image_plane.register_to_outline` and paired again (:func:`frame_pairs`); ``pairs``
    (their first pairing, dense) unchanged where too few outline vertices register. The run and
    ``benchmarks/bench_mirror.py`` both call this."""
    from bodystudio.mirror.image_plane import register_to_outline

    if pairs.dense is None:
        return pairs
    Vs2, Vt2, _ = register_to_outline(Vs, Vt, faces, weights, parents, camera, foreground, pairs.dense.source_mask,
                                      pairs.dense.source_depth, pairs.dense.origin)
    if Vs2 is Vs:  # too few outline vertices: the bodies as they are
        return pairs
    return frame_pairs([Vs2], [Vt2], faces, camera, correspondence)


def player_masks(players_c: np.ndarray, players: tuple[int, ...], several: bool
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The colour-registered player mask ``players_c`` (uint8 ids) split into the reshaped players' pixels
    (``person``), the other players' (``others``) and, for ``several``, the reshaped players' labels (uint8,
    0 elsewhere). One comparison per player ORed, and the labels as a product: ``np.isin`` and
    ``np.where(..).astype`` took ~1.2 ms of the two-actor frame for the same masks (MIR12e)."""
    person = players_c == players[0]
    for p in players[1:]:
        person |= players_c == p
    others = (players_c > 0) & ~person
    return person, others, (players_c * person).astype(np.uint8, copy=False) if several else None


@dataclass
class _Actor:
    """One reshaped player's state through a run: its body, target (Eq. 4), refinement plan, last pose, ramp."""

    player: int
    body: object
    c_target: np.ndarray
    target_rest: np.ndarray
    plan: object = None
    previous: object = None
    tracked_frames: int = 0
    posture: object = None  # E_trunk's centre (POSTURE_BONES), None: the rest pose
    refined_frames: int = 0
    follower: object = None  # capture.subject.SubjectFollower: the Kinect id this player holds, frame to frame


def _tracked_record(body) -> dict:
    """A :class:`~bodystudio.mirror.frames.TrackedBody` as the body record :mod:`bodystudio.capture.subject` follows."""
    return {"player": body.player, "names": body.names, "positions": body.positions, "tracked_body": body}


def _colour_or_none(session, i: int, camera) -> np.ndarray | None:
    """Frame ``i``'s Kinect colour image when it reads and has the colour camera's size, else None (rel6a: a frame
    whose depth, player mask or joints were damaged passed the previous frame's colour through, a frozen frame)."""
    try:
        rgb = session.frame(i).kinect_rgb
    except BodyStudioError:
        return None
    return rgb if rgb is not None and rgb.shape == (camera.height, camera.width, 3) else None


def session_inputs(session, body, model, edits: dict[str, float], player=1, ramp_frames: int = 30,
                   frames: Iterable[int] | None = None,
                   correspondence: str = CORRESPONDENCE, refine: bool = False) -> Iterator[MirrorInput]:
    """Per frame of ``session``: the colour frame, the player masks in colour and the projected vertex pairs
    (with ``correspondence`` ``dense`` also the dense correspondence of the posed bodies).

    ``player`` one Kinect player id with its source ``body``, or a sequence of players with a sequence of bodies
    (the same order): all of them are reshaped in each frame, their masks together the person of the graph cut,
    their pairs from one :func:`frame_pairs` call. A chosen player not in view is left out of the frame; one in
    the mask but not tracked (or tracked with an empty mask, or whose tracking fails) passes the frame through
    with a warning, as for one player.

    Each player is the id given at its first tracked frame and then followed by its joints
    (:func:`bodystudio.capture.subject.stage_follower` at the session's frame rate, the stages' rule since rel7b):
    the SDK renumbers a person it lost and two crossing actors can swap ids, so the frame's body nearest the player's
    last joints (within 0.3 m) is the player under whatever id it holds, and a body holding the player's id farther
    than a skeleton jumps in a frame (0.6 m, plus 3 m/s times the time the player was missed) is someone else, and
    stays someone else while it stays (rel7b: before, it was taken once the reach had grown past it). A run of
    one player whose subject is not found while the tracker reports other people passes the frame through with a
    warning (``subject_missing``); a bystander is never reshaped in the subject's place.

    The target body is computed once (Eq. 4) and reached gradually: the target rest shape is
    ``V_S + s (V_T - V_S)`` with ``s`` going 0 -> 1 over ``ramp_frames`` tracked frames of that player (Eq. 4 is
    linear in lambda, so this is the ramp of lambda without a solve per frame). ``refine``: the IK pose is refined
    against the frame's refined foreground (without the other players' pixels), the depth and the joints
    (:func:`bodystudio.mirror.refine.refine_pose`) before it poses the source and target bodies: the frame then
    carries ``late_pairs``, which :func:`mirror_frame` calls after the graph cut.
    """
    from bodystudio.mirror.frames import read_mirror_frame, register_depth_to_color
    from bodystudio.mirror.reshape import posed_source_and_target, target_coeffs, target_skeleton
    from bodystudio.mirror.track import ik_pose, untwisted_pose, upright_root

    sensor = session.kinect
    if sensor is None:
        raise InputError(f"{session.path}: not a Kinect session (no kinect/calibration.json); the mirror needs "
                         "Kinect colour, depth, player mask and joints")
    several = not isinstance(player, (int, np.integer))
    players = tuple(int(p) for p in player) if several else (int(player),)
    bodies = tuple(body) if several else (body,)
    if len(bodies) != len(players) or not players:
        raise InputError(f"session_inputs: {len(players)} players but {len(bodies)} source bodies")
    from bodystudio.capture.subject import follow_subjects, session_follower

    actors = []
    for p, b in zip(players, bodies, strict=True):
        c_target = target_coeffs(model, b.coeffs, edits)
        actors.append(_Actor(p, b, c_target, model.vertices(c_target),
                             follower=session_follower(session, p)))
    camera = sensor.color
    if refine:
        from bodystudio.mirror.frames import point_cloud
        from bodystudio.mirror.refine import TWIST_BONES, refine_plan, refine_pose, updated_posture

        steps = refine_steps(len(actors))
        weights = refine_weights(len(actors))
        for a in actors:
            a.plan = refine_plan(a.body.vertices, a.body.faces, a.body.weights, a.body.skeleton, sensor.version,
                                 twist_bones=TWIST_BONES)
    last_rgb = None
    seen = None
    for i in (session.frame_ids if frames is None else frames):
        timings, cpu = {}, {}
        t, c = time.perf_counter(), time.process_time()
        try:
            frame = (read_arriving_frame(session, int(i)) if isinstance(getattr(session, "manifest", {}).get("files"),
                                                                        _ExistingFiles)
                     else read_mirror_frame(session, int(i)))
        except BodyStudioError as exc:
            rgb = _colour_or_none(session, int(i), camera)  # a damaged depth / mask / joints file: its own colour
            if rgb is None:  # the colour itself unreadable: the last frame's, as a live mirror shows
                rgb = last_rgb if last_rgb is not None else np.zeros((camera.height, camera.width, 3), np.uint8)
            yield MirrorInput(int(i), rgb, warning=f"frame unreadable: {exc}", timings_ms=timings, cpu_ms=cpu)
            continue
        last_rgb = frame.rgb
        t1, c1 = time.perf_counter(), time.process_time()
        timings["read"] = (t1 - t) * 1e3
        cpu["read"] = (c1 - c) * 1e3
        depth_c, players_c = register_depth_to_color(frame.depth_m, frame.player, sensor)
        # where the depth camera has ever measured (its view is narrower than the colour camera's); grown only when
        # a frame measures somewhere new, so its dilation is redone only then
        measured = depth_c > 0
        if seen is None or (measured & ~seen).any():
            seen = measured if seen is None else seen | measured
            unseen = cv2.dilate(seen.astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
        found = follow_subjects([a.follower for a in actors], [_tracked_record(b) for b in frame.bodies])
        tracked_as = tuple(None if f is None else f["player"] for f in found)
        # the players' ids in this frame's mask: where found, the id each holds; where not, the id it held last unless
        # a tracked body (someone else) holds it now
        ids = tuple(a.follower.player for a, f in zip(actors, found, strict=True)
                    if f is not None or frame.body(a.follower.player) is None)
        if ids:
            person, others, labels = player_masks(players_c, ids, several)
        else:  # none of the run's players tracked: whoever is in the mask is someone else
            person = np.zeros(players_c.shape, bool)
            others, labels = players_c > 0, np.zeros(players_c.shape, np.uint8) if several else None
        t2, c2 = time.perf_counter(), time.process_time()
        timings["register"] = (t2 - t1) * 1e3
        cpu["register"] = (c2 - c1) * 1e3
        base = dict(index=int(i), rgb=frame.rgb, person_mask=person, others_mask=others, depth_color=depth_c,
                    timings_ms=timings, unseen=unseen, person_labels=labels, cpu_ms=cpu, tracked_as=tracked_as)
        present, warning, missing = [], None, False
        for a, f in zip(actors, found, strict=True):
            pid = a.follower.player
            if f is None:
                held = f" (last tracked as {pid})" if pid != a.player else ""
                if frame.body(pid) is None and (players_c == pid).any():
                    warning = f"player {a.player}{held} is in the mask but no body is tracked"
                    break
                if frame.bodies:  # people tracked, none of them the player: never reshape another in its place
                    missing = True
                    if not several:
                        warning = (f"player {a.player}{held} is not among the tracked bodies (players "
                                   f"{', '.join(str(b.player) for b in frame.bodies)}): the run's subject is not "
                                   f"found near its last joints{a.follower.lost_reason()}; the frame passes through "
                                   "unchanged")
                        break
                continue  # left out of the frame, as a player out of view
            mine = person if not several else players_c == pid
            present.append((a, f["tracked_body"], mine, pid))
        if warning is None and present:
            if not (frame.depth_m > 0).any():
                warning = "depth missing (no depth measurement in the frame)"
            else:
                empty = next((a for a, _, mine, _ in present if not mine.any()), None)
                if empty is not None:
                    warning = f"body {empty.player} is tracked but its player mask is empty"
        if warning is not None or not present:
            yield MirrorInput(**base, warning=warning, players=() if several else None, subject_missing=missing)
            continue
        poses = []
        for a, tracked, _, _ in present:
            try:
                pose = ik_pose(a.body.skeleton, tracked.positions, tracked.tracked, sensor.version,
                               previous=a.previous)
                untwist = untwist_bones()
                poses.append(untwisted_pose(a.body.skeleton, pose, untwist) if untwist else pose)
            except BodyStudioError as exc:
                warning = f"tracking failed: {exc}" if not several else f"tracking player {a.player} failed: {exc}"
                break
        if warning is not None:
            yield MirrorInput(**base, warning=warning, players=() if several else None, subject_missing=missing)
            continue
        shapes = []
        for (a, _, _, _), pose in zip(present, poses, strict=True):
            a.previous = pose
            a.tracked_frames += 1
            s = min(1.0, a.tracked_frames / max(int(ramp_frames), 1))
            Vt_rest = a.body.vertices + s * (a.target_rest - a.body.vertices)
            rig = target_skeleton(a.body, Vt_rest, model, a.body.coeffs + s * (a.c_target - a.body.coeffs))
            shapes.append((s, Vt_rest, rig))
        t3 = time.perf_counter()
        timings["ik"] = (t3 - t2) * 1e3
        cpu["ik"] = (time.process_time() - c2) * 1e3
        fraction = min(s for s, _, _ in shapes)
        reshaped = tuple(a.player for a, _, _, _ in present) if several else None

        def bodies_and_pairs(foreground, timings, poses=poses, frame=frame, present=present, shapes=shapes,
                             players_c=players_c, others=others, cpu=cpu):
            """Pose refinement (with the frame's refined ``foreground`` when given), the bodies, the pairs."""
            sources, targets, fgs = [], [], []
            for (a, tracked, _, pid), pose, (_, Vt_rest, rig) in zip(present, poses, shapes, strict=True):
                t, c = time.perf_counter(), time.process_time()
                if foreground is not None:
                    points = point_cloud(frame, sensor, pid)
                    points = points[points[:, 1] > 0.02]  # not the floor under the feet
                    # several players: this one's foreground is the cut's without the other players' pixels
                    not_mine = others if not several else (players_c > 0) & (players_c != pid)
                    fg = foreground if not several else foreground & ~not_mine
                    fgs.append(fg)
                    try:
                        pose = refine_pose(a.plan, a.body.skeleton, pose, camera, fg, tracked.positions,
                                           tracked.tracked, points, not_mine, sensor.version, iterations=steps,
                                           weights=weights, posture=a.posture)
                        if POSTURE_BONES:
                            a.refined_frames += 1
                            a.posture = updated_posture(a.posture, a.body.skeleton, pose, a.refined_frames,
                                                        POSTURE_WINDOW, POSTURE_BONES)
                    except BodyStudioError as exc:  # mirror_stream passes the frame through with this warning
                        who = f" of player {a.player}" if several else ""
                        raise InputError(f"pose refinement{who} failed: {exc}") from exc
                    t_refined, c_refined = time.perf_counter(), time.process_time()
                    timings["refine_pose"] = timings.get("refine_pose", 0.0) + (t_refined - t) * 1e3
                    cpu["refine_pose"] = cpu.get("refine_pose", 0.0) + (c_refined - c) * 1e3
                    t, c = t_refined, c_refined
                if UPRIGHT_ROOT:  # the root's tilt is the source's gauge and would turn the target (MIR12s)
                    pose = upright_root(a.body.skeleton, pose)
                Vs, Vt = posed_source_and_target(a.body, Vt_rest, pose, rig)
                sources.append(Vs)
                targets.append(Vt)
                timings["bodies"] = timings.get("bodies", 0.0) + (time.perf_counter() - t) * 1e3
                cpu["bodies"] = cpu.get("bodies", 0.0) + (time.process_time() - c) * 1e3
            t_bodies, c_bodies = time.perf_counter(), time.process_time()
            pairs = frame_pairs(sources, targets, present[0][0].body.faces, camera, correspondence)
            if fgs and len(actors) == 1 and REGISTER_OUTLINE_ONE_PLAYER and pairs.dense is not None:
                body = present[0][0].body
                pairs = registered_pairs(pairs, sources[0], targets[0], body.faces, body.weights,
                                         body.skeleton.parents, camera, fgs[0], correspondence)
            timings["pairs"] = (time.perf_counter() - t_bodies) * 1e3
            cpu["pairs"] = (time.process_time() - c_bodies) * 1e3
            return pairs

        if refine:  # the pose waits for the graph cut's foreground (mirror_frame calls back)
            yield MirrorInput(**base, edit_fraction=fraction, late_pairs=bodies_and_pairs, players=reshaped,
                              subject_missing=missing)
            continue
        pairs = bodies_and_pairs(None, timings)
        yield MirrorInput(**base, src_uv=pairs.src_uv, dst_uv=pairs.dst_uv, edit_fraction=fraction,
                          dense=pairs.dense, pair_groups=getattr(pairs, "groups", None), players=reshaped,
                          subject_missing=missing)


def _stage_module(name: str):
    """``bodystudio.mirror.<name>`` (the body side of the stage), or a one-line error when it is missing."""
    import importlib

    try:
        return importlib.import_module(f"bodystudio.mirror.{name}")
    except ImportError:
        raise InputError(f"this bodystudio has no mirror {name} step (bodystudio.mirror.{name}); install the "
                         "complete mirror stage") from None


def check_edits(edits: dict[str, float]) -> dict[str, float]:
    """The edits with their ranges checked by the reshape step (one-line InputError otherwise)."""
    bad = [k for k, v in edits.items() if not np.isfinite(float(v))]
    if bad:
        raise InputError(f"edit {bad[0]} is not a finite number; give a value such as --{bad[0]} 0.05")
    reshape = _stage_module("reshape")
    unknown = sorted(set(edits) - set(reshape.EDIT_NAMES))
    if unknown:
        raise InputError(f"unknown edit(s) {', '.join(unknown)}; valid: {', '.join(reshape.EDIT_NAMES)}")
    if hasattr(reshape, "check_edits"):
        return reshape.check_edits(edits)
    return {k: float(v) for k, v in edits.items()}


def run_mirror(session, edits: dict[str, float], out_video, source=None, side_by_side: bool = True,
               progress: bool = True, run_dir: str | Path | None = None, player=1, kind: str = "similarity",
               ramp_frames: int = 30, frames: Iterable[int] | None = None, live: str | Path | None = None,
               live_timeout_s: float = 5.0, correspondence: str = CORRESPONDENCE, refine_pose: bool = True,
               accept_implausible: bool = False, video_preset: str = "veryfast") -> dict:
    """``bodystudio mirror run``: reshape the actor(s) of ``session`` by ``edits`` and write the video and run folder.

    ``session`` an opened session or its path; ``player`` a Kinect player id or a sequence of them (all reshaped
    by ``edits`` in every frame, one graph cut and one warp); ``source`` a SourceBody or its .npz (one player), or a
    sequence of them in the order of ``player`` (default each player's file from ``mirror init --player N``,
    :func:`source_body_path`; a file that records another player is refused); ``run_dir`` default
    ``SESSION/mirror/run``.
    ``live``: a folder a recorder is filling with the session layout's ``kinect/`` streams; its frames are
    processed as they arrive (until ``live_timeout_s`` without a new one), each output frame also written
    to ``RUN/live_latest.png`` for a display to pick up. ``correspondence``: ``dense`` (default) or ``mls``
    (:data:`bodystudio.mirror.warp.CORRESPONDENCES`). ``refine_pose``: refine each frame's IK pose against the
    refined foreground, depth and joints (:mod:`bodystudio.mirror.refine`; on by default since MIRFAST, ~4 ms more
    per frame per player; False: the IK pose alone). Each player's source body is checked against the session's
    tracked skeleton and the depth-to-colour registration against the colour edges first
    (:mod:`bodystudio.mirror.plausibility`: another person's body or a misregistered Kinect is refused unless
    ``accept_implausible``; the verdicts go to run.json's ``plausibility``, per player when there are several).
    ``video_preset``: the x264 preset of the videos (:func:`check_video_preset`; default ``veryfast``).
    Returns run.json's content (per-step timings in ``summary.ms_per_frame``; several players: ``players``,
    ``source_fingerprints`` and each frame's ``players``).
    """
    from bodystudio.capture.session import open_session

    several = not isinstance(player, (int, np.integer))
    players = [int(p) for p in player] if several else [int(player)]
    for p in players:
        if not 1 <= p <= 6:
            raise InputError(f"--player {p}: a Kinect player id is 1..6")
    if not players:
        raise InputError("--player: give at least one Kinect player id (1..6)")
    if len(set(players)) != len(players):
        raise InputError(f"--player {' --player '.join(map(str, players))}: a player is given twice; give each once")
    sources = list(source) if several and source is not None and not isinstance(source, (str, os.PathLike)) \
        else [source] * len(players) if source is None else [source]
    if len(sources) != len(players):
        raise InputError(f"--source given {len(sources)} times for {len(players)} players; give one --source per "
                         "--player (in the same order), or none to read each player's body from the session")
    if not 0 <= int(ramp_frames) <= 10000:
        raise InputError(f"--ramp-frames {ramp_frames}: use 0..10000")
    if kind not in MLS_KINDS:
        raise InputError(f"--warp {kind!r}; valid: {', '.join(MLS_KINDS)}")
    if correspondence not in CORRESPONDENCES:
        raise InputError(f"--correspondence {correspondence!r}; valid: {', '.join(CORRESPONDENCES)}")
    check_video_preset(video_preset)
    video_paths(out_video, side_by_side)
    if isinstance(session, (str, os.PathLike)):
        session = open_session(session)
    run_dir = Path(session.path) / "mirror" / "run" if run_dir is None else Path(run_dir)
    frames_from = live_session(live) if live is not None else session
    if frames_from.kinect is None:
        raise InputError(f"{session.path}: not a Kinect session (no kinect/calibration.json); the mirror needs "
                         "Kinect colour, depth, player mask and joints")
    for p, src in zip(players, sources, strict=True):
        source_path = source_body_path(session.path, p) if src is None else src
        if isinstance(source_path, (str, os.PathLike)):
            if not Path(source_path).is_file():
                again = "" if p == 1 else f" --player {p}"
                raise FileFormatError(f"{source_path}: source body not found; run 'bodystudio mirror init "
                                      f"{session.path}{again}' first (or give --source)")
            check_source_player(source_path, p)
    edits = check_edits(dict(edits))
    metadata = session.metadata if isinstance(session.metadata, dict) else {}
    try:
        fps = float(metadata.get("fps", 30.0))
    except (TypeError, ValueError):
        fps = float("nan")
    if not 1.0 <= fps <= 240.0:
        raise InputError(f"{session.path}: session metadata fps {metadata.get('fps')!r} is not a frame rate "
                         "in 1..240; regenerate or re-import the session")
    if live is not None:
        ids, total = live_frame_ids(live, live_timeout_s), None
    else:
        ids = list(session.frame_ids if frames is None else frames)
        total = len(ids)
    fingerprint = _stage_module("init").source_fingerprint
    if not several:
        body, model = load_source(session, source) if players[0] == 1 else load_source(session, source, players[0])
        bodies = body
    else:
        loaded = [load_source(session, src, p) for p, src in zip(players, sources, strict=True)]
        bodies, model = [b for b, _ in loaded], loaded[0][1]
        if any(len(b.vertices) != len(bodies[0].vertices) for b in bodies):
            raise InputError(f"players {', '.join(map(str, players))}: their source bodies come from different "
                             "statistical models (6k / 2k); run 'bodystudio mirror init' for each with the same "
                             "--resolution")
    first = bodies[0] if several else bodies
    plausibility = None
    if live is None and hasattr(first, "skeleton"):  # live: the frames are not recorded yet
        from bodystudio.mirror.plausibility import check_registration, check_source_body, followed_players

        # each actor followed over the run's frames as the run follows them (rel6b: the checks read player N by its
        # id, and after the SDK renumbered the actor they measured the other one)
        followed = followed_players(session, players, ids)
        tracked = {p: {i: f[k] for i, f in followed.items()} for k, p in enumerate(players)}

        def _verdicts(b, p, src):
            return {"source_body": check_source_body(b, session, p, accept_implausible,
                                                     src if isinstance(src, (str, os.PathLike)) else None,
                                                     tracked_as=tracked[p]),
                    "registration": check_registration(session, p, accept_implausible, tracked_as=tracked[p])}

        if several:
            plausibility = {str(p): _verdicts(b, p, src) for p, b, src in zip(players, bodies, sources, strict=True)}
        else:
            plausibility = _verdicts(bodies, players[0], source)
    manifest = {"session": str(Path(session.path).resolve()),
                "session_run_id": (session.manifest.get("run") or {}).get("run_id"),
                # the recording read (eval mirror accepts the session moved with its run by this, not the path)
                "session_fingerprint": None if live is not None
                else _stage_module("frames").recording_fingerprint(session, ids),
                "live": None if live is None else str(Path(live).resolve()),
                "edits": edits, "player": players[0], "ramp_frames": int(ramp_frames),
                "correspondence": correspondence, "refine_pose": bool(refine_pose), "video_preset": video_preset,
                "source_fingerprint": fingerprint(first) if hasattr(first, "coeffs")
                else None}  # a stand-in body (tests) has none
    if plausibility is not None:
        manifest["plausibility"] = plausibility
    if several:
        manifest["players"] = players
        manifest["source_fingerprints"] = {str(p): fingerprint(b) if hasattr(b, "coeffs") else None
                                           for p, b in zip(players, bodies, strict=True)}
    inputs = session_inputs(frames_from, bodies, model, edits, players if several else players[0], ramp_frames, ids,
                            correspondence, bool(refine_pose))
    return mirror_stream(inputs, run_dir, out_video, fps, side_by_side, kind, manifest, progress, total,
                         preview=run_dir / "live_latest.png" if live is not None else None, video_preset=video_preset)


# ---------------------------------------------------------------------------------------------- live mode

class _ExistingFiles(Mapping):
    """The files of a folder that a recorder is filling, looked up on disk (no checksums: nothing is final)."""

    def __init__(self, root: Path):
        self.root = root

    def __getitem__(self, rel: str):
        if (self.root / rel).is_file():
            return None
        raise KeyError(rel)

    def __contains__(self, rel) -> bool:
        return isinstance(rel, str) and (self.root / rel).is_file()

    def __iter__(self):
        return (p.relative_to(self.root).as_posix() for p in sorted(self.root.rglob("*")) if p.is_file())

    def __len__(self) -> int:
        return sum(1 for _ in iter(self))


class _ArrivedFrames:
    def __init__(self, root: Path):
        self.root = root

    def __contains__(self, frame) -> bool:
        from bodystudio.capture.session import stream_path

        return (self.root / stream_path("kinect_rgb", int(frame))).is_file()

    def __iter__(self):
        from bodystudio.fileio import is_frame_number

        return iter(sorted(int(p.stem) for p in (self.root / "kinect" / "rgb").glob("*.png")
                           if is_frame_number(p.stem)))


def live_session(folder: str | Path):
    """A folder being filled by a recorder (the session layout's ``kinect/`` streams, no manifest yet) opened
    as a session whose frames are read as they arrive."""
    from bodystudio.capture.session import KINECT_CALIBRATION, Session

    folder = Path(folder)
    if not folder.is_dir():
        if str(folder).isdigit() or str(folder).startswith("/dev/"):
            raise InputError(f"--live {folder}: reading a camera device needs a Kinect SDK bridge, which bodystudio "
                             "does not have; let the recorder write frames into a folder and pass that folder")
        raise InputError(f"--live {folder}: no such folder")
    if not (folder / KINECT_CALIBRATION).is_file():
        raise InputError(f"--live {folder}: no {KINECT_CALIBRATION}; the recorder must write the sensor calibration "
                         "first (the session layout's kinect/ folder)")
    manifest = {"files": _ExistingFiles(folder), "frames": _ArrivedFrames(folder), "cameras": [], "streams": [],
                "metadata": {}}
    return Session(folder, manifest)


#: ``--live``: a frame's file modified this recently may still be being written by the recorder (s).
LIVE_WRITE_SETTLE_S = 0.3


def read_arriving_frame(session, i: int, settle_s: float = LIVE_WRITE_SETTLE_S, poll_s: float = 0.02):
    """Frame ``i`` of a live folder (:func:`live_session`) as :func:`~bodystudio.mirror.frames.read_mirror_frame`
    reads it, read again while it fails and one of its files was modified within ``settle_s`` (the recorder is still
    writing it); once its files have been quiet that long the error stands (a damaged frame). Before, a colour PNG
    read half-written was "unreadable" and the previous frame's colour was shown in its place with a warning, though
    the frame was complete a moment later (adv5)."""
    from bodystudio.capture.session import stream_path
    from bodystudio.mirror.frames import read_mirror_frame

    root = Path(session.path)
    while True:
        try:
            return read_mirror_frame(session, i)
        except BodyStudioError:
            newest = 0.0
            for stream in ("kinect_rgb", "kinect_depth", "kinect_player", "kinect_joints"):
                try:
                    newest = max(newest, (root / stream_path(stream, i)).stat().st_mtime)
                except OSError:
                    continue
            if time.time() - newest > settle_s:
                raise
            time.sleep(poll_s)


def live_frame_ids(folder: str | Path, timeout_s: float = 5.0, poll_s: float = 0.02,
                   settle_s: float = 0.3) -> Iterator[int]:
    """Frame ids of a live folder in order, each once its colour, depth and player mask are there (and its
    joints, or the next frame has started, or ``settle_s`` passed); stops after ``timeout_s`` without a new frame."""
    from bodystudio.capture.session import stream_path

    folder = Path(folder)
    arrived = list(_ArrivedFrames(folder))
    i = arrived[0] if arrived else 0
    last = time.monotonic()
    while True:
        needed = [folder / stream_path(s, i) for s in ("kinect_rgb", "kinect_depth", "kinect_player")]
        if all(p.is_file() for p in needed):
            joints = (folder / stream_path("kinect_joints", i)).is_file()
            nxt = (folder / stream_path("kinect_rgb", i + 1)).is_file()
            if joints or nxt or time.time() - needed[0].stat().st_mtime > settle_s:
                yield i
                i += 1
                last = time.monotonic()
                continue
        later = _complete_later_frame(folder, i, settle_s)
        if later is not None:  # a recorder that dropped frame i goes on: do not stop (and drop the rest) there
            log.warning("live frame %d never arrived complete (frame %d did); skipped", i, later)
            i = later
            continue
        if time.monotonic() - last > timeout_s:
            return
        time.sleep(poll_s)


def _complete_later_frame(folder: Path, i: int, settle_s: float) -> int | None:
    """The first frame after ``i`` whose colour, depth and player mask are all there and whose colour is older
    than ``settle_s`` (so frame ``i`` had its time to arrive), else None."""
    from bodystudio.capture.session import stream_path

    for j in _ArrivedFrames(folder):
        if j <= i:
            continue
        needed = [folder / stream_path(s, j) for s in ("kinect_rgb", "kinect_depth", "kinect_player")]
        try:
            settled = time.time() - needed[0].stat().st_mtime > settle_s
        except OSError:
            return None
        return j if settled and all(p.is_file() for p in needed) else None
    return None
