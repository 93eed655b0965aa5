"""Silhouettes by colour-based background segmentation (Rapid Skin Sec. V.A).

Rapid Skin obtains "silhouettes of the user ... through color-based background segmentation". We use
the statistical background model of Horprasert, Harwood and Davis (1999, "A statistical approach for
real-time robust background subtraction and shadow detection"): each pixel has a mean colour E and a
per-channel standard deviation s learnt from empty-studio frames; an image pixel I is compared with
its *brightness distortion* alpha (the scale of E closest to I) and its *chromaticity distortion* CD
(the distance of I from the line through E), both in units of s. Shadows and highlights change
alpha but not CD, so they stay background. The raw foreground is then cleaned with morphology and
connected components (the subject is the largest component, optionally with big companions).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bodystudio.errors import InputError, SessionError

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class BackgroundModel:
    """Per-pixel background statistics of one camera (Horprasert et al. 1999, Sec. 4.1).

    ``mean`` and ``std`` are (H, W, 3) float32 in grey levels; ``alpha_rms`` and ``cd_rms`` are the
    camera's RMS brightness and chromaticity distortions over the training frames (the paper's a and
    b, pooled over the image because a handful of frames cannot estimate them per pixel).
    """

    mean: np.ndarray
    std: np.ndarray
    alpha_rms: float
    cd_rms: float
    n_frames: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.mean.shape[:2]


@dataclass(frozen=True)
class SegmentationParams:
    """Thresholds of :func:`segment_silhouette`.

    ``tau_cd``: normalised chromaticity distortion above which a pixel is foreground.
    ``tau_brightness``: normalised brightness distortion beyond which a same-chromaticity pixel is
    foreground (|alpha - 1| / alpha_rms); ``shadow_floor`` / ``highlight_ceiling``: brightness ratios
    that shadows / highlights never pass (darker or brighter pixels are foreground whatever the CD).
    """

    tau_cd: float = 4.0
    tau_brightness: float = 6.0
    shadow_floor: float = 0.45
    highlight_ceiling: float = 1.6
    shadows_are_background: bool = True
    std_floor: float = 1.0
    single_frame_std: float = 3.0
    close_px: int = 0
    open_px: int = 0
    min_component_fraction: float = 0.1
    min_component_px: int = 50
    max_hole_fraction: float = 0.0001

    def __post_init__(self):
        for name, lo, hi in (("tau_cd", 0.1, 100.0), ("tau_brightness", 0.1, 100.0), ("shadow_floor", 0.0, 1.0),
                             ("highlight_ceiling", 1.0, 10.0), ("std_floor", 0.0, 50.0),
                             ("single_frame_std", 0.0, 50.0), ("close_px", 0, 100), ("open_px", 0, 100),
                             ("min_component_fraction", 0.0, 1.0), ("min_component_px", 0, 10**6),
                             ("max_hole_fraction", 0.0, 1.0)):
            value = getattr(self, name)
            if not np.isfinite(value) or not lo <= value <= hi:
                flag = {"tau_cd": "--tau-cd", "close_px": "--close", "open_px": "--open"}.get(name, name)
                raise InputError(f"{flag} {value:g} is out of range; use a value in [{lo:g}, {hi:g}]")


def background_model(frames: list[np.ndarray], std_floor: float = 1.0,
                     single_frame_std: float = 3.0) -> BackgroundModel:
    """Learn the background statistics of one camera from empty-studio RGB frames (Horprasert Sec. 4.1).

    The per-pixel std is floored by the camera's median std (so a pixel whose few samples happened to
    agree does not become hypersensitive) and by ``std_floor``; a single frame uses ``single_frame_std``.
    """
    if not frames:
        raise ValueError("background_model needs at least one empty frame")
    stack = np.stack([np.asarray(f, dtype=np.float32) for f in frames])
    mean = stack.mean(0)
    if len(frames) > 1:
        std = stack.std(0, ddof=1)
        std = np.maximum(std, max(float(np.median(std)), std_floor))
    else:
        std = np.full_like(mean, single_frame_std)
    model = BackgroundModel(mean, std.astype(np.float32), 1.0, 1.0, len(frames))
    if len(frames) > 1:
        alphas, cds = zip(*(brightness_chromaticity_distortion(f, model) for f in frames), strict=True)
        alpha_rms = float(np.sqrt(np.mean((np.stack(alphas) - 1.0) ** 2)))
        cd_rms = float(np.sqrt(np.mean(np.stack(cds) ** 2)))
    else:
        # Expected values for pure sensor noise of std s: CD ~ chi with 2 dof, alpha - 1 ~ s / |E|.
        cd_rms = float(np.sqrt(2.0))
        alpha_rms = float(np.median(np.sqrt(1.0 / np.maximum(((mean / std) ** 2).sum(-1), 1e-6))))
    # Compressed or denoised footage varies less over time than between frames with and without the
    # subject; a floor on b keeps the classifier from becoming overconfident (unit = one model std).
    return BackgroundModel(mean, std.astype(np.float32), max(alpha_rms, 1e-3), max(cd_rms, 1.0), len(frames))


def brightness_chromaticity_distortion(image: np.ndarray, model: BackgroundModel) -> tuple[np.ndarray, np.ndarray]:
    """Brightness distortion alpha and chromaticity distortion CD per pixel, Eqs. 4-5 of Horprasert et al.

    alpha = sum_c (I_c E_c / s_c^2) / sum_c (E_c / s_c)^2,  CD = sqrt(sum_c ((I_c - alpha E_c) / s_c)^2).
    """
    I = np.asarray(image, dtype=np.float32)
    if I.shape != model.mean.shape:
        raise ValueError(f"image is {I.shape[1]}x{I.shape[0]} but the background model is "
                         f"{model.mean.shape[1]}x{model.mean.shape[0]}")
    E, s = model.mean, model.std
    Es = E / s
    alpha = (I * E / (s * s)).sum(-1) / np.maximum((Es * Es).sum(-1), 1e-6)
    cd = np.sqrt((((I - alpha[..., None] * E) / s) ** 2).sum(-1))
    return alpha, cd


def foreground_pixels(image: np.ndarray, model: BackgroundModel,
                      params: SegmentationParams = SegmentationParams()) -> np.ndarray:
    """Raw per-pixel foreground (H, W) bool: Horprasert's classification with shadows as background.

    A pixel is foreground when its normalised CD exceeds ``tau_cd``, or it is darker than a shadow
    can make it (alpha < shadow_floor) or brighter than a highlight (alpha > highlight_ceiling). With
    ``shadows_are_background=False`` any brightness change beyond ``tau_brightness`` counts too.
    """
    alpha, cd = brightness_chromaticity_distortion(image, model)
    fg = (cd / model.cd_rms > params.tau_cd) | (alpha < params.shadow_floor) | (alpha > params.highlight_ceiling)
    if not params.shadows_are_background:
        fg |= np.abs(alpha - 1.0) / model.alpha_rms > params.tau_brightness
    return fg


def clean_mask(mask: np.ndarray, params: SegmentationParams = SegmentationParams()) -> np.ndarray:
    """Morphological clean-up: optional opening, closing, keep the large components, fill small holes."""
    m = np.asarray(mask, dtype=np.uint8)
    if params.open_px > 1:
        m = morphology(m, params.open_px, close=False)
    if params.close_px > 1:
        m = morphology(m, params.close_px, close=True)
    m = largest_components(m > 0, params.min_component_fraction, params.min_component_px)
    return fill_small_holes(m, params.max_hole_fraction * m.size)


def morphology(mask: np.ndarray, size: int, close: bool) -> np.ndarray:
    """Closing (``close``) or opening of a uint8 mask by a ``size`` x ``size`` ellipse, without a shift.

    OpenCV's ``morphologyEx`` applies both passes with the same kernel and anchor; for an even ``size`` the
    anchor is off-centre and the result moves by one pixel (a 2 px closing moved a matte down-right by one pixel
    and lost a corner). The second pass here uses the reflected kernel with the reflected anchor, which is the
    textbook closing/opening (extensive/anti-extensive, no shift) and equals ``morphologyEx`` for odd sizes.
    """
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    a, ra = size // 2, size - 1 - size // 2
    first, second = (cv2.dilate, cv2.erode) if close else (cv2.erode, cv2.dilate)
    return second(first(mask, k, anchor=(a, a)), np.ascontiguousarray(k[::-1, ::-1]), anchor=(ra, ra))


def largest_components(mask: np.ndarray, min_fraction: float = 0.1, min_px: int = 50) -> np.ndarray:
    """The largest 8-connected component plus any others at least ``min_fraction`` of its area."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero((areas >= min_fraction * areas.max()) & (areas >= min_px)) + 1
    return np.isin(labels, keep)


def fill_small_holes(mask: np.ndarray, max_hole_px: float) -> np.ndarray:
    """Fill background regions enclosed by the mask that are smaller than ``max_hole_px`` pixels.

    Bigger enclosed regions (the gap between an arm and the torso) are real background and stay.
    """
    inverse = (~mask).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(inverse, connectivity=4)
    H, W = mask.shape
    out = mask.copy()
    for k in range(1, n):
        x, y, w, h, area = stats[k]
        touches_border = x == 0 or y == 0 or x + w == W or y + h == H
        if not touches_border and area <= max_hole_px:
            out[labels == k] = True
    return out


def segment_silhouette(image: np.ndarray, model: BackgroundModel,
                       params: SegmentationParams = SegmentationParams()) -> np.ndarray:
    """Silhouette (H, W) bool of the subject in ``image`` against the background ``model``."""
    return clean_mask(foreground_pixels(image, model, params), params)


def mask_iou(mask: np.ndarray, reference: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = np.asarray(mask, bool), np.asarray(reference, bool)
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


@dataclass(frozen=True)
class SilhouetteReport:
    """What ``segment_session`` did: masks written and, for synthetic sessions, IoU against ground truth."""

    n_masks: int
    iou_mean: float | None
    iou_min: float | None
    iou_per_camera: dict

    def to_dict(self) -> dict:
        return {"n_masks": self.n_masks, "iou_mean": self.iou_mean, "iou_min": self.iou_min,
                "iou_per_camera": self.iou_per_camera}


def silhouette_scores(session) -> SilhouetteReport:
    """IoU of a session's current masks (``cam_NN/mask``) against its ground-truth masks (``gt/masks``)."""
    if "gt_mask" not in session.streams:
        raise SessionError(f"{session.path / 'session.json'}: no ground-truth masks to score against "
                           "(only synthetic sessions have gt/masks)")
    ious: dict[str, list[float]] = {c: [] for c in session.camera_names}
    n = 0
    for frame in session:
        for cam in frame.gt_masks:
            if cam in frame.masks:
                ious[cam].append(mask_iou(frame.masks[cam], frame.gt_masks[cam]))
                n += 1
    return _report(n, ious)


def _report(n: int, ious: dict[str, list[float]]) -> SilhouetteReport:
    per_camera = {c: float(np.mean(v)) for c, v in ious.items() if v}
    all_ious = [x for v in ious.values() for x in v]
    return SilhouetteReport(n, float(np.mean(all_ious)) if all_ious else None,
                            float(np.min(all_ious)) if all_ious else None, per_camera)


def session_background_models(session, params: SegmentationParams = SegmentationParams()) -> dict[str, BackgroundModel]:
    """One background model per camera from the session's ``cam_NN/background/`` frames."""
    models = {}
    for cam in session.camera_names:
        frames = session.background_frames(cam)
        if not frames:
            raise SessionError(f"{session.path / cam / 'background'}: no empty-studio frames for camera {cam}; "
                               "record a few frames without the subject (import them with --backgrounds)")
        models[cam] = background_model(frames, params.std_floor, params.single_frame_std)
    return models


def segment_session(path: str | os.PathLike, params: SegmentationParams = SegmentationParams(),
                    progress: bool = False) -> SilhouetteReport:
    """Segment every RGB frame of a session and write the masks (``cam_NN/mask/``), updating the manifest.

    The update is atomic as a whole: masks are staged and committed with the new manifest at the end.
    Ground-truth masks (``gt/masks``) of synthetic sessions are untouched and give the reported IoU.
    """
    from bodystudio.capture.session import SessionWriter, open_session, progress_bar

    session = open_session(Path(path))
    if "rgb" not in session.streams:
        raise SessionError(f"{session.path / 'session.json'}: the session has no RGB frames to segment")
    models = session_background_models(session, params)
    ious: dict[str, list[float]] = {c: [] for c in session.camera_names}
    n = 0
    with progress_bar(progress) as bar:
        task = bar.add_task("silhouettes", total=len(session))
        with SessionWriter(session.path, update=True, metadata={"masks": "segmented (Horprasert)"},
                           command="bodystudio capture silhouettes") as writer:
            for frame in session:
                for cam, image in ((c, frame.images[c]) for c in frame.images):
                    if image.shape != models[cam].mean.shape:
                        raise SessionError(f"{session.path / cam / 'rgb'}: frame {frame.frame_id} is "
                                           f"{image.shape[1]}x{image.shape[0]} but the background frames are "
                                           f"{models[cam].mean.shape[1]}x{models[cam].mean.shape[0]}")
                    mask = segment_silhouette(image, models[cam], params)
                    writer.write_mask(cam, frame.frame_id, mask)
                    n += 1
                    if cam in frame.gt_masks:
                        ious[cam].append(mask_iou(mask, frame.gt_masks[cam]))
                bar.advance(task)
    report = _report(n, ious)
    log.info("segmented %d masks in %s (IoU mean %s)", n, session.path, report.iou_mean)
    return report
