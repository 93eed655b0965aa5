"""Render the new garment on the fitted actor, refine it in image space and composite it (§6-7 of Garment
Replacement in Monocular Video); ``bodystudio garment render`` and the composite half of ``eval garment``.

Per frame: the fitted body (a :class:`~bodystudio.garment.fitfile.GarmentFit`) is posed, dressed and
rendered as two layers with depth under the fit's lights (§6); the garment layer is warped by the optical
flow correction (§7.1) and the silhouette RBF warp (§7.2, Eq. 9), and composited by depth (§7.3).

``ground_truth_fit`` / ``perturbed_fit`` build an oracle fit from a synthetic session's ground truth (and
one with the errors of a real fit), so the refinement can be developed and measured without §4.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import Mp4Writer
from bodystudio.garment.garments import GARMENTS, PATTERNS

log = logging.getLogger(__name__)

RENDER_DIR = "render"
RENDER_JSON = "render.json"
RENDER_FORMAT = "bodystudio-garment-render"
STEPS = ("render", "flow", "rbf", "composite", "write")
#: The §7 refinement steps that can be switched off (ablations); ``hem``: the hem matte (ours, gar13e).
OPTIONS = ("flow", "rbf", "depth", "hem")


# ------------------------------------------------------------------------------------------ oracle fits

def ground_truth_fit(session, camera_name: str | None = None):
    """A :class:`GarmentFit` made of a synthetic garment session's ground truth (the oracle of §4).

    True shape, pose, lights and camera; the albedo is what §5.1 estimates, the colour the video shows at
    each vertex (the worn garment's where it covers the skin) divided by its true shading
    (:func:`observed_albedo`); vertices no frame sees keep ``gt/albedo.json``'s ``appearance``.
    """
    from bodystudio.capture.session import open_session
    from bodystudio.garment.fitfile import GarmentFit
    from bodystudio.garment.lighting import Lighting

    session = open_session(session) if isinstance(session, (str, os.PathLike)) else session
    subject, lighting = session.gt_subject, session.gt_lighting
    if subject is None or lighting is None or session.gt_garment is None:
        raise InputError(f"{session.path}: not a synthetic garment session (no gt/phenotype.json, gt/lighting.json "
                         "or gt/garment.json); make one with 'bodystudio synth garment'")
    camera_name = camera_name or session.camera_names[0]
    camera = session.cameras[camera_name]
    bone_names = tuple(subject["bone_names"])
    frame_ids = np.asarray(session.frame_ids, dtype=np.int64)
    rotations, translations, masks, images = [], [], [], []
    for fid in frame_ids:
        frame = session.frame(int(fid))
        pose = frame.gt_pose
        rotations.append(pose.rotations)
        translations.append(pose.translation)
        masks.append(frame.masks[camera_name])
        images.append(frame.images[camera_name])
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype
    from bodystudio.body.pose import Pose

    light = Lighting.from_dict(lighting, str(session.path))
    body = build_body(Phenotype.from_dict(subject["phenotype"]), subject["local"], resolution=subject["template"])
    posed = [body.pose(Pose(r, t))[0] for r, t in zip(rotations, translations, strict=True)]
    albedo = observed_albedo(images, posed, body.faces, camera, light, session.gt_appearance_albedo)
    masks = np.stack(masks)
    return GarmentFit(source=str(session.path), fps=float(session.metadata.get("fps", 30.0)), frame_ids=frame_ids,
                      camera=camera, template=str(subject["template"]), bone_names=bone_names,
                      phenotype=dict(subject["phenotype"]), local=dict(subject["local"]),
                      stature_m=float(subject["stature_m"]), rotations=np.stack(rotations),
                      translations=np.stack(translations),
                      silhouette_iou=body_silhouette_iou(body, np.stack(rotations), np.stack(translations), camera,
                                                         masks),
                      masks=masks, lighting=light, albedo=albedo,
                      warnings=("oracle fit: the session's ground truth",))


def body_silhouette_iou(body, rotations: np.ndarray, translations: np.ndarray, camera, masks: np.ndarray) -> np.ndarray:
    """(n,) IoU of the posed body's silhouette and the person mask per frame (the fit's quality measure)."""
    from bodystudio.body.pose import Pose
    from bodystudio.capture.render import render

    out = np.zeros(len(masks))
    for i, (r, t, mask) in enumerate(zip(rotations, translations, masks, strict=True)):
        V, _ = body.pose(Pose(r, t))
        sil = render(V, body.faces, camera).mask
        union = (sil | mask).sum()
        out[i] = (sil & mask).sum() / union if union else 0.0
    return out


def observed_albedo(frames: list[np.ndarray], posed_vertices: list[np.ndarray], F: np.ndarray, camera, lighting,
                    fallback: np.ndarray | None = None, min_cos: float = 0.05) -> np.ndarray:
    """§5.1's albedo with known lights: per vertex ``sum_t I S / sum_t S^2`` over the frames that see it
    (I its pixel colour, S its shading under ``lighting`` with self-shadowing); unseen vertices ``fallback``.
    ``min_cos`` is low: a vertex seen at a grazing angle (the lower belly from a camera at chest height)
    must still take the colour it shows there, or the flow of §7.1 matches a wrong hem."""
    from bodystudio.garment.lighting import vertex_shading, visible_vertex_colors

    n = len(posed_vertices[0])
    num, den = np.zeros((n, 3)), np.zeros((n, 3))
    seen_colors = visible_vertex_colors(frames, posed_vertices, F, camera, min_cos)
    for (ids, colors), V in zip(seen_colors, posed_vertices, strict=True):
        S = vertex_shading(V, F, lighting, camera, shadows=True)[ids]
        num[ids] += colors * S
        den[ids] += S * S
    seen = den.min(axis=1) > 1e-6
    albedo = np.tile(np.nanmean(num[seen] / den[seen], axis=0) if seen.any() else np.full(3, 0.5), (n, 1)) \
        if fallback is None else np.array(fallback, dtype=np.float64, copy=True)
    albedo[seen] = np.clip(num[seen] / den[seen], 0.0, 1.0)
    return albedo


def perturbed_fit(fit, seed: int = 0, pose_deg: float = 3.0, translation_m: float = 0.015, light_deg: float = 10.0):
    """``fit`` with the errors of a real monocular fit: every bone turned by ``pose_deg`` about a random axis,
    the root moved by ``translation_m`` in a random direction, each frame anew, and the lights turned by
    ``light_deg`` (once). The refinement of §7 has these to correct. ``silhouette_iou`` is measured anew:
    with the defaults it is 0.6-0.75, below :data:`~bodystudio.garment.fitfile.MIN_FRAME_IOU` (limbs are thin),
    so rendering it needs ``min_frame_iou=0`` (a harsher test than a fit that passes the gate)."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from bodystudio.garment.lighting import Lighting

    rng = np.random.default_rng([seed, 13, 7])
    n, B, _ = fit.rotations.shape

    def random_rotations(count: int, angle_rad: float):
        axes = rng.normal(size=(count, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        return Rotation.from_rotvec(axes * angle_rad)

    noise = random_rotations(n * B, np.radians(pose_deg))
    rotations = (noise * Rotation.from_rotvec(fit.rotations.reshape(-1, 3))).as_rotvec().reshape(n, B, 3)
    shift = rng.normal(size=(n, 3))
    translations = fit.translations + translation_m * shift / np.linalg.norm(shift, axis=1, keepdims=True)
    lighting = fit.lighting
    if lighting is not None:
        turn = random_rotations(1, np.radians(light_deg))
        lighting = Lighting(turn.apply(lighting.directions), lighting.colors, lighting.ambient)
    iou = body_silhouette_iou(fit.body(), rotations, translations, fit.camera, fit.masks)
    return replace(fit, rotations=rotations, translations=translations, lighting=lighting, silhouette_iou=iou,
                   warnings=(f"perturbed oracle fit: {pose_deg:g} deg per bone, {100 * translation_m:g} cm root, "
                             f"lights {light_deg:g} deg (seed {seed})",))


# ------------------------------------------------------------------------------------------ per frame

@dataclass(frozen=True, eq=False)
class RefinedFrame:
    """One composited frame: ``image`` uint8 RGB, ``garment_mask`` the garment pixels it shows, ``unrefined_mask``
    the garment pixels of the plain 3D composite, the warp ``field`` (H, W, 2) used and ms per step;
    ``flow_applied`` whether §7.1's correction was used (asked for, and then either arbitrated per pixel by the
    video or, without the hem matte, above what the flow resolves);
    ``hem_applied`` whether the hem matte was (asked for, and the worn garment's colour told apart from the rest of
    the actor's)."""

    image: np.ndarray
    garment_mask: np.ndarray
    unrefined_mask: np.ndarray
    field: np.ndarray
    timings_ms: dict
    flow_applied: bool = False
    hem_applied: bool = False


def refine_and_composite(frame: np.ndarray, person_mask: np.ndarray, layer, flow: bool = True, rbf: bool = True,
                         depth: bool = True, sigma_px: float | None = None, hem: bool = True) -> RefinedFrame:
    """§7 on one frame: flow correction (§7.1), silhouette RBF warp (§7.2-7.3, Eq. 9), depth compositing (§7.3),
    then the hem matte (ours: :func:`bodystudio.garment.refine.hem_matte`, the new garment's hem lines moved onto
    the worn garment's edges in the video, at most ``HEM_REACH_FRACTION`` of the frame height).

    With the flow on, the frame is warped, composited and matted twice, with §7.1's correction and without it
    (§7.2 alone), and where the two garment regions differ the video decides per pixel
    (:func:`bodystudio.garment.refine.arbitrate_flow_correction`: garment where the hem matte's colour model says
    the actor's worn garment is there); the garment's colours are the corrected warp's when the correction is
    larger than the flow resolves (:func:`bodystudio.garment.refine.flow_correction_is_significant`), else §7.2's
    alone (pixels only the other hypothesis shows take its colours). Where the matte does not run (``hem=False``,
    or the worn garment's colour is not told apart from the rest of the actor's, ``MAX_HEM_CLASSIFIER_ERROR``) the
    correction is used whole when it is that large, otherwise the frame is warped by §7.2 alone.

    ``layer`` is a :class:`bodystudio.garment.render.GarmentLayer` of the fitted body in this frame.
    """
    from bodystudio.garment import refine

    H, W = person_mask.shape
    timings = {}
    t0 = time.perf_counter()
    correction = None
    if flow:
        correction = refine.garment_motion_correction(frame, person_mask, layer.body_image, layer.body_mask,
                                                      layer.mask)
    t1 = time.perf_counter()
    zero = np.zeros((H, W, 2), dtype=np.float32)
    # with the flow, both hypotheses are warped and composited: the flow-corrected one and §7.2 alone; the video
    # decides between them per pixel (below), or, where its colours do not separate, the gate per frame
    main = _warp_and_matte(frame, person_mask, layer, zero if correction is None else correction, rbf, depth,
                           sigma_px, hem, timings, t1)
    flow_applied = False
    image, shown, field = main["image"], main["shown"], main["field"]
    if correction is not None:
        # timed as part of ``composite`` (the second hypothesis and the arbitration)
        plain = _warp_and_matte(frame, person_mask, layer, zero, rbf, depth, sigma_px, hem, timings, None)
        significant = refine.flow_correction_is_significant(correction, layer.mask)  # else the render's smear
        if main["worn"] is not None:
            # the region: the video decides where the two differ; the colours: the corrected warp's only where the
            # correction is larger than the flow resolves (below, the flow moves the texture by the albedo's smear)
            shown = refine.arbitrate_flow_correction(main["shown"], plain["shown"], main["worn"], person_mask)
            base, other = (main, plain) if significant else (plain, main)
            image, field = base["image"].copy(), base["field"]
            from_other = shown & ~base["shown"]
            image[from_other] = other["image"][from_other]
            dropped = base["shown"] & ~shown
            image[dropped] = frame[dropped]
            flow_applied = True
        elif significant:
            flow_applied = True
        else:
            image, shown, field = plain["image"], plain["shown"], plain["field"]
    hem_applied = main["worn"] is not None
    _, unrefined = refine.depth_composite(frame, layer.rgb, layer.mask, layer.depth, layer.body_depth, True)
    t3 = time.perf_counter()
    timings.update(flow=(t1 - t0) * 1e3, composite=(t3 - t0) * 1e3 - (t1 - t0) * 1e3 - timings.get("rbf", 0.0))
    return RefinedFrame(image, shown, unrefined, field, timings, flow_applied, hem_applied)


def _warp_and_matte(frame: np.ndarray, person_mask: np.ndarray, layer, field: np.ndarray, rbf: bool, depth: bool,
                    sigma_px: float | None, hem: bool, timings: dict, start: float | None) -> dict:
    """§7.2-7.3 and the hem matte on one frame after the backward warp ``field`` (§7.1's correction, or zeros):
    ``image``, ``shown`` (the composited garment region), ``field`` (with §7.2's warp concatenated) and ``worn``
    (the worn-garment probability the matte used; None when the matte was off or skipped). Adds the RBF time to
    ``timings['rbf']`` (from ``start``, a ``time.perf_counter()``; not timed when None)."""
    from bodystudio.garment import refine

    H, W = person_mask.shape
    if rbf:
        g_mask = refine.warp_image(layer.mask, field)
        b_mask = refine.warp_image(layer.body_mask, field)
        src, tgt = refine.match_silhouettes(refine.outer_silhouette(g_mask, b_mask), person_mask)
        kwargs = {} if sigma_px is None else {"sigma_px": sigma_px}
        silhouette = refine.silhouette_rbf_warp(tgt, src - tgt, (H, W), **kwargs)
        field = refine.concatenate_warps(field, silhouette)
    if start is not None:
        timings["rbf"] = timings.get("rbf", 0.0) + (time.perf_counter() - start) * 1e3
    g_rgb = refine.warp_image(layer.rgb, field)
    g_mask = refine.warp_image(layer.mask, field)
    g_depth = refine.warp_image(layer.depth, field, nearest=True)
    b_depth = refine.warp_image(layer.body_depth, field, nearest=True)
    image, shown = refine.depth_composite(frame, g_rgb, g_mask, g_depth, b_depth, use_depth=depth)
    worn = None
    if hem:
        reach_px = refine.HEM_REACH_FRACTION * H
        probability, error = refine.worn_garment_probability(frame, person_mask, shown, reach_px)
        if error <= refine.MAX_HEM_CLASSIFIER_ERROR:
            matte = refine.hem_matte(shown, probability, person_mask, reach_px)
            image = refine.composite_hem_matte(image, frame, matte, shown, g_rgb, g_mask)
            shown, worn = matte, probability
    return {"image": image, "shown": shown, "field": field, "worn": worn}


def default_lighting(camera):
    """Lights when the fit has none: one white light from the camera, ambient 0.3."""
    from bodystudio.garment.lighting import Lighting

    return Lighting.single(camera.center / np.linalg.norm(camera.center), 0.7, 0.3)


# ------------------------------------------------------------------------------------------ frames in

def _check_source_unchanged(fit, path, source, camera) -> None:
    """Refuse a fit's source that is no longer the recording it was fitted on (another clip or session at the
    same path): the garment would be composited onto frames it was not fitted to."""
    from bodystudio.garment.person import source_fingerprint

    expected = getattr(fit, "source_fingerprint", None)  # None: a fit from before it existed, or a stand-in
    if expected is None:
        return
    if source_fingerprint(source, fit.frame_ids, camera) != expected:
        raise InputError(f"{path}: not the recording the fit was made from (it changed since 'bodystudio garment "
                         f"fit'); restore it or rerun the fit")


def source_frames(fit, fit_dir: str | os.PathLike | None = None):
    """Yield the video frames (H, W, 3) uint8 RGB of ``fit.frame_ids`` from the fit's source: a session folder
    (its camera ``fit.camera.name`` or its only camera) or a video file (frame ids = frame numbers)."""
    source = Path(fit.source)
    if not source.is_absolute() and not source.exists() and fit_dir is not None:
        source = Path(fit_dir) / source
    if source.is_dir():
        from bodystudio.capture.session import open_session

        session = open_session(source)
        cam = fit.camera.name if fit.camera.name in session.camera_names else session.camera_names[0]
        _check_source_unchanged(fit, source, session, cam)
        for fid in fit.frame_ids:
            yield session.frame(int(fid)).images[cam]
        return
    if not source.is_file():
        raise InputError(f"{source}: the fit's source video or session is gone; restore it or rerun 'bodystudio "
                         "garment fit'")
    _check_source_unchanged(fit, source, source, None)
    import imageio_ffmpeg

    order = [int(f) for f in fit.frame_ids]
    # frames are decoded in stream order and handed out as soon as every earlier fitted frame has been:
    # an increasing frame list (the usual case) holds one frame at a time, not the whole video
    pending: dict[int, list[int]] = {}
    for k, fid in enumerate(order):
        pending.setdefault(fid, []).append(k)
    held: dict[int, np.ndarray] = {}
    next_k = 0
    fail = f"{source}: cannot read the video"
    try:
        from bodystudio.garment.person import VIDEO_READ_OPTIONS

        gen = imageio_ffmpeg.read_frames(str(source), output_params=list(VIDEO_READ_OPTIONS))
        meta = next(gen)
        w, h = meta["size"]
        for i, raw in enumerate(gen):
            if i in pending:
                frame = np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 3).copy()
                for k in pending.pop(i):
                    held[k] = frame
                while next_k in held:
                    yield held.pop(next_k)
                    next_k += 1
            if not pending:
                break
        gen.close()
    except (OSError, RuntimeError, StopIteration) as exc:
        raise FileFormatError(f"{fail} ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__}); "
                              "check the file") from None
    if pending:
        raise FileFormatError(f"{source}: frame {min(pending)} of the fit is missing from the video (it has "
                              f"fewer frames); rerun 'bodystudio garment fit'")


# ------------------------------------------------------------------------------------------ the video

def _png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image if image.ndim == 2 else image[..., ::-1],
                            [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise FileFormatError("cannot encode a PNG frame")
    return data.tobytes()


def check_render_options(garment: str, texture: str, out_video: str | os.PathLike | None, seed: int = 0) -> Path | None:
    """Refuse unknown garments/textures, a bad cloth seed and an unwritable or non-.mp4 ``out_video`` before any
    work."""
    from bodystudio.runfolder import check_output_destination

    if garment not in GARMENTS:
        raise InputError(f"--garment {garment!r}: valid: {', '.join(GARMENTS)}")
    if texture not in PATTERNS:
        raise InputError(f"--texture {texture!r}: valid: {', '.join(PATTERNS)}")
    if not (isinstance(seed, int) and 0 <= seed < 2**32):
        raise InputError(f"--seed {seed}: must be in [0, 2^32)")
    if out_video is None:
        return None
    out_video = Path(out_video)
    if out_video.suffix.lower() != ".mp4":
        raise InputError(f"--out {out_video}: the video must be an .mp4 file")
    check_output_destination(out_video, "video")
    return out_video


def render_garment_video(fit_dir: str | os.PathLike, garment: str = "tshirt", texture: str = "stripes",
                         out_video: str | os.PathLike | None = None, flow: bool = True, rbf: bool = True,
                         depth: bool = True, seed: int = 0, texture_size: int = 512, shadows: bool = True,
                         progress: bool = False, fit=None, command: str = "bodystudio garment render",
                         min_frame_iou: float | None = None, hem: bool = True) -> dict:
    """Dress the fitted body of ``fit_dir`` in ``garment`` with cloth ``texture``, render, refine (§7) and
    composite every frame; commit ``fit_dir/render/`` (render.json, frames/, garment_masks/) and ``out_video``
    as one unit. Returns render.json. ``fit`` overrides the fit read from ``fit_dir`` (oracle fits). Frames whose
    silhouette IoU is below ``min_frame_iou`` (default the fit's ``MIN_FRAME_IOU``) pass through unchanged
    (status in render.json)."""
    from bodystudio.capture.session import progress_bar
    from bodystudio.garment.fitfile import MIN_FRAME_IOU, load_garment_fit
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment_layer
    from bodystudio.runfolder import RunLayout, RunWriter

    fit_dir = Path(fit_dir)
    out_video = check_render_options(garment, texture, out_video, seed)
    if not 16 <= texture_size <= 4096:
        raise InputError(f"texture size {texture_size} must lie in [16, 4096]")
    if fit is None:
        fit = load_garment_fit(fit_dir)
    if out_video is not None:  # --out onto the clip itself would replace the input the fit was made from
        from bodystudio.fileio import check_not_an_input

        source = Path(fit.source)
        if not source.is_absolute() and not source.exists():
            source = fit_dir / source
        check_not_an_input(out_video, {"the fit's source video": source})
    render_dir = fit_dir / RENDER_DIR
    layout = RunLayout(render_dir, RENDER_JSON, ".", str(render_dir))
    t_start = time.perf_counter()
    body = fit.body()
    cloth = dress(body, garment, texture, texture_size, seed)
    lighting = fit.lighting if fit.lighting is not None else default_lighting(fit.camera)
    albedo = fit.albedo if fit.albedo is not None and len(fit.albedo) == body.n_vertices else None
    steps_ms: dict[str, list[float]] = {s: [] for s in STEPS}
    per_frame = []
    min_frame_iou = MIN_FRAME_IOU if min_frame_iou is None else float(min_frame_iou)
    fitted = fit.silhouette_iou >= min_frame_iou
    if not fitted.any():
        raise InputError(f"{fit_dir}: no frame of the fit matches the person's silhouette (IoU >= "
                         f"{min_frame_iou}); rerun 'bodystudio garment fit' (nothing to render)")
    H, W = fit.camera.height, fit.camera.width
    with RunWriter(layout, command, {"stage": "garment", "kind": "render"}) as w, progress_bar(progress) as bar:
        task = bar.add_task("garment render", total=len(fit.frame_ids))
        video = Mp4Writer(w.path_for(Path(out_video).absolute()), (W, H), fit.fps) if out_video is not None else None
        try:
            for i, (fid, frame) in enumerate(zip(fit.frame_ids, source_frames(fit, fit_dir), strict=True)):
                if frame.shape != (H, W, 3):
                    raise FileFormatError(f"{fit.source}: frame {int(fid)} is {frame.shape[1]}x{frame.shape[0]}, the "
                                          f"fit's camera {W}x{H}; rerun 'bodystudio garment fit'")
                t0 = time.perf_counter()
                if not fitted[i]:  # a frame the fit could not match: the video passes through unchanged
                    image, shown, ms, status = frame, np.zeros((H, W), dtype=bool), {}, "passed_through"
                    flow_applied = hem_applied = False
                    t2 = time.perf_counter()
                else:
                    pose = fit.pose(i)
                    V, _ = body.pose(pose)
                    layer = render_garment_layer(V, body.faces, cloth, pose_garment(cloth, body, pose), fit.camera,
                                                 lighting, albedo, shadows)
                    t1 = time.perf_counter()
                    result = refine_and_composite(frame, fit.masks[i], layer, flow, rbf, depth, hem=hem)
                    t2 = time.perf_counter()
                    image, shown, status = result.image, result.garment_mask, "ok"
                    flow_applied, hem_applied = result.flow_applied, result.hem_applied
                    ms = {"render": (t1 - t0) * 1e3, **result.timings_ms}
                w.write_bytes(f"frames/{int(fid):05d}.png", _png(image))
                w.write_bytes(f"garment_masks/{int(fid):05d}.png", _png(shown.astype(np.uint8) * 255))
                if video is not None:
                    video.write(image)
                ms["write"] = (time.perf_counter() - t2) * 1e3
                for k, v in ms.items():
                    steps_ms[k].append(v)
                # the flow gate's decision: options.flow says it was asked for, not that it was used
                per_frame.append({"frame": int(fid), "status": status, "garment_px": int(shown.sum()),
                                  "flow_applied": bool(flow_applied), "hem_applied": bool(hem_applied),
                                  "ms": {k: round(v, 2) for k, v in ms.items()}})
                bar.advance(task)
        finally:
            if video is not None:
                video.close()
        doc = {"format": RENDER_FORMAT, "version": 1, "fit": str(fit_dir), "garment": garment, "texture": texture,
               "seed": seed, "texture_size": texture_size,
               "options": {"flow": flow, "rbf": rbf, "depth": depth, "hem": hem, "shadows": shadows},
               "min_frame_iou": min_frame_iou,
               "video": None if out_video is None else str(out_video), "frame_ids": [int(f) for f in fit.frame_ids],
               "ms_per_frame": {k: round(float(np.median(v)), 2) for k, v in steps_ms.items() if v},
               "ms_per_frame_statistic": "median", "n_passed_through": int((~fitted).sum()),
               "n_flow_applied": sum(f["flow_applied"] for f in per_frame),
               "n_hem_applied": sum(f["hem_applied"] for f in per_frame),
               "wall_s": round(time.perf_counter() - t_start, 2),
               "frames": per_frame}
        return w.commit(doc)


# ------------------------------------------------------------------------------------------ evaluation

def load_render(fit_dir: str | os.PathLike) -> dict:
    """``fit_dir/render/render.json``, checked readable (no live writer, no interrupted commit) and, when it
    records its run (every render does), its frames and masks checked against it: before, a render folder
    holding a frame of another render (copied in, or edited) was shown and scored as this one."""
    from bodystudio.runfolder import RunLayout, check_readable, verify_run_files

    render_dir = Path(fit_dir) / RENDER_DIR
    layout = RunLayout(render_dir, RENDER_JSON, ".", str(render_dir))
    problem = check_readable(layout)
    if problem:
        raise FileFormatError(problem)
    path = render_dir / RENDER_JSON
    if not path.is_file():
        raise FileFormatError(f"{path}: not found; run 'bodystudio garment render {fit_dir} --out OUT.mp4' first")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"{path}: unreadable ({exc}); rerun 'bodystudio garment render'") from None
    if doc.get("format") != RENDER_FORMAT:
        raise FileFormatError(f"{path}: not a garment render; rerun 'bodystudio garment render'")
    block = doc.get("run")
    if isinstance(block, dict) and isinstance(block.get("files"), dict):  # the video beside it is not read here
        verify_run_files(layout, block, only=tuple(k for k in block["files"]
                                                   if not k.startswith("..") and not Path(k).is_absolute()))
    return doc


def ssim_map(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """Per-pixel SSIM (Wang et al. 2004; Gaussian window sigma 1.5, 8-bit constants), channels averaged."""
    a = a.astype(np.float64)
    b = b.astype(np.float64)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(x):
        return cv2.GaussianBlur(x, (0, 0), sigma)

    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a ** 2
    var_b = blur(b * b) - mu_b ** 2
    cov = blur(a * b) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
    return s.mean(axis=2) if s.ndim == 3 else s


def render_target_mismatch(render_doc: dict, gt_garment: dict | None) -> str | None:
    """Why a render cannot be scored against a session's ``gt/garment_target`` (None when it can): the
    render's garment, texture and cloth seed must be the session's target ones (``gt/garment.json``)."""
    if gt_garment is None:
        return "the session has no gt/garment.json (not a 'synth garment' session)"
    target = gt_garment.get("target", {})
    want = (target.get("name"), target.get("pattern"), target.get("seed"))
    got = (render_doc.get("garment"), render_doc.get("texture"), render_doc.get("seed"))
    if got != want:
        return (f"rendered {got[1]} {got[0]} with --seed {got[2]} but the session's target is {want[1]} {want[0]} "
                f"with seed {want[2]}; render with --garment {want[0]} --texture {want[1]} --seed {want[2]}")
    return None


def composite_errors(fit_dir: str | os.PathLike, session) -> dict:
    """Score ``fit_dir/render`` against a synthetic session's truth (issue 13's acceptance):
    ``garment_iou`` (composited garment region vs ``gt/garment_target_layers``), ``psnr_person`` and
    ``ssim_person`` (composite vs ``gt/garment_target`` inside the true person region), each the mean over
    frames, per-frame values and ``ms_per_frame`` by step (from render.json)."""
    from bodystudio.capture.session import LAYER_GARMENT, open_session

    session = open_session(session) if isinstance(session, (str, os.PathLike)) else session
    doc = load_render(fit_dir)
    render_dir = Path(fit_dir) / RENDER_DIR
    mismatch = render_target_mismatch(doc, session.gt_garment)
    if mismatch:  # the true render shows another garment or cloth: a score against it would be meaningless
        raise InputError(f"{render_dir}: {mismatch}; the session's truth cannot score this render")
    cam = session.camera_names[0]
    ious, psnrs, ssims = [], [], []
    for fid in doc["frame_ids"]:
        frame = session.frame(int(fid))
        labels = frame.gt_target_layers[cam]
        truth = frame.gt_target[cam]
        img = cv2.imread(str(render_dir / "frames" / f"{fid:05d}.png"), cv2.IMREAD_COLOR)
        mask = cv2.imread(str(render_dir / "garment_masks" / f"{fid:05d}.png"), cv2.IMREAD_GRAYSCALE)
        if img is None or mask is None or img.shape[:2] != labels.shape:
            raise FileFormatError(f"{render_dir}: frame {fid} is missing or damaged; rerun 'bodystudio garment render'")
        img = img[..., ::-1]
        shown = mask > 127
        true_garment = labels == LAYER_GARMENT
        union = (shown | true_garment).sum()
        ious.append(float((shown & true_garment).sum() / union) if union else 1.0)
        person = labels > 0
        err = (img[person].astype(np.float64) - truth[person].astype(np.float64)) ** 2
        mse = float(err.mean()) if person.any() else 0.0
        psnrs.append(float(10 * np.log10(255.0 ** 2 / mse)) if mse > 0 else float("inf"))
        ssims.append(float(ssim_map(img, truth)[person].mean()) if person.any() else 1.0)
    return {"garment_iou": float(np.mean(ious)), "psnr_person": float(np.mean(psnrs)),
            "ssim_person": float(np.mean(ssims)), "garment_iou_per_frame": [round(v, 4) for v in ious],
            "psnr_person_per_frame": [round(v, 2) for v in psnrs], "render_options": doc["options"],
            "render_ms_per_frame": doc["ms_per_frame"]}
