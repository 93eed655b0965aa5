"""Image-based refinement of the rendered garment (§7 of Garment Replacement in Monocular Video).

The fitted body (§4) is close to the actor but not pixel-exact, so the rendered garment G is warped in
image space before it is composited:

* §7.1 garment motion correction: dense optical flow between the actor's frame and the fitted body
  rendered with the estimated albedo and lights, outlier removal with a small median filter, then an
  edge-aware domain-transform filter (Gastal & Oliveira 2011, ``cv2.ximgproc.dtFilter``) that fills
  and smooths the sparse field. The paper chains flow between keyframes of the video and of the render
  (Eq. 8); we have the rendered body of every frame, so the difference field D of Eq. 8 is measured
  directly, frame against render, with no drift to average out.
* §7.2 silhouette matching: the outer silhouette of the (flow-warped) garment is matched to the
  actor's silhouette, each garment point to the nearest point of the person mask's boundary (the
  paper's user picks the segments; here every garment-against-background pixel is a candidate).
* §7.3 warping (Eq. 9, an inverse-multiquadric RBF with a Gaussian falloff) and depth-based
  compositing: garment and body depth are warped with the same field and the actor's own pixels
  stay wherever the fitted body is in front of the garment (an arm across the chest).

All warps are *backward* maps ``(H, W, 2)`` of (dx, dy): output pixel p takes the source at p + field(p),
as ``cv2.remap`` wants.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from bodystudio.errors import InputError

#: §7.3: "sigma = 8.3" pixels of the Gaussian falloff of Eq. 9.
RBF_SIGMA_PX = 8.3
#: §7.1: the domain transform's spatial sigma as a fraction of the image height (80 px at 320, 160 px at 640;
#: measured on development subject 11 at 480x640: 40 px 0.908, 80 px 0.918, 160 px 0.923 garment IoU; at
#: 240x320 subject 4: 40 px 0.966, 80 px 0.966).
DT_SIGMA_SPATIAL_FRACTION = 0.25
#: §7.1: below this share of reliable flow around a pixel its correction fades towards 0.
SUPPORT = 1e-4
#: Silhouette points further than this from the actor's silhouette are not matched (a different part).
MAX_MATCH_PX = 24.0


def to_gray8(image: np.ndarray) -> np.ndarray:
    """uint8 grey of an RGB image given as uint8 or as float in [0, 1]."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        image = np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


#: Optical flow is computed on images of at most this height (then scaled up): a body's flow field is smooth,
#: and DIS's patches then cover the same part of the body at every video resolution.
FLOW_HEIGHT_PX = 320


def dense_optical_flow(source: np.ndarray, target: np.ndarray, preset: str = "medium",
                       max_height: int = FLOW_HEIGHT_PX) -> np.ndarray:
    """(H, W, 2) float32 flow with ``source(p) ~ target(p + flow(p))`` (OpenCV DIS, Kroeger et al. 2016).

    The paper uses the belief-propagation flow of Lipski et al.; DIS with variational refinement is what
    OpenCV offers that is dense, fast and handles the few-to-tens of pixels a fit is off by.
    """
    presets = {"fast": cv2.DISOPTICAL_FLOW_PRESET_FAST, "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
               "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST}
    dis = cv2.DISOpticalFlow_create(presets[preset])
    a, b = to_gray8(source), to_gray8(target)
    H, W = a.shape
    scale = min(1.0, max_height / H)
    if scale == 1.0:
        return dis.calc(a, b, None)
    size = (max(8, round(W * scale)), max(8, round(H * scale)))
    small = dis.calc(cv2.resize(a, size, interpolation=cv2.INTER_AREA),
                     cv2.resize(b, size, interpolation=cv2.INTER_AREA), None)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_LINEAR) * np.float32(W / size[0])


#: §7.1 gate: the correction is applied only when the 90th percentile of |D| over the garment exceeds this many
#: pixels at the flow's working resolution (:data:`FLOW_HEIGHT_PX`, i.e. 2 px of a 480x640 frame). Below it D is
#: the render's appearance mismatch, not motion: the fit's albedo was painted from this video through the fitted
#: pose, so the worn clothes' edges sit where the fit saw them and a well-posed frame leaves the flow nothing but
#: their smear. Measured with the real §4 fit at 480x640 (docs/garment.md, *The real fit's gap*): subject 37
#: (arm_flex, joints 3.2 px) has p90 |D| 1.3-2.2 px and the correction costs 0.008 garment IoU; subject 21
#: (walk, joints 7.5 px) 2.1-8.7 px and it earns 0.021.
MIN_FLOW_CORRECTION_PX = 1.0


def flow_correction_is_significant(field: np.ndarray, garment_mask: np.ndarray,
                                   min_px: float = MIN_FLOW_CORRECTION_PX, quantile: float = 90.0,
                                   max_height: int = FLOW_HEIGHT_PX) -> bool:
    """§7.1: is the motion correction ``field`` (H, W, 2) larger than the flow can resolve?

    True when the ``quantile`` of |field| over ``garment_mask`` exceeds ``min_px`` pixels of the image the flow
    is computed on (:func:`dense_optical_flow` at most ``max_height`` high); False for an empty garment.
    """
    if not garment_mask.any():
        return False
    scale = min(1.0, max_height / garment_mask.shape[0])
    magnitude = np.linalg.norm(field[garment_mask], axis=1) * scale
    return bool(np.percentile(magnitude, quantile) > min_px)


def median_outlier_removal(flow: np.ndarray, valid: np.ndarray, ksize: int = 5,
                           max_deviation_px: float = 2.0) -> np.ndarray:
    """§7.1: "we can safely apply an outlier removal to all D using a small median filter".

    Returns the bool (H, W) pixels of ``valid`` whose flow lies within ``max_deviation_px`` of its
    ``ksize`` x ``ksize`` median (OpenCV's float median takes 3 or 5).
    """
    med = np.dstack([cv2.medianBlur(np.ascontiguousarray(flow[..., k], dtype=np.float32), ksize) for k in range(2)])
    return valid & (np.linalg.norm(flow - med, axis=2) <= max_deviation_px)


def domain_transform_smoothing(field: np.ndarray, valid: np.ndarray, guide: np.ndarray,
                               sigma_spatial: float | None = None, sigma_color: float = 100.0,
                               min_support: float = SUPPORT) -> np.ndarray:
    """§7.1: interpolate and smooth a sparse field with the domain transform (Gastal & Oliveira 2011).

    Normalised convolution: ``dt(field * valid) / dt(valid)`` with ``cv2.ximgproc.dtFilter`` guided by
    ``guide`` (uint8 image), so the field spreads into the pixels without a value and stops at the
    guide's edges; ``sigma_spatial`` defaults to :data:`DT_SIGMA_SPATIAL_FRACTION` of the image height.
    Pixels that no valid pixel reaches get 0 (``dt(valid)`` below ``min_support``; raising
    it fades weakly supported pixels towards 0: measured on 6 frames at 480x640, 0.3 helped one frame and
    cost four others, mean garment IoU 0.908 -> 0.900).
    """
    guide = np.ascontiguousarray(guide)
    if sigma_spatial is None:
        sigma_spatial = DT_SIGMA_SPATIAL_FRACTION * guide.shape[0]
    w = valid.astype(np.float32)
    num = np.dstack([cv2.ximgproc.dtFilter(guide, np.ascontiguousarray(field[..., k] * w, dtype=np.float32),
                                           sigma_spatial, sigma_color, mode=cv2.ximgproc.DTF_NC, numIters=3)
                     for k in range(2)])
    den = cv2.ximgproc.dtFilter(guide, w, sigma_spatial, sigma_color, mode=cv2.ximgproc.DTF_NC, numIters=3)
    return num / np.maximum(den, min_support)[..., None]


def garment_motion_correction(frame: np.ndarray, person_mask: np.ndarray, body_image: np.ndarray,
                              body_mask: np.ndarray, garment_mask: np.ndarray | None = None, median_ksize: int = 5,
                              sigma_spatial: float | None = None, sigma_color: float = 100.0, max_fb_px: float = 1.5,
                              max_grey_diff: float = 24.0, reach_px: int = 15) -> np.ndarray:
    """§7.1 (Eq. 8's difference field D): backward warp (H, W, 2) that moves the render onto the actor.

    Flow from the actor's frame (masked by ``person_mask``, on black) to the fitted body rendered with the
    estimated albedo and lights (``body_image`` float in [0, 1], on black): the actor's pixel p is the
    render's p + D(p). As the paper discards unreliable trajectories, D is kept only where the actor is,
    the flow lands on the rendered body within ``reach_px`` of the garment (``garment_mask``, the region the
    warp moves), flow and backward flow agree within ``max_fb_px`` and the two grey values within
    ``max_grey_diff`` (cast shadows the render lacks); then the median test, then the domain transform
    guided by the frame fills and smooths it.
    """
    if frame.shape[:2] != body_mask.shape or person_mask.shape != body_mask.shape:
        raise InputError(f"frame {frame.shape[:2]}, person mask {person_mask.shape} and render {body_mask.shape} "
                         "must have the same size")
    actor = np.where(person_mask[..., None], frame, 0).astype(np.uint8)
    render = np.clip(np.round(np.where(body_mask[..., None], body_image, 0) * 255.0), 0, 255).astype(np.uint8)
    flow = dense_optical_flow(actor, render)
    back = dense_optical_flow(render, actor)
    H, W = body_mask.shape
    rows, cols = np.mgrid[0:H, 0:W]
    lr = np.clip(np.round(rows + flow[..., 1]), 0, H - 1).astype(np.int64)
    lc = np.clip(np.round(cols + flow[..., 0]), 0, W - 1).astype(np.int64)
    region = body_mask
    if garment_mask is not None:
        near = cv2.dilate(garment_mask.astype(np.uint8), cv2.getStructuringElement(
            cv2.MORPH_ELLIPSE, (2 * reach_px + 1, 2 * reach_px + 1))) > 0
        region = body_mask & near
    valid = person_mask & region[lr, lc]
    valid &= np.linalg.norm(flow + back[lr, lc], axis=2) <= max_fb_px
    valid &= np.abs(to_gray8(actor).astype(np.float32) - to_gray8(render)[lr, lc]) <= max_grey_diff
    valid = median_outlier_removal(flow, valid, median_ksize)
    return domain_transform_smoothing(flow, valid, frame, sigma_spatial, sigma_color)


def outer_silhouette(garment_mask: np.ndarray, body_mask: np.ndarray) -> np.ndarray:
    """(K, 2) float (x, y) garment pixels on the garment's silhouette against the background (§7.2's S_G):
    garment pixels with a 4-neighbour that is neither garment nor body (hems against skin are not silhouettes)."""
    covered = garment_mask | body_mask
    background = ~covered
    near_bg = ndimage.binary_dilation(background, structure=ndimage.generate_binary_structure(2, 1))
    ys, xs = np.nonzero(garment_mask & near_bg)
    return np.column_stack([xs, ys]).astype(np.float64)


def mask_boundary(mask: np.ndarray) -> np.ndarray:
    """bool (H, W): pixels of ``mask`` with a 4-neighbour outside it (the silhouette S_M of §7.2)."""
    return mask & ~ndimage.binary_erosion(mask, structure=ndimage.generate_binary_structure(2, 1), border_value=1)


def match_silhouettes(points: np.ndarray, person_mask: np.ndarray, max_match_px: float = MAX_MATCH_PX,
                      spacing_px: float = 2.0, neighbours: int = 9, max_deviation_px: float = 3.0
                      ) -> tuple[np.ndarray, np.ndarray]:
    """§7.2: pairs (sources (K, 2), targets (K, 2)) matching garment silhouette points to the actor's silhouette.

    Each garment point goes to the nearest boundary pixel of ``person_mask`` within ``max_match_px``;
    targets shared by several points keep their mean source; targets are thinned to one per
    ``spacing_px`` cell; a pair whose displacement differs from the median of its ``neighbours`` nearest
    pairs by more than ``max_deviation_px`` is dropped (silhouettes are smooth curves, as the paper's
    parametric matching assumes).
    """
    empty = np.zeros((0, 2)), np.zeros((0, 2))
    boundary = mask_boundary(person_mask)
    if len(points) == 0 or not boundary.any():
        return empty
    dist, (iy, ix) = ndimage.distance_transform_edt(~boundary, return_indices=True)
    px = points.astype(np.int64)
    d = dist[px[:, 1], px[:, 0]]
    keep = d <= max_match_px
    if not keep.any():
        return empty
    src = points[keep]
    tgt = np.column_stack([ix[px[keep, 1], px[keep, 0]], iy[px[keep, 1], px[keep, 0]]]).astype(np.float64)
    cell = np.floor(tgt / spacing_px).astype(np.int64)
    _, inverse, counts = np.unique(cell[:, 0] * 1_000_003 + cell[:, 1], return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    src_mean = np.zeros((len(counts), 2))
    tgt_mean = np.zeros((len(counts), 2))
    np.add.at(src_mean, inverse, src)
    np.add.at(tgt_mean, inverse, tgt)
    src, tgt = src_mean / counts[:, None], tgt_mean / counts[:, None]
    if len(tgt) > neighbours:
        disp = src - tgt
        _, nn = cKDTree(tgt).query(tgt, k=neighbours)
        med = np.median(disp[nn], axis=1)
        ok = np.linalg.norm(disp - med, axis=1) <= max_deviation_px
        src, tgt = src[ok], tgt[ok]
    return src, tgt


def inverse_multiquadric(r: np.ndarray) -> np.ndarray:
    """The kernel of Eq. 9, ``1 / sqrt(1 + r)`` (r in pixels); positive definite (Schoenberg: it is
    completely monotone in r^2), so the interpolation system below is solvable."""
    return 1.0 / np.sqrt(1.0 + r)


def silhouette_rbf_warp(targets: np.ndarray, displacements: np.ndarray, shape: tuple[int, int],
                        sigma_px: float = RBF_SIGMA_PX, chunk: int = 8192) -> np.ndarray:
    """Eq. 9 of Garment Replacement: the smooth warp field (H, W, 2) that moves silhouette points onto targets.

    ``w(p) = sum_i c_i phi(|p - t_i|) * exp(-1/2 |p - t_c|^2 / sigma^2)`` with phi the inverse multiquadric
    and t_c the nearest silhouette point. The paper normalises the kernel weights (a Shepard average),
    which leaves each silhouette point short of its target; we solve ``Phi c = w_s`` instead, so the
    field equals ``displacements`` exactly at ``targets``. The paper prints the falloff as
    ``|p - s_c| / sigma^2``; a Gaussian falloff (its words) needs the square, used here. The field is a
    backward map: the output pixel t_i takes the garment at ``t_i + displacements_i``.
    """
    H, W = shape
    field = np.zeros((H, W, 2), dtype=np.float32)
    if len(targets) == 0:
        return field
    targets = np.asarray(targets, dtype=np.float64)
    Phi = inverse_multiquadric(np.linalg.norm(targets[:, None] - targets[None], axis=2))
    coeffs = np.linalg.solve(Phi, np.asarray(displacements, dtype=np.float64))
    # the Gaussian falls below 1e-4 of the displacement beyond 4.3 sigma: evaluate in that band only
    boundary = np.zeros((H, W), dtype=bool)
    t = np.round(targets).astype(np.int64)
    boundary[np.clip(t[:, 1], 0, H - 1), np.clip(t[:, 0], 0, W - 1)] = True
    band = ndimage.distance_transform_edt(~boundary) <= 4.3 * sigma_px
    ys, xs = np.nonzero(band)
    P = np.column_stack([xs, ys]).astype(np.float64)
    t2 = (targets ** 2).sum(1)
    for a in range(0, len(P), chunk):
        p = P[a:a + chunk]
        d2 = np.maximum((p ** 2).sum(1)[:, None] + t2[None] - 2.0 * (p @ targets.T), 0.0)
        w = inverse_multiquadric(np.sqrt(d2)) @ coeffs
        falloff = np.exp(-0.5 * d2.min(axis=1) / sigma_px ** 2)  # |p - s_c|^2 to the nearest silhouette point
        field[ys[a:a + chunk], xs[a:a + chunk]] = w * falloff[:, None]
    return field


def concatenate_warps(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """§7.3: "this warp field is then concatenated with the warp field from ... Sect. 7.1".

    Backward maps: the result samples the source of ``first`` at p + second(p) + first(p + second(p)),
    i.e. ``first`` is applied to the image, then ``second`` to the result.
    """
    H, W = first.shape[:2]
    xs, ys = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    mx, my = xs + second[..., 0], ys + second[..., 1]
    inner = np.dstack([cv2.remap(np.ascontiguousarray(first[..., k]), mx, my, cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_REPLICATE) for k in range(2)])
    return second + inner


def warp_image(image: np.ndarray, field: np.ndarray, nearest: bool = False) -> np.ndarray:
    """``image`` (H, W[, C]) sampled at p + field(p) (0 outside); ``nearest`` for depth and labels."""
    H, W = field.shape[:2]
    xs, ys = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    mx = (xs + field[..., 0]).astype(np.float32)
    my = (ys + field[..., 1]).astype(np.float32)
    image = np.ascontiguousarray(image)
    is_mask = image.dtype == np.bool_
    src = image.astype(np.float32) if is_mask else image
    out = cv2.remap(src, mx, my, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out > 0.5 if is_mask else out


def depth_composite(frame: np.ndarray, garment_rgb: np.ndarray, garment_mask: np.ndarray, garment_depth: np.ndarray,
                    body_depth: np.ndarray, use_depth: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """§7.3 depth-based compositing: the garment replaces the actor's pixels except where the fitted body is
    in front of it (``body_depth < garment_depth``: an arm across the chest), which keep the actor.

    Returns the composite (H, W, 3) uint8 and the bool (H, W) garment pixels it shows. The actor's worn
    garment outside the new one is kept, as in the paper (which inpaints only loose parts, by hand).
    ``use_depth=False`` (ablation) lays the garment over everything.
    """
    show = garment_mask.copy()
    if use_depth:
        show &= ~((body_depth > 0) & (body_depth < garment_depth))
    out = frame.copy()
    out[show] = np.clip(np.round(garment_rgb[show] * 255.0), 0, 255).astype(np.uint8)
    return out, show


# ------------------------------------------------------------------------------------------ hem matting

#: The hem matte's reach: how far the new garment's hem lines may move to the worn garment's edges measured in the
#: video, as a fraction of the frame height (8 px at 480 px high, 10.7 px at 640; measured on the kept fits of
#: subjects 37 / 21 / 3 at 640 px high: 8 px gave 0.990 / 0.986 / 0.991, 10.7 px 0.992 / 0.992 / 0.996).
HEM_REACH_FRACTION = 1.0 / 60.0
#: Hem matting is skipped when the worn garment's colour and the rest of the actor's are not this separable
#: (balanced error of the colour model on held-out pixels, see ``worn_garment_probability``): a shirt the colour of
#: the skin. The benchmark's frames measure 0.000-0.015.
MAX_HEM_CLASSIFIER_ERROR = 0.12
#: Bins of the colour histograms: chromaticity r and g, brightness.
_HEM_BINS = (32, 32, 8)


def _colour_features(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) histogram bin coordinates of each pixel: chromaticity ``(r, g) / (r + g + b)`` (what shading leaves
    alone, §5.1's assumption) and the brightness."""
    rgb = frame.astype(np.float64)
    total = rgb.sum(axis=2)
    chroma = rgb[..., :2] / np.maximum(total, 1.0)[..., None]
    bright = total / (3.0 * 255.0)
    feats = np.dstack([chroma[..., 0], chroma[..., 1], bright])
    bins = np.asarray(_HEM_BINS)
    return np.clip((feats * bins).astype(np.int64), 0, bins - 1)


def worn_garment_probability(frame: np.ndarray, person_mask: np.ndarray, garment_shown: np.ndarray,
                             margin_px: float) -> tuple[np.ndarray, float]:
    """The probability that each pixel of the video shows the actor's worn garment, and the classifier's error.

    The matte of §7.2's actor silhouettes M, for the worn garment instead of the whole person: a colour model
    (histograms of chromaticity and brightness, Bayes with equal priors) trained on the frame itself, the worn
    garment's pixels being the person's pixels inside the new garment's composited region eroded by
    ``margin_px``, the rest of the actor's those outside it dilated by ``margin_px`` (skin, hair, other clothes).
    The error is the balanced error on half of those pixels of a model built from the other half (0 separable,
    0.5 not at all); 0.5 when either side has too few pixels.
    """
    structure = ndimage.generate_binary_structure(2, 1)
    steps = max(1, int(round(margin_px)))
    inside = person_mask & ndimage.binary_erosion(garment_shown, structure, iterations=steps)
    outside = person_mask & ~ndimage.binary_dilation(garment_shown, structure, iterations=steps)
    prob = np.zeros(person_mask.shape, dtype=np.float64)
    if inside.sum() < 50 or outside.sum() < 50:
        return prob, 0.5
    bins = _colour_features(frame)
    flat = np.ravel_multi_index((bins[..., 0], bins[..., 1], bins[..., 2]), _HEM_BINS)

    def posterior(half: np.ndarray) -> np.ndarray:
        size = int(np.prod(_HEM_BINS))
        densities = []
        for side in (inside & half, outside & half):
            hist = np.bincount(flat[side], minlength=size).reshape(_HEM_BINS).astype(np.float64)
            # smoothed: noise and shading spread a plain colour over neighbouring bins
            densities.append(ndimage.gaussian_filter(hist, 1.0) / max(int(side.sum()), 1))
        return (densities[0] / np.maximum(densities[0] + densities[1], 1e-12)).ravel()

    # the error is measured on the pixels the model was not built from (a checkerboard of 8 px blocks: neighbouring
    # pixels look alike): with few pixels the histograms would separate any two sets they were built from
    ys, xs = np.indices(person_mask.shape)
    even = (ys // 8 + xs // 8) % 2 == 0
    held_out = posterior(even)[flat]
    error = 0.5 * (float((held_out[inside & ~even] < 0.5).mean()) + float((held_out[outside & ~even] >= 0.5).mean()))
    prob = posterior(np.ones_like(even))[flat]
    prob[~person_mask] = 0.0
    return prob, error


def hem_matte(garment_shown: np.ndarray, worn_probability: np.ndarray, person_mask: np.ndarray,
              reach_px: float) -> np.ndarray:
    """The new garment's hem lines moved onto the worn garment's edges (our extension of §7.2's silhouette matching
    to the lines inside the actor's silhouette: sleeve ends, neckline, waist hem).

    Within ``reach_px`` of the composited garment's boundary inside the person (hems, and occlusion edges such
    as an arm in front of the shirt) each pixel is garment where the video shows the worn garment
    (``worn_probability`` > 0.5 after a 5x5 median): the band is re-segmented by the video. A garment pixel is
    given up only where the worn garment's edge is within ``reach_px`` (a new garment longer than the worn one,
    over bare skin, keeps its hem: there is no worn edge near it), and added only where a pixel of the actor that is
    not the worn garment is within ``reach_px`` (a new garment shorter than the worn one is not lengthened along
    it). Outside the band the composite is unchanged,
    so the snap moves a hem by at most ``reach_px``. Returns the new bool (H, W) garment region.
    """
    worn = cv2.medianBlur((worn_probability > 0.5).astype(np.uint8) * 255, 5) > 0
    worn &= person_mask
    inner = person_mask & ~garment_shown
    if not inner.any() or not garment_shown.any():
        return garment_shown.copy()
    near_shown = ndimage.distance_transform_edt(~garment_shown) <= reach_px
    near_inner = ndimage.distance_transform_edt(~inner) <= reach_px
    near_worn = ndimage.distance_transform_edt(~worn) <= reach_px if worn.any() else np.zeros_like(worn)
    # an added pixel needs the worn garment's edge near it too: a new garment shorter than the worn one keeps its
    # hem where the worn garment goes on beyond the reach
    not_worn = person_mask & ~worn
    near_not_worn = ndimage.distance_transform_edt(~not_worn) <= reach_px if not_worn.any() else np.zeros_like(worn)
    out = garment_shown.copy()
    out[inner & near_shown & worn & near_not_worn] = True
    out[garment_shown & near_inner & ~worn & near_worn] = False
    return out


def composite_hem_matte(composite: np.ndarray, frame: np.ndarray, matte: np.ndarray, garment_shown: np.ndarray,
                        garment_rgb: np.ndarray, garment_mask: np.ndarray) -> np.ndarray:
    """The composite with the garment region of :func:`hem_matte`: pixels it gives up show the actor again (the
    frame), pixels it adds take the warped garment's colour there, or where the garment layer does not reach, the
    nearest garment pixel's (a band of at most the reach)."""
    out = composite.copy()
    removed = garment_shown & ~matte
    out[removed] = frame[removed]
    added = matte & ~garment_shown
    if added.any() and garment_mask.any():  # hem_matte adds only next to shown garment, which the layer covers
        _, (iy, ix) = ndimage.distance_transform_edt(~garment_mask, return_indices=True)
        ys, xs = np.nonzero(added)
        colour = garment_rgb[iy[ys, xs], ix[ys, xs]]
        out[ys, xs] = np.clip(np.round(colour * 255.0), 0, 255).astype(np.uint8)
    return out


def arbitrate_flow_correction(corrected: np.ndarray, uncorrected: np.ndarray, worn_probability: np.ndarray,
                              person_mask: np.ndarray) -> np.ndarray:
    """§7.1's correction accepted per pixel where the video confirms it (ours, gar13f): the garment region of the
    flow-corrected composite (``corrected``, after §7.2, §7.3 and the hem matte) and of the one without the
    correction (``uncorrected``) agree almost everywhere; where they differ, a pixel is garment when the video shows
    the actor's worn garment there (``worn_probability`` > 0.5, :func:`worn_garment_probability`, inside
    ``person_mask``), else not. The flow's move of the garment region is kept where it moves it toward the worn
    garment's pixels and undone where it moves it away (onto the background or the actor's skin); the Eq. 8 field
    itself still carries the texture.

    Returns the bool (H, W) garment region.
    """
    worn = (worn_probability > 0.5) & person_mask
    return (corrected & uncorrected) | ((corrected ^ uncorrected) & worn)

