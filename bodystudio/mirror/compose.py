"""Output image composition, §5.5 of Real-time Reshaping of Humans: warped foreground over a background model.

The warped foreground is laid over the *unwarped* current frame. Where the person was but the warped
person no longer is (a shorter or thinner target), the hole is filled from a static background image
recorded first, while the scene is empty, and updated over time with the pixels that are background
with high confidence: farther than ``margin_px`` from the estimated foreground (§5.5). Pixels the
model has never seen (the person never moved away from them) are the only ones inpainted (OpenCV's
Telea), and counted, so a run can report how much of the output was invented.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from bodystudio.errors import InputError


@dataclass(frozen=True, eq=False)
class BackgroundModel:
    """The learnt empty scene: ``image`` (H, W, 3) uint8, ``valid`` (H, W) bool where it has been seen,
    ``frames`` how many frames contributed."""

    image: np.ndarray
    valid: np.ndarray
    frames: int = 0

    @property
    def coverage(self) -> float:
        """Fraction of the image the model has seen."""
        return float(self.valid.mean()) if self.valid.size else 0.0


def empty_background(shape: tuple[int, int]) -> BackgroundModel:
    """A background model that has seen nothing yet, for images of ``shape`` (H, W)."""
    H, W = int(shape[0]), int(shape[1])
    return BackgroundModel(np.zeros((H, W, 3), np.uint8), np.zeros((H, W), bool), 0)


def _check_image_and_mask(rgb, mask, what: str) -> tuple[np.ndarray, np.ndarray]:
    rgb = np.asarray(rgb)
    mask = np.asarray(mask)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise InputError(f"{what} needs an (H, W, 3) uint8 colour image, got {rgb.shape} {rgb.dtype}")
    if mask.shape != rgb.shape[:2]:
        raise InputError(f"{what}: mask {mask.shape} must match the colour image {rgb.shape[:2]}")
    return rgb, mask


def confident_background(fg_mask: np.ndarray, margin_px: int = 15) -> np.ndarray:
    """Pixels farther than ``margin_px`` (Chebyshev distance) from the foreground: background with high confidence."""
    m8 = np.asarray(fg_mask).astype(np.uint8)
    if margin_px <= 0:
        return m8 == 0
    k = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
    return cv2.dilate(m8, k) == 0


def update_background(model: BackgroundModel | None, rgb, fg_mask, margin_px: int = 15,
                      rate: float = 0.5, unverified=None) -> BackgroundModel:
    """Background model update of §5.5: confident background pixels replace the older ones.

    A pixel seen for the first time is copied; one seen before moves ``rate`` of the way to the new
    value (1 = plain replacement as in the paper; less averages out sensor noise). ``unverified``
    (H, W) bool marks pixels whose emptiness cannot be checked (outside the depth camera's view, where
    no player mask exists): they are learnt once, from the empty scene, and then kept. ``model`` None
    starts an empty one. Returns a new model; the old one is unchanged.
    """
    rgb, fg_mask = _check_image_and_mask(rgb, fg_mask, "update_background")
    if not 0.0 < rate <= 1.0:
        raise InputError(f"background update rate must lie in (0, 1], got {rate}")
    if model is None:
        model = empty_background(rgb.shape[:2])
    if model.image.shape != rgb.shape:
        raise InputError(f"background model {model.image.shape} does not match the frame {rgb.shape}")
    confident = confident_background(fg_mask, int(margin_px))
    if unverified is not None:
        unverified = np.asarray(unverified, dtype=bool)
        if unverified.shape != confident.shape:
            raise InputError(f"update_background: unverified mask {unverified.shape} must match the frame "
                             f"{confident.shape}")
        confident &= ~(unverified & model.valid)
    if rate >= 1.0 or not model.valid.any():
        new = rgb
    else:
        new = cv2.addWeighted(model.image, 1.0 - rate, rgb, rate, 0.0)
        if not model.valid.all():
            new = cv2.copyTo(rgb, (~model.valid).astype(np.uint8), new)  # first sighting: copied
    image = cv2.copyTo(new, confident.astype(np.uint8), model.image.copy())
    return BackgroundModel(image, model.valid | confident, model.frames + 1)


def compose(warped_rgb, warped_mask, background: BackgroundModel, rgb, fg_mask, hole_margin_px: int = 2,
            stats: dict | None = None) -> np.ndarray:
    """Output frame of §5.5: the warped foreground over the unwarped frame, holes filled from the background.

    ``warped_mask`` is the warped foreground's alpha (H, W) in [0, 1] (or bool); ``fg_mask`` the input
    frame's foreground. Where the input's foreground (grown by ``hole_margin_px``, so no rim of the old
    silhouette stays) is not covered by the warped person, the background model shows; pixels the model
    never saw are inpainted and counted in ``stats["inpainted_px"]`` (``stats["hole_px"]`` all holes).
    """
    rgb, fg_mask = _check_image_and_mask(rgb, fg_mask, "compose")
    warped_rgb, alpha = _check_image_and_mask(warped_rgb, warped_mask, "compose (warped foreground)")
    if background.image.shape != rgb.shape:
        raise InputError(f"background model {background.image.shape} does not match the frame {rgb.shape}")
    alpha = alpha.astype(np.float32)
    H, W = fg_mask.shape
    out = rgb.copy()
    # every pixel this touches lies in the box of the grown foreground and the covered pixels: work there (the
    # same frame bit for bit; two actors' frame 1.6 -> see docs/mirror.md, MIRFAST3)
    margin = max(int(hole_margin_px), 0)
    fx, fy, fw, fh = cv2.boundingRect(fg_mask.view(np.uint8) if fg_mask.dtype == bool else fg_mask.astype(np.uint8))
    covered = alpha > 0
    cx, cy, cw, ch = cv2.boundingRect(covered.view(np.uint8))
    boxes = [b for b in ((fx - margin, fy - margin, fx + fw + margin, fy + fh + margin) if fw else None,
                         (cx, cy, cx + cw, cy + ch) if cw else None) if b is not None]
    n_hole = n_unknown = 0
    if boxes:
        x0, y0 = max(min(b[0] for b in boxes), 0), max(min(b[1] for b in boxes), 0)
        x1, y1 = min(max(b[2] for b in boxes), W), min(max(b[3] for b in boxes), H)
        box = (slice(y0, y1), slice(x0, x1))
        m8 = fg_mask[box].astype(np.uint8)
        if hole_margin_px > 0:
            m8 = cv2.dilate(m8, np.ones((2 * hole_margin_px + 1,) * 2, np.uint8))
        hole = (m8 > 0) & (alpha[box] < 1.0)
        valid = background.valid[box]
        out[box] = cv2.copyTo(background.image[box], (hole & valid).astype(np.uint8), out[box])
        unknown = hole & ~valid
        n_hole, n_unknown = int(np.count_nonzero(hole)), int(np.count_nonzero(unknown))
        if n_unknown:
            full = np.zeros((H, W), np.uint8)
            full[box] = unknown
            out = cv2.inpaint(out, full, 3, cv2.INPAINT_TELEA)
    if stats is not None:
        stats["hole_px"] = n_hole
        stats["inpainted_px"] = n_unknown
    if cw:
        x, y, w, h = cx, cy, cw, ch
        roi = (slice(y, y + h), slice(x, x + w))
        # alpha 1 takes the warped colour as it is, alpha 0 leaves the frame: only the soft edge is blended (the
        # same float32 sums as blending the whole box, which two actors' box made 2 ms; MIRFAST2), in one numba pass
        # over the box (MIR12f: was a copy under a mask, and numpy's masks, nonzero and gathers for the edge)
        _blend_warped(out[roi], warped_rgb[roi], alpha[roi])
    return out


@njit(cache=True)
def _blend_warped(out, warped, alpha):
    """``out`` (h, w, 3) uint8, in place: ``warped`` where ``alpha >= 1``; where ``0 < alpha < 1``
    ``clip(warped a + out (1 - a) + 0.5, 0, 255)`` truncated to uint8, in float32 as numpy computed it."""
    h, w = alpha.shape
    one = np.float32(1.0)
    for r in range(h):
        for c in range(w):
            a = alpha[r, c]
            if a >= one:
                for ch in range(3):
                    out[r, c, ch] = warped[r, c, ch]
            elif a > 0:
                b = one - a
                for ch in range(3):
                    x = np.float32(warped[r, c, ch]) * a + np.float32(out[r, c, ch]) * b + np.float32(0.5)
                    out[r, c, ch] = np.uint8(min(max(x, np.float32(0.0)), np.float32(255.0)))
