"""Rapid Skin frame by frame as a tracker: the previous frame's pose as the prior, and a lost-track check.

Rapid Skin initialises every frame from the skeleton joints (§IV.A); a sequence at video rate moves
little from one frame to the next, so the previous frame's refined pose can be the starting point
instead, and the joints' initialisation and its refinement run only at the first frame or when the
track is lost.

The image term is shared by both paths: per-camera signed distance fields of the frame's silhouettes
(:class:`SilhouetteFields`, computed once per frame) give an implicit visual hull, ``max_c d_c z_c /
f_c`` (:func:`silhouette_data_term`), that the Gauss-Newton step of
:func:`bodystudio.reconstruct.articulated_fit.refine_bone_transforms` fits without carving the hull.
A tracked frame starts that fit from the previous frame's bone transforms
(:func:`track_bone_transforms`); a re-initialised one from the frame's tracker joints.

Measured (docs/reconstruct.md): the implicit hull is as accurate as the carved hull and cheaper, and
is the default refinement. Tracking from the previous frame is off by default. A tracked frame fits until
the data energy plateaus and re-matches ``outer_iterations`` (3) times instead of the run's ``No`` (8):
the whole tracked frame ~240 -> ~100 ms CPU at 13K and 10 views, and on the three 30 fps benchmark
sessions its p90 is at or below the previous tracker's and the per-frame initialisation's.

The lost-track check (:func:`lost_track_reason`), in this order, re-initialises from the tracker joints
(or the hull) with the full articulated fit:

- ``first``: the first frame of the sequence;
- ``joint_jump``: the tracked torso joints moved by more than ``joint_jump_m`` (median over joints)
  since the previous frame: faster than a person moves between video frames;
- ``silhouette``: the prior pose (the previous frame's) has more than ``prior_outside_max`` of the fit
  template's vertices projecting outside a silhouette: the person is no longer where the track is;
- ``energy_jump``: after the tracking fit, the outside share (the silhouette energy) is above
  ``energy_abs`` and ``energy_ratio`` times the previous frame's: the fit did not follow;
- ``limbs_far``: after the tracking fit, a limb joint of the fitted pose (elbows, wrists, knees, ankles) lies
  more than ``limbs_far_mm`` from the frame's tracker joint: the limb was lost inside the visual hull of few or
  small views, where the silhouettes cannot hold it (rec15r; docs/reconstruct.md).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from bodystudio.body.kinect import kinect_joint_names
from bodystudio.errors import InputError
from bodystudio.reconstruct.articulated_fit import (
    REFINE_BONES,
    PoseRefineParams,
    _huber_weights,
    refine_bone_transforms,
)
from bodystudio.reconstruct.pose_init import TORSO_JOINTS
from bodystudio.reconstruct.silhouette import MatchSchedule

#: Why a frame was (re-)initialised instead of tracked; ``tracked`` when it was not.
TRACK_REASONS = ("first", "joint_jump", "silhouette", "energy_jump", "limbs_far", "tracked", "per_frame")


@dataclass(frozen=True)
class TrackParams:
    """Settings of the tracker and its lost-track check (see the module docstring).

    ``outside_px``: a vertex counts as outside a silhouette beyond this distance (the fit template is
    generic, so its limbs poke out by a few pixels on a good fit); ``inside_weight``: weight of vertices
    inside the implicit hull (as the hull fit's); ``inside_m``: vertices deeper inside are ignored;
    ``iterations``: Gauss-Newton iterations of the tracking fit, at most: it stops once an iteration lowered
    the data energy by less than ``min_decrease`` (a fraction; the previous frame's pose is close, so two or
    three steps reach the plateau); ``joint_weight``: pull of the tracked joints per squared metre (0:
    silhouettes only).

    The tracked frame's deformation (issue 15's frame time): ``warm_mesh`` starts Algorithm 1 from the
    previous frame's deformed mesh carried by the change of the posed template
    (:func:`carry_deformed_mesh`) instead of the posed template, and ``outer_iterations`` (``No`` of a
    tracked frame; 0: the deformation's own) re-matches fewer times from that closer start. A
    re-initialised frame (first, lost track) runs the full deformation from its posed template.
    ``matching``: the tracked frame's :class:`bodystudio.reconstruct.silhouette.MatchSchedule` (which of its
    outer iterations match the cheaper way; default: the last one reads the outline raster drawn at the one
    before and keeps the visual-hull gate's decisions of the earlier ones); ``exact_fields``: the run's
    :class:`SilhouetteFields` by the exact distance transform (default False: the 5x5 chamfer one, ~2x
    faster). Both measured in docs/reconstruct.md (rec15e);
    ``TrackParams(matching=MatchSchedule(), exact_fields=True)`` is the tracker before them.
    ``tau_px``: the tracked frame's contour search range (Algorithm 1's ``tau``; never above the run's; 0: the
    run's). The tracked frame starts from the previous frame's pose fitted to this frame's silhouettes, a few
    centimetres from the surface at most, while the paper's 30 px reach ~20 cm at 3 m (f ~ 450 px): the far
    crossings it finds are other body parts' contours (a head's rim vertex inside a raised arm's silhouette, a
    fingertip reaching the next finger's), each pulling its vertex 10-20 cm into a spike (issue 15, rec15l;
    docs/reconstruct.md). ``neck_joint``: the template each frame deforms is posed with its neck's base on the
    frame's tracked Neck joint (:func:`bodystudio.reconstruct.pose_init.neck_at_joint`; Eq. 11 places it by the
    spine's transform, 3-7 cm beside it on the hidden subjects); the tracker's own pose (the next frame's prior)
    is the fit's, unchanged. ``unstretch_head``: that placement also takes Eq. 11's segment stretch off the head
    (``neck_at_joint(..., unstretch_head=True)``; issue 15, rec15m: the neck and head are aimed and stretched as one
    segment from the misplaced neck base, 1.24-1.43x on the hidden subjects, and the head kept it).
    ``initial_outer_iterations``: ``No`` of a tracked run's first and re-initialised frames (0: the run's; never
    more): the upper back drifts outwards over the later re-matchings of the run's 8 (issue 15, rec15m).
    ``inner_iterations``: the tracked frame's Gauss-Seidel sweeps per outer iteration (Algorithm 1's ``Ni``; 0: the
    run's). The template is thinner or stouter than the subject by centimetres, and the silhouettes pull only its
    rims: the surface between them (a heavier subject's lower back, which no rim and no depth pair reaches) follows
    through the smoothness constraints by about one ring of vertices per sweep, and 3 x 8 sweeps left it 25-35 mm
    inside the truth. 2 outer iterations x 40 sweeps cost what 3 x 8 did (one full matching fewer) and carry the
    pull (issue 15, rec15n; docs/reconstruct.md). ``initial_inner_iterations``: the same for a tracked run's
    re-initialised frames (first, lost track; 0: the run's ``Ni``): with ``initial_outer_iterations`` 3 x 40
    instead of 8 x 8, more reach with fewer re-matchings (less of the first frame's drift), ~45 instead of ~85 ms;
    64 sweeps (rec15p) carry the first frame's rims further still: walk 31's first-frame upper back 30.5 -> 28.6 mm
    (its Hausdorff goal), medians and p90s lower on the four tuning sessions, ~+14 ms on those frames only.
    ``compiled_rotations``: the tracking fit's rotation bookkeeping compiled
    (:attr:`bodystudio.reconstruct.articulated_fit.PoseRefineParams.compiled_rotations`; rec15j).
    ``limbs_far_mm``: the ``limbs_far`` check's distance (mm) between a limb joint of the tracking fit's pose and the
    frame's tracker joint (0: off). A per-frame fit's limb joints lie <= 57 mm from the tracker's on every measured
    session, and the tracked frames of the eight 640x480 sessions <= 58 mm (the tracker's noise and the template's
    joint placement, which the refinement corrects); tracked frames on 4-6 small views at 65-321 mm fitted p90
    12-97 mm where their re-initialisation fits 8-14 mm. 80 mm: 1.4x the largest good frame, below the 88 mm frame
    that fitted p90 19.9 mm against 10.4 re-initialised (rec15r; docs/reconstruct.md).
    """

    joint_jump_m: float = 0.25
    prior_outside_max: float = 0.25
    energy_abs: float = 0.15
    energy_ratio: float = 2.0
    outside_px: float = 2.0
    inside_weight: float = 0.5
    inside_m: float = 0.10
    robust_m: float = 0.03
    iterations: int = 6
    prior_weight: float = 0.05
    joint_weight: float = 0.0
    joint_bones: tuple[str, ...] = REFINE_BONES
    min_decrease: float = 0.01
    warm_mesh: bool = False
    outer_iterations: int = 2
    tau_px: float = 15.0
    inner_iterations: int = 40
    neck_joint: bool = True
    unstretch_head: bool = True
    initial_outer_iterations: int = 3
    initial_inner_iterations: int = 64
    matching: MatchSchedule = MatchSchedule(cheap_iterations=1, keep_outline=True, gate="reuse")
    exact_fields: bool = False
    compiled_rotations: bool = False
    limbs_far_mm: float = 80.0

    def __post_init__(self):
        for name, value, lo, hi in (("joint_jump_m", self.joint_jump_m, 1e-3, 10.0),
                                    ("prior_outside_max", self.prior_outside_max, 0.0, 1.0),
                                    ("energy_abs", self.energy_abs, 0.0, 1.0),
                                    ("energy_ratio", self.energy_ratio, 1.0, 100.0),
                                    ("iterations", self.iterations, 1, 100),
                                    ("min_decrease", self.min_decrease, 0.0, 1.0),
                                    ("outer_iterations", self.outer_iterations, 0, 100),
                                    ("initial_outer_iterations", self.initial_outer_iterations, 0, 100),
                                    ("tau_px", self.tau_px, 0.0, 500.0),
                                    # the fit's data and prior terms: robust_m 0 gave every silhouette residual
                                    # weight 0 (the previous pose returned unchanged), a negative weight pushed
                                    # away from the data or the prior, both with exit 0
                                    ("outside_px", self.outside_px, 0.0, 100.0),
                                    ("inside_weight", self.inside_weight, 0.0, 10.0),
                                    ("inside_m", self.inside_m, 0.0, 1.0),
                                    ("robust_m", self.robust_m, 1e-4, 1.0),
                                    ("prior_weight", self.prior_weight, 0.0, 1e6),
                                    ("joint_weight", self.joint_weight, 0.0, 1e9),
                                    ("inner_iterations", self.inner_iterations, 0, 1000),
                                    ("initial_inner_iterations", self.initial_inner_iterations, 0, 1000),
                                    ("limbs_far_mm", self.limbs_far_mm, 0.0, 10000.0)):
            if not np.isfinite(value) or not lo <= value <= hi:
                raise InputError(f"tracking {name} {value:g} is out of range; use a value in [{lo:g}, {hi:g}]")


_FIELD_POOLS: dict = {}
# A pool's threads do not survive a fork: a forked child (mutmut's per-mutant fork, a fork-started worker) would
# queue its transforms on a pool with no thread and wait for ever; it starts pools of its own instead.
os.register_at_fork(after_in_child=_FIELD_POOLS.clear)


def _field_pool(threads: int) -> ThreadPoolExecutor:
    """One thread pool per size for :class:`SilhouetteFields`'s transforms, kept for the process."""
    pool = _FIELD_POOLS.get(threads)
    if pool is None:
        pool = _FIELD_POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="bodystudio-fields")
    return pool


class SilhouetteFields:
    """Per-camera signed distance fields of one frame's silhouettes (px; > 0 outside, < 0 inside).

    Computed once per frame (OpenCV's exact Euclidean distance transform) on the silhouette's bounding
    box grown by ``margin_px``: pixels beyond it read ``margin_px`` outside with no gradient (far off,
    counted as outside by the lost-track check, no pull in the fit). Read by the tracking fit and the
    silhouette energy of the lost-track check.
    """

    def __init__(self, cameras, masks: dict, margin_px: int = 48, exact: bool = True):
        self.cameras = list(cameras)
        # ``exact=False``: OpenCV's 5x5 chamfer transform (issue 15's frame time: ~2x faster, 5.8 instead of 11.6 ms a
        # frame; within 0.2 px of the exact distance up to 10 px from the contour, 1.6 px at most on a 640x480 view)
        dist_mask = cv2.DIST_MASK_PRECISE if exact else cv2.DIST_MASK_5
        if not margin_px >= 1:
            # with no margin a silhouette that fills its box has no outside pixel to measure the inside from: its
            # inside distances come out ~1e19 and the fit reads them as the data
            raise InputError(f"tracking: SilhouetteFields margin_px must be >= 1 pixel, got {margin_px}")
        self.margin_px = float(margin_px)
        self.sdf, self.offset = {}, {}
        boxes = []
        for cam in self.cameras:
            if cam.name not in masks:
                raise InputError(f"tracking: no mask for camera {cam.name}")
            mask = np.asarray(masks[cam.name])
            # a boolean mask is read as its bytes (a compare of a 640x480 bool image was 0.17 ms)
            full = np.ascontiguousarray(mask if mask.dtype == np.bool_ else mask > 0).view(np.uint8)
            H, W = full.shape
            bx, by, bw, bh = cv2.boundingRect(full)  # the foreground's box (0, 0, 0, 0 when empty)
            if bw:
                y0, y1 = max(by - margin_px, 0), min(by + bh + margin_px, H)
                x0, x1 = max(bx - margin_px, 0), min(bx + bw + margin_px, W)
            else:
                y0, y1, x0, x1 = 0, H, 0, W
            boxes.append((full, (bx, by, bw, bh), (y0, y1, x0, x1)))
        C = len(self.cameras)
        shapes = np.array([(y1 - y0, x1 - x0) for _, _, (y0, y1, x0, x1) in boxes], dtype=np.int64).reshape(C, 2)
        # the fields are written straight into the packed array of the compiled passes; ``sdf`` views it
        self._packed_sdf = np.zeros((C, *(shapes.max(axis=0) if C else (1, 1))), np.float32)

        def transform(k):
            full, (bx, by, bw, bh), (y0, y1, x0, x1) = boxes[k]
            sdf = self._packed_sdf[k, :y1 - y0, :x1 - x0]
            sdf[:] = cv2.distanceTransform(1 - full[y0:y1, x0:x1], cv2.DIST_L2, dist_mask)
            # pixel centres: +d outside, -d inside; the contour lies half-way, so shift by 0.5
            np.subtract(sdf, np.float32(0.5), out=sdf)
            if bw:
                # The inside distances on the silhouette's bounding box grown by one pixel only: that ring is all
                # outside, and the nearest outside pixel of an inside one is at most as far as its clamp onto the
                # ring, so the exact transform of the small box is the big one's (tested); half the pixels.
                b0, b1 = max(by - 1, y0), min(by + bh + 1, y1)
                a0, a1 = max(bx - 1, x0), min(bx + bw + 1, x1)
                core = np.ascontiguousarray(full[b0:b1, a0:a1])
                in_d = cv2.distanceTransform(core, cv2.DIST_L2, dist_mask)
                np.copyto(sdf[b0 - y0:b1 - y0, a0 - x0:a1 - x0], np.float32(0.5) - in_d, where=core.view(np.bool_))

        # The views' transforms are independent and OpenCV releases the GIL: with more than one numba thread (the
        # cores the frame may use) every other view runs on the pool's threads while this one does the rest, each
        # writing its own slice (the same arrays).
        threads = min(numba.get_num_threads(), C)
        helpers = [_field_pool(threads - 1).submit(transform, k) for k in range(1, C, threads)] if threads > 1 else []
        for k in range(C):
            if threads == 1 or k % threads != 1:
                transform(k)
        for f in helpers:
            f.result()
        for k, cam in enumerate(self.cameras):
            (y0, y1, x0, x1) = boxes[k][2]
            self.sdf[cam.name] = self._packed_sdf[k, :y1 - y0, :x1 - x0]
            self.offset[cam.name] = (x0, y0)
        self._shapes = shapes
        self._offsets = np.array([self.offset[c.name] for c in self.cameras], dtype=np.float64).reshape(C, 2)
        self._R = np.array([c.R for c in self.cameras], dtype=np.float64).reshape(C, 3, 3)
        self._t = np.array([c.t for c in self.cameras], dtype=np.float64).reshape(C, 3)
        self._K = np.array([c.K for c in self.cameras], dtype=np.float64).reshape(C, 3, 3)
        self._dist = np.array([np.asarray(c.dist, float)[:5] for c in self.cameras], dtype=np.float64).reshape(C, 5)
        self._has_dist = np.array([c.has_distortion for c in self.cameras], dtype=np.bool_)
        self._size = np.array([(c.width, c.height) for c in self.cameras], dtype=np.float64).reshape(C, 2)

    def implicit_hull(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``max_c d_c z_c / f_c`` (m; -inf where no camera sees the point) and its gradient ``(n, 3)``
        (zero beyond the fields): the implicit visual hull of :func:`silhouette_data_term`."""
        return _implicit_hull(np.ascontiguousarray(V, dtype=np.float64), self._R, self._t, self._K, self._dist,
                              self._has_dist, self._size, self._packed_sdf, self._shapes, self._offsets,
                              self.margin_px, numba.get_num_threads())

    def hull_gate(self, V: np.ndarray, vertex: np.ndarray, origin: np.ndarray, direction: np.ndarray,
                  gate_m: float, projected: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Keep mask of the visual-hull gate (:func:`bodystudio.reconstruct.rapid_skin.hull_consistent_constraints`)
        in one compiled pass: ``hull(q) <= max(hull(v), 0) + gate_m`` with ``q`` the point of each constraint's
        ray nearest its vertex. The same values as two :meth:`implicit_hull` calls, without the gradient,
        ``hull(v)`` once per distinct vertex, and ``hull(q)`` stopping at the first camera that rejects.
        ``projected``: the pixels ``(C, n, 2)`` and depths ``(C, n)`` of all of ``V`` in these cameras, as the
        matching projected them (:meth:`SilhouetteViews.projection`, the same arithmetic), so ``hull(v)`` only
        reads the fields."""
        if projected is None:
            uv, z = np.zeros((0, 0, 2)), np.zeros((0, 0))
        else:
            uv, z = projected
        return _hull_gate(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(vertex, dtype=np.int64),
                          np.ascontiguousarray(origin, dtype=np.float64),
                          np.ascontiguousarray(direction, dtype=np.float64), float(gate_m), self._R, self._t,
                          self._K, self._dist, self._has_dist, self._size, self._packed_sdf, self._shapes,
                          self._offsets, self.margin_px, numba.get_num_threads(), projected is not None, uv, z)

    def hull_gate_memo(self, V: np.ndarray, vertex: np.ndarray, camera: np.ndarray, origin: np.ndarray,
                       direction: np.ndarray, gate_m: float, memo: np.ndarray, reuse: bool,
                       projected: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Keep mask of :func:`bodystudio.reconstruct.rapid_skin.hull_consistent_constraints` with its ``memo``
        (int8 per (camera, vertex): 0 undecided, 1 kept, 2 dropped) in one compiled pass: with ``reuse`` the pairs
        decided before keep their decision, the others are gated by :meth:`hull_gate` (in their order) and their
        decisions written in; without it every pair is gated and written."""
        if projected is None:
            uv, z = np.zeros((0, 0, 2)), np.zeros((0, 0))
        else:
            uv, z = projected
        return _hull_gate_memo(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(vertex, dtype=np.int64),
                               np.ascontiguousarray(camera, dtype=np.int64),
                               np.ascontiguousarray(origin, dtype=np.float64),
                               np.ascontiguousarray(direction, dtype=np.float64), float(gate_m), memo, bool(reuse),
                               self._R, self._t, self._K, self._dist, self._has_dist, self._size, self._packed_sdf,
                               self._shapes, self._offsets, self.margin_px, numba.get_num_threads(),
                               projected is not None, uv, z)

    def sample(self, cam, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bilinear signed distance ``(m,)`` and its image gradient ``(m, 2)`` at pixels ``uv``; ``ok``
        marks pixels inside the image (outside it the distance is unknown)."""
        S = self.sdf[cam.name]
        x0, y0 = self.offset[cam.name]
        H, W = S.shape
        ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0)
        ok &= (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
        u = np.where(ok, uv[:, 0] - x0, 0.0)
        v = np.where(ok, uv[:, 1] - y0, 0.0)
        inner = ok & (u >= 0) & (v >= 0) & (u < W - 1) & (v < H - 1)
        u = np.where(inner, u, 0.0)
        v = np.where(inner, v, 0.0)
        xi, yi = u.astype(np.int64), v.astype(np.int64)
        fx, fy = u - xi, v - yi
        s00, s10, s01, s11 = S[yi, xi], S[yi, xi + 1], S[yi + 1, xi], S[yi + 1, xi + 1]
        d = (1 - fy) * ((1 - fx) * s00 + fx * s10) + fy * ((1 - fx) * s01 + fx * s11)
        gu = (1 - fy) * (s10 - s00) + fy * (s11 - s01)
        gv = (1 - fx) * (s01 - s00) + fx * (s11 - s10)
        d = np.where(inner, d, self.margin_px)
        g = np.where(inner[:, None], np.stack([gu, gv], axis=1), 0.0)
        return d.astype(np.float64), g.astype(np.float64), ok


def outside_fraction(V: np.ndarray, fields: SilhouetteFields, outside_px: float = 2.0) -> float:
    """Silhouette energy of the lost-track check: share of vertices ``V`` projecting more than
    ``outside_px`` outside the silhouette of at least one camera (the hull's "outside" test, Rapid Skin
    §IV: a point of the body lies inside every silhouette). One compiled pass over vertices and cameras
    (a vertex stops at its first camera that sees it outside); the same decisions as
    :func:`outside_fraction_reference` (tested; the projection's operation order may differ from
    :meth:`Camera.project` by an ulp, which flips a vertex only at exactly ``outside_px``)."""
    if not len(V):
        return 0.0
    return _outside_count(np.ascontiguousarray(V, dtype=np.float64), fields._R, fields._t, fields._K, fields._dist,
                          fields._has_dist, fields._size, fields._packed_sdf, fields._shapes, fields._offsets,
                          fields.margin_px, float(outside_px)) / len(V)


@numba.njit(cache=True)
def _outside_count(V, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin, outside_px):
    """Vertices seen more than ``outside_px`` outside a silhouette by some camera (:func:`outside_fraction`):
    projection as :meth:`Camera.project_with_depth`, bilinear distance as :meth:`SilhouetteFields.sample`. The
    cameras outermost, each projecting every vertex in one vectorised pass (:func:`_project_points`) and testing
    those no earlier camera saw outside (rec15i; the decisions of the vertex-major loop that stopped at a vertex's
    first such camera)."""
    n, C = V.shape[0], R.shape[0]
    out = np.zeros(n, np.bool_)
    Vf = V.reshape(-1)
    pu, pv, pz = np.empty(n), np.empty(n), np.empty(n)
    for c in range(C):
        _project_points(Vf, R[c], t[c], K[c], dist[c], has_dist[c], pu, pv, pz)
        umax, vmax = size[c, 0] - 1.0, size[c, 1] - 1.0
        ou, ov, sw, sh = offsets[c, 0], offsets[c, 1], shapes[c, 1] - 1, shapes[c, 0] - 1
        field = sdf[c]
        for i in range(n):
            if out[i] or not pz[i] > 0.0:
                continue
            u, v = pu[i], pv[i]
            if not (u >= 0.0 and v >= 0.0 and u <= umax and v <= vmax):
                continue
            uu, vv = u - ou, v - ov
            d = margin
            if uu >= 0.0 and vv >= 0.0 and uu < sw and vv < sh:
                xi, yi = int(uu), int(vv)
                ax, ay = uu - xi, vv - yi
                s00 = np.float64(field[yi, xi])
                s10 = np.float64(field[yi, xi + 1])
                s01 = np.float64(field[yi + 1, xi])
                s11 = np.float64(field[yi + 1, xi + 1])
                d = (1 - ay) * ((1 - ax) * s00 + ax * s10) + ay * ((1 - ax) * s01 + ax * s11)
            out[i] = d > outside_px
    return int(out.sum())


def outside_fraction_reference(V: np.ndarray, fields: SilhouetteFields, outside_px: float = 2.0) -> float:
    """:func:`outside_fraction` by :meth:`Camera.project` and :meth:`SilhouetteFields.sample` per camera
    (the vectorised path the compiled one replaced; the equality test's reference)."""
    out = np.zeros(len(V), bool)
    for cam in fields.cameras:
        d, _, ok = fields.sample(cam, cam.project(V))
        out |= ok & (d > outside_px)
    return float(np.mean(out)) if len(V) else 0.0


def silhouette_data_term(fields: SilhouetteFields, params: TrackParams):
    """Implicit visual-hull residuals of the tracking fit as ``data_term(V, N) -> (rows, r, w, G)``.

    A point lies inside the visual hull (Rapid Skin §IV) when it projects inside every silhouette, so
    ``max_c d_c z_c / f_c`` over the cameras (``d_c`` its signed distance in pixels to camera c's
    silhouette, ``z_c / f_c`` metres per pixel at its depth) is a signed distance to the hull that needs
    no carving: positive outside, negative inside. Each vertex gets that residual from its maximising
    camera, point-to-plane like the hull fit of :func:`refine_bone_transforms`: Huber-weighted, inside
    points down-weighted by ``inside_weight`` (the hull over-estimates the body), used only where the
    vertex normal agrees with the field's gradient (``> 0.2``, the hull fit's normal test). ``G`` is the
    residual's gradient: the field's image gradient through the pinhole Jacobian of the projection (lens
    distortion is ignored in the Jacobian only).
    """

    def term(V: np.ndarray, N: np.ndarray):
        best, G = fields.implicit_hull(V)
        seen = np.isfinite(best)
        norm = np.linalg.norm(G, axis=1)
        agree = np.einsum("ij,ij->i", N, G) > 0.2 * np.maximum(norm, 1e-12)
        use = np.flatnonzero(seen & agree & (norm > 1e-9) & (best > -params.inside_m))
        r = best[use]
        w = _huber_weights(r, params.robust_m) * np.where(r < 0, params.inside_weight, 1.0)
        return use, r, w, G[use]

    return term


@numba.njit(cache=True, parallel=True)
def _implicit_hull(V, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin, chunks):
    """One compiled pass of the implicit visual hull over vertices and cameras (see
    :meth:`SilhouetteFields.implicit_hull`; OpenCV projection as :meth:`Camera.project_with_depth`). The
    vertices run in ``prange`` as ``chunks`` contiguous chunks (one per numba thread, passed in as for
    :func:`_hull_max`); each vertex's arithmetic is the serial loop's, so the values are the same on any
    number of threads."""
    n = V.shape[0]
    best = np.full(n, -np.inf)
    G = np.zeros((n, 3))
    chunks = max(min(chunks, n), 1)
    size_chunk = (n + chunks - 1) // chunks
    for ch in numba.prange(chunks):
        _implicit_hull_range(V, best, G, ch * size_chunk, min(n, (ch + 1) * size_chunk), R, t, K, dist, has_dist,
                             size, sdf, shapes, offsets, margin)
    return best, G


@numba.njit(cache=True, inline="always")
def _implicit_hull_range(V, best, G, lo, hi, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin):
    """:func:`_implicit_hull` of the vertices ``lo:hi`` into ``best`` and ``G``: the cameras outermost, each
    projecting the range in one vectorised pass (:func:`_project_points`) and raising a vertex's max where its
    value is strictly above (the first maximising camera, as the vertex-major loop's ``r > best``), then the
    gradient of each vertex at its maximising camera alone (issue 15's frame time, rec15i; the same values as
    :func:`_implicit_hull_range_reference`, tested)."""
    C = R.shape[0]
    m = hi - lo
    if m <= 0:
        return
    Vf = V[lo:hi].reshape(-1)
    pu, pv, pz = np.empty(m), np.empty(m), np.empty(m)
    arg = np.full(m, -1, np.int64)
    for c in range(C):
        _project_points(Vf, R[c], t[c], K[c], dist[c], has_dist[c], pu, pv, pz)
        umax, vmax = size[c, 0] - 1.0, size[c, 1] - 1.0
        ou, ov, sw, sh = offsets[c, 0], offsets[c, 1], shapes[c, 1] - 1, shapes[c, 0] - 1
        f = 0.5 * (K[c, 0, 0] + K[c, 1, 1])
        field = sdf[c]
        for k in range(m):
            z = pz[k]
            if not z > 1e-6:
                continue
            u, v = pu[k], pv[k]
            if not (u >= 0.0 and v >= 0.0 and u <= umax and v <= vmax):
                continue
            uu, vv = u - ou, v - ov
            d = margin
            if uu >= 0.0 and vv >= 0.0 and uu < sw and vv < sh:
                xi, yi = int(uu), int(vv)
                ax, ay = uu - xi, vv - yi
                s00 = np.float64(field[yi, xi])
                s10 = np.float64(field[yi, xi + 1])
                s01 = np.float64(field[yi + 1, xi])
                s11 = np.float64(field[yi + 1, xi + 1])
                d = (1 - ay) * ((1 - ax) * s00 + ax * s10) + ay * ((1 - ax) * s01 + ax * s11)
            r = d * z / f
            up = r > best[lo + k]
            best[lo + k] = r if up else best[lo + k]
            arg[k] = c if up else arg[k]
    for k in range(m):
        c = arg[k]
        if c >= 0:
            _implicit_hull_at(V, best, G, lo + k, c, c + 1, R, t, K, dist, has_dist, size, sdf, shapes, offsets,
                              margin, True)


@numba.njit(cache=True, inline="always")
def _implicit_hull_at(V, best, G, i, c0, c1, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin, gradient):
    """Vertex ``i`` of :func:`_implicit_hull` over the cameras ``c0:c1``, vertex-major (the loop before rec15i):
    raises ``best[i]`` where a camera's value is above it and takes that camera's gradient into ``G[i]``; with
    ``gradient`` the gradient is written for the last camera whatever its value (the maximising one, known)."""
    X, Y, Z = V[i, 0], V[i, 1], V[i, 2]
    for c in range(c0, c1):
        xc = R[c, 0, 0] * X + R[c, 0, 1] * Y + R[c, 0, 2] * Z + t[c, 0]
        yc = R[c, 1, 0] * X + R[c, 1, 1] * Y + R[c, 1, 2] * Z + t[c, 1]
        z = R[c, 2, 0] * X + R[c, 2, 1] * Y + R[c, 2, 2] * Z + t[c, 2]
        if not z > 1e-6:
            continue
        x, y = xc / z, yc / z
        if has_dist[c]:
            k1, k2, p1, p2, k3 = dist[c, 0], dist[c, 1], dist[c, 2], dist[c, 3], dist[c, 4]
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x, y = xd, yd
        fx, fy = K[c, 0, 0], K[c, 1, 1]
        u = fx * x + K[c, 0, 1] * y + K[c, 0, 2]
        v = fy * y + K[c, 1, 2]
        if not (u >= 0.0 and v >= 0.0 and u <= size[c, 0] - 1.0 and v <= size[c, 1] - 1.0):
            continue
        uu, vv = u - offsets[c, 0], v - offsets[c, 1]
        d, gu, gv = margin, 0.0, 0.0
        if uu >= 0.0 and vv >= 0.0 and uu < shapes[c, 1] - 1 and vv < shapes[c, 0] - 1:
            xi, yi = int(uu), int(vv)
            ax, ay = uu - xi, vv - yi
            s00 = np.float64(sdf[c, yi, xi])
            s10 = np.float64(sdf[c, yi, xi + 1])
            s01 = np.float64(sdf[c, yi + 1, xi])
            s11 = np.float64(sdf[c, yi + 1, xi + 1])
            d = (1 - ay) * ((1 - ax) * s00 + ax * s10) + ay * ((1 - ax) * s01 + ax * s11)
            gu = (1 - ay) * (s10 - s00) + ay * (s11 - s01)
            gv = (1 - ax) * (s01 - s00) + ax * (s11 - s10)
        f = 0.5 * (fx + fy)
        r = d * z / f
        if gradient or r > best[i]:
            best[i] = r
            # d(uv)/d(Pc) of the pinhole model, scaled to metres per pixel at the vertex's depth, to world
            s = z / f
            g0 = s * gu * fx / z
            g1 = s * gv * fy / z
            g2 = -s * (gu * fx * xc + gv * fy * yc) / (z * z)
            for k in range(3):
                G[i, k] = g0 * R[c, 0, k] + g1 * R[c, 1, k] + g2 * R[c, 2, k]


@numba.njit(cache=True)
def _implicit_hull_reference(V, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin):
    """:func:`_implicit_hull` vertex-major on one thread, each vertex over all cameras (the loop before rec15i),
    kept as the equality test's reference."""
    n = V.shape[0]
    best = np.full(n, -np.inf)
    G = np.zeros((n, 3))
    for i in range(n):
        _implicit_hull_at(V, best, G, i, 0, R.shape[0], R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin,
                          False)
    return best, G


@numba.njit(cache=True, parallel=True)
def _hull_max(X, limit, R, t, K, dist, has_dist, size_px, sdf, shapes, offsets, margin, chunks):
    """The implicit hull ``max_c d_c z_c / f_c`` of points ``X`` (the arithmetic of :func:`_implicit_hull`,
    operation for operation, without the gradient), cameras in the outer loop: one camera's field (~0.5 MB)
    stays in cache while every point reads it, where the point-major loop reads ten. A point whose running
    max exceeds its ``limit`` is not read by the later cameras (its value is then only known to be above).
    The points run in ``prange`` as ``chunks`` contiguous chunks (one per numba thread, passed in: numba's
    thread count read inside would keep the function out of the cache; one parallel region a call; each
    point's arithmetic and camera order are the serial loop's, so the values are the same on any number of
    threads)."""
    n = X.shape[0]
    best = np.full(n, -np.inf)
    chunks = max(min(chunks, n), 1)
    size = (n + chunks - 1) // chunks
    for ch in numba.prange(chunks):
        _hull_max_range(X, limit, best, ch * size, min(n, (ch + 1) * size), R, t, K, dist, has_dist, size_px,
                        sdf, shapes, offsets, margin)
    return best


@numba.njit(cache=True, inline="always")
def _hull_max_range(X, limit, best, lo, hi, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin):
    """:func:`_hull_max` of the points ``lo:hi`` into ``best``, cameras outermost: each camera projects the
    range in one vectorised pass (:func:`_project_points`), then reads its field at the points still undecided."""
    C = R.shape[0]
    m = hi - lo
    if m <= 0:
        return
    Xf = X[lo:hi].reshape(-1)
    pu, pv, pz = np.empty(m), np.empty(m), np.empty(m)
    for c in range(C):
        _project_points(Xf, R[c], t[c], K[c], dist[c], has_dist[c], pu, pv, pz)
        umax, vmax = size[c, 0] - 1.0, size[c, 1] - 1.0
        ou, ov, sw, sh = offsets[c, 0], offsets[c, 1], shapes[c, 1] - 1, shapes[c, 0] - 1
        f = 0.5 * (K[c, 0, 0] + K[c, 1, 1])
        field = sdf[c]
        for k in range(m):
            i = lo + k
            if best[i] > limit[i]:
                continue
            z = pz[k]
            if not z > 1e-6:
                continue
            u, v = pu[k], pv[k]
            if not (u >= 0.0 and v >= 0.0 and u <= umax and v <= vmax):
                continue
            uu, vv = u - ou, v - ov
            d = margin
            if uu >= 0.0 and vv >= 0.0 and uu < sw and vv < sh:
                xi, yi = int(uu), int(vv)
                ax, ay = uu - xi, vv - yi
                s00 = np.float64(field[yi, xi])
                s10 = np.float64(field[yi, xi + 1])
                s01 = np.float64(field[yi + 1, xi])
                s11 = np.float64(field[yi + 1, xi + 1])
                d = (1 - ay) * ((1 - ax) * s00 + ax * s10) + ay * ((1 - ax) * s01 + ax * s11)
            # a select, not a branch: whether a later camera raises the max is a coin flip for the branch predictor
            # (rec15f: 3.3 -> 2.6 ms for a pass's 11.6K targets, the same values)
            best[i] = max(best[i], d * z / f)


@numba.njit(cache=True, error_model="numpy")
def _project_points(Xf, R, t, K, dist, distorted, pu, pv, pz):
    """Pixels ``(pu, pv)`` and depths ``pz`` of the points of the flat ``(3 m,)`` array ``Xf`` in one camera, the
    arithmetic of :func:`_implicit_hull` operation for operation (the pixel is only read where ``z > 1e-6``), in a
    branch-free loop over flat arrays that LLVM vectorises (issue 15's frame time, rec15i: the gate's targets
    pass ~2.3 -> ~1.6 ms)."""
    r00, r01, r02, r10, r11, r12 = R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22, t0, t1, t2 = R[2, 0], R[2, 1], R[2, 2], t[0], t[1], t[2]
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    fx, fy, sk, cx, cy = K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]
    if distorted:
        for k in range(pz.shape[0]):
            X0, Y0, Z0 = Xf[3 * k], Xf[3 * k + 1], Xf[3 * k + 2]
            xc = r00 * X0 + r01 * Y0 + r02 * Z0 + t0
            yc = r10 * X0 + r11 * Y0 + r12 * Z0 + t1
            z = r20 * X0 + r21 * Y0 + r22 * Z0 + t2
            x, y = xc / z, yc / z
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            pu[k] = fx * xd + sk * yd + cx
            pv[k] = fy * yd + cy
            pz[k] = z
    else:
        for k in range(pz.shape[0]):
            X0, Y0, Z0 = Xf[3 * k], Xf[3 * k + 1], Xf[3 * k + 2]
            xc = r00 * X0 + r01 * Y0 + r02 * Z0 + t0
            yc = r10 * X0 + r11 * Y0 + r12 * Z0 + t1
            z = r20 * X0 + r21 * Y0 + r22 * Z0 + t2
            x, y = xc / z, yc / z
            pu[k] = fx * x + sk * y + cx
            pv[k] = fy * y + cy
            pz[k] = z


@numba.njit(cache=True, parallel=True)
def _hull_max_at(order, uv, z, K, size_px, sdf, shapes, offsets, margin, chunks):
    """:func:`_hull_max` of the vertices ``order`` (no limit) from their pixels ``uv[c, i]`` and depths
    ``z[c, i]`` already projected (by :func:`bodystudio.reconstruct.silhouette._project_into`, the same
    arithmetic as :func:`_hull_max_range`'s projection, so the same values): the field reads only."""
    n = order.shape[0]
    best = np.full(n, -np.inf)
    chunks = max(min(chunks, n), 1)
    size = (n + chunks - 1) // chunks
    for ch in numba.prange(chunks):
        lo, hi = ch * size, min(n, (ch + 1) * size)
        for c in range(K.shape[0]):
            f = 0.5 * (K[c, 0, 0] + K[c, 1, 1])
            umax, vmax = size_px[c, 0] - 1.0, size_px[c, 1] - 1.0
            ou, ov, sw, sh = offsets[c, 0], offsets[c, 1], shapes[c, 1] - 1, shapes[c, 0] - 1
            field = sdf[c]
            for k in range(lo, hi):
                i = order[k]
                zc = z[c, i]
                if not zc > 1e-6:
                    continue
                u, v = uv[c, i, 0], uv[c, i, 1]
                if not (u >= 0.0 and v >= 0.0 and u <= umax and v <= vmax):
                    continue
                uu, vv = u - ou, v - ov
                d = margin
                if uu >= 0.0 and vv >= 0.0 and uu < sw and vv < sh:
                    xi, yi = int(uu), int(vv)
                    ax, ay = uu - xi, vv - yi
                    s00 = np.float64(field[yi, xi])
                    s10 = np.float64(field[yi, xi + 1])
                    s01 = np.float64(field[yi + 1, xi])
                    s11 = np.float64(field[yi + 1, xi + 1])
                    d = (1 - ay) * ((1 - ax) * s00 + ax * s10) + ay * ((1 - ax) * s01 + ax * s11)
                best[k] = max(best[k], d * zc / f)  # a select, as in _hull_max_range (1.2 -> 0.7 ms a pass)
    return best


@numba.njit(cache=True)
def _hull_gate(V, vertex, origin, direction, gate_m, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin,
               chunks, has_projection, uv, z):
    """Keep mask of :meth:`SilhouetteFields.hull_gate`: ``hull(v)`` of each distinct vertex once (a rim
    vertex has matches in several views), then ``hull(q)`` of the targets, each target dropped from the
    camera loop as soon as it exceeds ``max(hull(v), 0) + gate_m`` (the max only grows, so the decision is
    the full max's). The distinct vertices are read in the order of their ids (neighbours on the mesh, near in
    every image: the fields' reads stay in cache; issue 15's frame time, rec15k: ~0.7 -> ~0.5 ms a pass of ~7K
    vertices, the same values, each vertex's max over the cameras in their order)."""
    m = vertex.shape[0]
    slot = np.full(V.shape[0], -1, np.int64)
    for j in range(m):
        slot[vertex[j]] = 0
    order = np.empty(m, np.int64)
    nu = 0
    for i in range(V.shape[0]):
        if slot[i] == 0:
            slot[i] = nu
            order[nu] = i
            nu += 1
    if has_projection:
        hv = _hull_max_at(order[:nu], uv, z, K, size, sdf, shapes, offsets, margin, chunks)
    else:
        P = np.empty((nu, 3))
        for k in range(nu):
            P[k, 0], P[k, 1], P[k, 2] = V[order[k], 0], V[order[k], 1], V[order[k], 2]
        hv = _hull_max(P, np.full(nu, np.inf), R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin, chunks)
    Q = np.empty((m, 3))
    limit = np.empty(m)
    for j in range(m):
        i = vertex[j]
        ox, oy, oz = origin[j, 0], origin[j, 1], origin[j, 2]
        dx, dy, dz = direction[j, 0], direction[j, 1], direction[j, 2]
        s = (V[i, 0] - ox) * dx + (V[i, 1] - oy) * dy + (V[i, 2] - oz) * dz
        Q[j, 0], Q[j, 1], Q[j, 2] = ox + s * dx, oy + s * dy, oz + s * dz
        limit[j] = max(hv[slot[i]], 0.0) + gate_m
    hq = _hull_max(Q, limit, R, t, K, dist, has_dist, size, sdf, shapes, offsets, margin, chunks)
    keep = np.empty(m, np.bool_)
    for j in range(m):
        keep[j] = not hq[j] > limit[j]
    return keep


@numba.njit(cache=True)
def _hull_gate_memo(V, vertex, camera, origin, direction, gate_m, memo, reuse, R, t, K, dist, has_dist, size, sdf,
                    shapes, offsets, margin, chunks, has_projection, uv, z):
    """:meth:`SilhouetteFields.hull_gate_memo`: the undecided pairs (all without ``reuse``) through
    :func:`_hull_gate` in their order, the decisions of the others read from ``memo``."""
    m, n = vertex.shape[0], V.shape[0]
    keep = np.empty(m, np.bool_)
    todo = np.empty(m, np.int64)
    nt = 0
    for j in range(m):
        known = memo[camera[j] * n + vertex[j]] if reuse else 0
        keep[j] = known == 1
        if known == 0:
            todo[nt] = j
            nt += 1
    if nt == 0:
        return keep
    if nt == m:
        new = _hull_gate(V, vertex, origin, direction, gate_m, R, t, K, dist, has_dist, size, sdf, shapes, offsets,
                         margin, chunks, has_projection, uv, z)
    else:
        sub = todo[:nt]
        new = _hull_gate(V, vertex[sub], origin[sub], direction[sub], gate_m, R, t, K, dist, has_dist, size, sdf,
                         shapes, offsets, margin, chunks, has_projection, uv, z)
    for k in range(nt):
        j = todo[k]
        keep[j] = new[k]
        memo[camera[j] * n + vertex[j]] = 1 if new[k] else 2
    return keep


def joint_anchors(body, joint_transforms: np.ndarray, bones=REFINE_BONES):
    """Heads and tails of the refined ``bones`` placed by the bone transforms of the frame's tracker
    joints (:func:`bodystudio.reconstruct.pose_init.initialise_pose`): ``(bones, rest_points, targets)``."""
    skel = body.skeleton
    ids = np.array([skel.index(b) for b in bones])
    a_bones = np.concatenate([ids, ids])
    rest = np.concatenate([skel.heads[ids], skel.tails[ids]])
    T = np.asarray(joint_transforms, dtype=np.float64)[a_bones]
    return a_bones, rest, np.einsum("mij,mj->mi", T[:, :3, :3], rest) + T[:, :3, 3]


def track_bone_transforms(body, previous: np.ndarray, fields: SilhouetteFields,
                          params: TrackParams | None = None, joint_transforms: np.ndarray | None = None
                          ) -> np.ndarray:
    """Bone transforms ``(B, 4, 4)`` of this frame from the previous frame's, fitted to the silhouettes.

    The Gauss-Newton step and the segments of :func:`refine_bone_transforms` on the fit template
    ``body`` (2.5K), the data term :func:`silhouette_data_term`, the prior holding each segment near
    the previous frame's pose; with ``joint_transforms`` (the Eq. 11 transforms of this frame's tracker
    joints) the segments' heads and tails are also pulled towards the tracked joints
    (``joint_weight``), which keeps the silhouettes' blind directions from drifting over frames.
    """
    params = params or TrackParams()
    refine = PoseRefineParams(iterations=params.iterations, prior_weight=params.prior_weight,
                              robust_m=params.robust_m, min_decrease=params.min_decrease,
                              compiled_rotations=params.compiled_rotations)
    anchors = None
    if joint_transforms is not None and params.joint_weight > 0:
        anchors = (*joint_anchors(body, joint_transforms, params.joint_bones), params.joint_weight)
    return refine_bone_transforms(body, previous, None, refine, data_term=silhouette_data_term(fields, params),
                                  anchors=anchors)


def carry_deformed_mesh(previous_deformed: np.ndarray, previous_posed: np.ndarray,
                        posed: np.ndarray) -> np.ndarray:
    """The previous frame's deformed mesh moved to this frame's pose: ``V_prev + (P - P_prev)``.

    ``P_prev`` and ``P`` are the template posed (Eq. 12 of Rapid Skin) by the previous and this frame's
    bone transforms; the deformation's offsets from its posed template are carried over as they are
    (not rotated with their bones: between video frames a segment turns a few degrees, so an offset of
    a few millimetres moves by a few hundredths of one). The warm start of a tracked frame's Algorithm 1.
    """
    return np.asarray(previous_deformed, dtype=np.float64) + (np.asarray(posed, dtype=np.float64)
                                                              - np.asarray(previous_posed, dtype=np.float64))


def torso_joint_jump_m(joints: np.ndarray | None, previous: np.ndarray | None) -> float:
    """Median displacement (m) of the torso joints tracked in both frames (0 when none are)."""
    if joints is None or previous is None:
        return 0.0
    names = kinect_joint_names("v2")
    ids = [names.index(n) for n in TORSO_JOINTS]
    a, b = np.asarray(joints)[ids], np.asarray(previous)[ids]
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    if not ok.any():
        return 0.0
    return float(np.median(np.linalg.norm(a[ok] - b[ok], axis=1)))


def lost_track_reason(first: bool, joint_jump_m: float, prior_outside: float,
                      params: TrackParams) -> str | None:
    """Why the track is lost before fitting this frame (see the module docstring), or None."""
    if first:
        return "first"
    if joint_jump_m > params.joint_jump_m:
        return "joint_jump"
    if prior_outside > params.prior_outside_max:
        return "silhouette"
    return None


def limbs_far(limb_joint_mm: float | None, params: TrackParams) -> bool:
    """The tracking fit's pose put a limb joint ``limb_joint_mm`` (the largest over the limb joints tracked in
    the frame, :func:`bodystudio.reconstruct.plausibility.tracker_joint_residual`; None: none tracked) further than
    ``limbs_far_mm`` from the frame's tracker joint (``limbs_far``; 0: off)."""
    return bool(params.limbs_far_mm > 0 and limb_joint_mm is not None and limb_joint_mm > params.limbs_far_mm)


def energy_jumped(energy: float, previous_energy: float | None, params: TrackParams) -> bool:
    """The silhouette energy after the tracking fit jumped (``energy_jump``)."""
    if previous_energy is None:
        return energy > params.energy_abs
    return energy > params.energy_abs and energy > params.energy_ratio * previous_energy
