"""Rendered source/target frames with ground truth for testing and benchmarking the image steps (§5.3-§5.5).

Independent of a mirror session and of the body fit: a subject is projected into the statistical model,
edited (Eq. 4 via ``StatisticalBodyModel.edit``), both bodies are posed with one pose of a motion and
rendered over a textured background plate into the Kinect v1 colour camera (640x480). The player mask
imitates the SDK's: the true silhouette sampled on the coarser depth grid, shifted by a registration
offset of a pixel or two and with random pixels along its boundary flipped (jitter at the edges, §5.3).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from bodystudio.errors import InputError

#: Depth (m) given to the background plate in the simulated colour-registered depth image.
BACKGROUND_DEPTH_M = 4.5


@dataclass(frozen=True, eq=False)
class ImageCase:
    """One frame of a mirror with its ground truth (all images 640x480 in the colour camera)."""

    rgb: np.ndarray  # (H, W, 3) uint8 input frame (source body over the background)
    target_rgb: np.ndarray  # (H, W, 3) uint8 the same frame with the target body (what the mirror should show)
    background: np.ndarray  # (H, W, 3) uint8 the empty scene
    true_mask: np.ndarray  # (H, W) bool source person
    target_mask: np.ndarray  # (H, W) bool target person
    player_mask: np.ndarray  # (H, W) bool SDK-like jittered player mask in colour
    depth_color: np.ndarray  # (H, W) float64 metres, 0 = no measurement
    src_uv: np.ndarray  # (m, 2) projected visible source vertices
    dst_uv: np.ndarray  # (m, 2) the same vertices of the target body
    source_vertices: np.ndarray  # (n, 3) posed
    target_vertices: np.ndarray  # (n, 3) posed
    faces: np.ndarray
    camera: object
    actors: int = 1
    pair_groups: np.ndarray | None = None  # (m,) actor of each vertex pair
    dense: object | None = None  # warp.DenseCorrespondence of the true bodies (all actors, one z-buffer)


def sdk_player_mask(mask: np.ndarray, depth_m: np.ndarray, rng: np.random.Generator, depth_scale: int = 2,
                    flip_rate: float = 0.35, shift_px: float = 1.5, hole_rate: float = 0.02
                    ) -> tuple[np.ndarray, np.ndarray]:
    """An SDK-like player mask and colour-registered depth from the true ones (both (H, W)).

    Both are sampled on a grid ``depth_scale`` times coarser (the depth camera), the mask's boundary
    pixels flipped at ``flip_rate``, both shifted by the same random offset of up to ``shift_px``
    (depth-to-colour registration error) and brought back to full size; ``hole_rate`` of the depth
    pixels read 0 (no measurement).
    """
    H, W = mask.shape
    size = (W // depth_scale, H // depth_scale)
    small = cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST)
    small_depth = cv2.resize(depth_m.astype(np.float32), size, interpolation=cv2.INTER_NEAREST)
    kernel = np.ones((3, 3), np.uint8)
    boundary = (cv2.dilate(small, kernel) != cv2.erode(small, kernel))
    flip = boundary & (rng.random(small.shape) < flip_rate)
    small = np.where(flip, 1 - small, small).astype(np.uint8)
    small_depth[rng.random(small.shape) < hole_rate] = 0.0
    dx, dy = rng.uniform(-shift_px, shift_px, 2)
    M = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    out = []
    for image in (small, small_depth):
        big = cv2.resize(image, (W, H), interpolation=cv2.INTER_NEAREST)
        out.append(cv2.warpAffine(big, M, (W, H), flags=cv2.INTER_NEAREST))
    return out[0] > 0, out[1].astype(np.float64)


def make_image_case(edits: dict[str, float] | None = None, seed: int = 0, actors: int = 1, frame: int = 10,
                    model=None, distance_m: float = 2.4, n_handles: int | None = None, motion: str = "walk",
                    rim_cos: float | str | None = "run") -> ImageCase:
    """A rendered source/target frame pair; ``edits`` are ``StatisticalBodyModel`` attribute deltas
    (default ``{"stature_m": +10 %, "mass_kg": 15}``); ``actors`` 1 or 2 (side by side, 0.8 m apart).
    ``n_handles`` candidate vertices per frame (shared by the actors) and ``rim_cos`` the rim vertices added
    (None: none) default (None, ``"run"``) to the mirror run's (:data:`bodystudio.mirror.run.N_HANDLES`,
    ``RIM_COS``)."""
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_subject
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.motion import motion_sequence
    from bodystudio.capture.render import background_plate as plate
    from bodystudio.capture.render import render, render_rgb
    from bodystudio.geometry.camera import kinect_v1
    from bodystudio.mirror import run
    from bodystudio.mirror.warp import visible_vertex_pairs, warp_pairs

    n_handles = run.N_HANDLES if n_handles is None else n_handles
    rim_cos = run.RIM_COS if rim_cos == "run" else rim_cos

    if actors not in (1, 2):
        raise InputError(f"actors must be 1 or 2, got {actors}")
    model = load_statistical_model("2k", progress=False) if model is None else model
    rng = np.random.default_rng(seed)
    camera = kinect_v1(eye=(0.0, 1.0, distance_m), target=(0.0, 0.9, 0.0)).color
    background = plate(camera, seed=seed)
    sources, targets = [], []
    offsets = [0.0] if actors == 1 else [-0.45, 0.45]
    for a, x in enumerate(offsets):
        phenotype, local = sample_subject(seed * 10 + a + 1)
        c = model.project(build_body(phenotype, local, resolution=model.resolution).vertices)
        measured = model.measure(c)
        deltas = {"stature_m": 0.10 * measured["stature_m"], "mass_kg": 15.0} if edits is None else edits
        c_target = model.edit(c, deltas, others="follow")
        src, tgt = model.body(c), model.body(c_target)
        pose = motion_sequence(motion, max(frame + 1, 2), src.skeleton, seed=seed + a)[frame]
        Vs, _ = src.pose(pose)
        Vt, _ = tgt.pose(pose)
        # both stand on the floor where the actor stands
        shift = np.array([x, -Vs[:, 1].min(), 0.0])
        sources.append(Vs + shift)
        targets.append(Vt + np.array([x, -Vt[:, 1].min(), 0.0]))
    nv = len(sources[0])
    F = np.concatenate([model.faces + a * nv for a in range(actors)])
    Vs, Vt = np.concatenate(sources), np.concatenate(targets)
    rs, rt = render(Vs, F, camera), render(Vt, F, camera)
    rgb = render_rgb(Vs, F, camera, background=background, result=rs, noise_std=2.0, rng=rng)
    target_rgb = render_rgb(Vt, F, camera, background=background, result=rt)
    player, depth = sdk_player_mask(rs.mask, np.where(rs.mask, rs.depth, BACKGROUND_DEPTH_M), rng)
    src_uv, dst_uv, groups = [], [], []
    for a in range(actors):
        # one budget of candidate vertices per frame, shared by the actors (the MLS cost grows with both)
        s, t, _ = visible_vertex_pairs(sources[a], targets[a], model.faces, camera, n_handles // actors,
                                       rim_cos=rim_cos)
        src_uv.append(s)
        dst_uv.append(t)
        groups.append(np.full(len(s), a))
    # the dense correspondence of all actors at once: their bodies occlude each other in one z-buffer
    face_groups = np.repeat(np.arange(actors), len(model.faces))
    dense = warp_pairs(Vs, Vt, F, camera, 0, dense=True, face_groups=face_groups).dense
    return ImageCase(rgb, target_rgb, background, rs.mask, rt.mask, player, depth, np.concatenate(src_uv),
                     np.concatenate(dst_uv), Vs, Vt, F, camera, actors,
                     np.concatenate(groups), dense)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


@functools.lru_cache(maxsize=6)
def cached_image_case(edits: tuple[tuple[str, float], ...] | None = None, seed: int = 0, actors: int = 1) -> ImageCase:
    """:func:`make_image_case` memoised per process (tests and benchmarks share a few cases; do not modify them)."""
    return make_image_case(None if edits is None else dict(edits), seed=seed, actors=actors)
