"""Arm-muscle capture from a depth camera: the pipeline of Arm-Muscle Capture (Robertini et al. 2013).

Steps, each in its own module and named after the paper's concepts:

1. depth clean-up and point clouds (Sec. 4): ``bodystudio.muscle.depth``;
2. rigid alignment with scale on the first frame, applied to the whole sequence (Sec. 5.1), then
   non-rigid ICP: closest points, the six filters of Sec. 5.2, ARAP (Sec. 5.3): ``bodystudio.muscle.nicp``;
3. model-based filtering (Sec. 6.2): Procrustes joint angles (Eq. 11), shape parameters fitted once per
   sequence, the model mesh of Eq. 12 with the norm limit: ``bodystudio.muscle.refine``;
4. refinement (Sec. 7): correspondences averaged over frames i-1, i, i+1 (Eq. 13-14), weighted by
   agreement with the vertex normals and closeness to a joint (Sec. 7.2), last ARAP.

``capture_arm_frames`` runs the pipeline on arrays; ``capture_arm_sequence`` reads a session. The
``mode`` switch gives the paper's ablations: ``full``; ``nicp`` (NICP + ARAP without the model, the
paper's Fig. 6a); ``model`` (model-based filtering without the refinement).

Everything runs in the template's space: the Sec. 5.1 similarity (found once) maps the depth points
onto the template, as in the paper, and the results are mapped back to world (sensor) coordinates.

Where we depart from the paper, each measured on synthetic 6k Kinect v2 sequences at 1 m (numbers
in the docstrings and commits):

- the first frame starts from the body tracker's shoulder/elbow/wrist when the session has them
  (our sequences do not begin in the base pose), and Sec. 5.1's transform is a translation by
  default: scale and rotation from point-to-point pairs of a one-sided view shrank and rolled the arm;
- NICP and refinement pull vertices to the depth points' tangent planes (point-to-plane), not onto
  the points: the ~3 mm spaced noisy samples dragged vertices sideways;
- the model is fitted to the depth points themselves (point-to-plane, weakly to the NICP mesh),
  with the elbow as a hinge, the forearm twist and the wrist held (unobservable on a near-cylinder;
  the paper cannot capture pronation either), one torso placement per sequence, the tracker joints
  as a weak extra observation and a previous-frame prior; then every frame's angles are solved
  together over the whole sequence (model-based tracking, ``refine.fit_arm_sequence``: depth,
  tracker and a second-difference prior, Huber residuals) and smoothed over +-5 frames before the
  model meshes are rebuilt;
- ``known_shape``: the subject's measured BMI, muscularity, height and arm length (the paper's
  Table 1) can replace the fitted shape, which is the weakest step (see the report figures).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.errors import FileFormatError, InputError, SessionError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle.arm import ArmPose, ArmTemplate, pose_arm
from bodystudio.muscle.depth import DepthCleanupOptions, clean_depth, depth_point_cloud, segment_by_distance
from bodystudio.muscle.nicp import (
    CorrespondenceFilters,
    NicpOptions,
    apply_similarity,
    arap_system,
    closest_point_correspondences,
    filter_correspondences,
    nonrigid_icp,
    plane_targets,
    rigid_alignment_with_scale,
    vertex_neighbourhoods,
)
from bodystudio.muscle.refine import (
    DepthFrame,
    DepthOutline,
    arm_pose_from_part_transforms,
    correspondence_weights,
    depth_energy_mm,
    depth_residual_sigma_m,
    edge_on_pairs,
    fit_arm_sequence_skeleton,
    fit_body_rest_shape,
    fit_body_rest_shape_and_poses,
    fit_rest_shape_correction,
    fit_shape_parameters,
    initial_arm_pose_from_joints,
    model_based_filtering,
    noise_weighted_tracker_weight,
    population_shape_prior,
    posed_joints,
    procrustes_part_transforms,
    refine_surface,
    refit_arm_poses_to_depth,
    skeleton_model_mesh,
    smooth_arm_poses,
    time_consistent_correspondences,
    tracker_mean_standard_error,
    tracker_noise_sigma_m,
    tracker_placement_prior_weight,
    unseen_hold_weights,
)

log = logging.getLogger(__name__)

MODES = ("full", "nicp", "model")
TRACKER_JOINTS = {"left": ("ShoulderLeft", "ElbowLeft", "WristLeft"),
                  "right": ("ShoulderRight", "ElbowRight", "WristRight")}


# The capture setting for extending a model (``muscle capture --for-extension``): the subject's skeleton and the
# torso placement fitted with every frame's angles in the sequence fit, Huber weights on the depth pairs only, and
# otherwise the capture's defaults as they were measured here (pinned, so that a later change of a default is measured
# for the extension before it reaches it). Measured (docs/muscle.md, fifth pass; the benchmark's extension step), mean
# change of the held-out out-of-range subjects' model-only error, sets A / B: captures without the sequence fit -6.6 /
# -5.7 %; with the skeleton fit, each rest mesh centred by sex (``model.capture_samples(centre="sex")``) -11.7 /
# -11.7 %.
# The capture's later defaults (the body rest shape with its tracker at 10, the 20 % limit, the pose refit, the hold
# of the unseen side, the grazing cut of the pose fits, the refinement's rim cut and own depth clean-up) since the
# eleventh pass of the extension (docs/muscle.md): chosen on held-out set C with two sets of added subjects, the
# extended model's mean median mm on C (601-604 / 671-674 added) 6.37 / 6.84 -> 6.29 / 6.45, C's in-range men 3.60 /
# 3.73 -> 3.63 / 3.33; the captures' own medians 7.61 / 9.67 -> 5.95 / 7.04 mm. Before it they were off here: the
# regressed rest arm, a 50 % limit and no pose refit (better on C than the then defaults in the ninth pass), and the
# later ones unmeasured; the hold of the unseen side on the regressed rest arm (with the cuts) ties the rows to the
# model: C 6.43 -> 7.53 mm. The pose smoothing stays the Gaussian mean at sigma 2.5, and the rest fit's prior on the
# local targets 0.25 on every target: measured for the extension (docs/muscle.md, "Dataset extension, twelfth pass";
# set C, 601-604 added, change and mean mm), the fifteenth pass's local quadratic changes the captures (5.96 -> 5.75 mm
# mean median) and not the extension (-23.4 %, 6.29 mm either way); its population prior on the local targets costs
# the extension (-23.4 -> -15.5 %, 6.29 -> 6.99 mm; both: -19.4 -> -18.1 % with 671-674 added): an out-of-range
# subject lies outside the in-range population's spread (the short woman 603's row 4.44 -> 8.47 mm from her truth).
# No outline pairs in the rest fit either (the sixteenth pass's, not measured for the extension).
EXTENSION_CAPTURE = {"sequence_fit_skeleton": True, "sequence_fit_root": True, "sequence_depth_huber_only": True,
                     "body_rest_shape": True, "body_rest_tracker_weight": 10.0, "norm_limit": 0.2, "pose_refit": True,
                     "refine_unseen_hold": 1.0, "refine_min_facing_cos": 0.35, "refine_depth_median_px": 1,
                     "refine_depth_gaussian_sigma_px": 0.5, "sequence_min_facing_cos": 0.3,
                     "pose_sigma_frames": 2.5, "pose_smoothing_degree": 0, "body_rest_population_locals": 0.0,
                     "body_rest_local_sigma": 0.25, "body_rest_outline_weight": 0.0}
# The setting of a sequence that pins its shared torso placement and skeleton (``CaptureOptions.sequence_pinned_se_m``,
# off by default): the skeleton and placement fitted with every frame's angles, Huber on the depth pairs only, the
# chest's pairs off, the tracker's joints at 10, and a 5 % norm limit (the fitted skeleton carries a lower model biceps;
# the limit keeps the pose term's bulge, which the sensor cannot see at strong flexion): the sixth pass's best on 501
# (median / p90 4.61 / 7.74 -> 3.15 / 5.66 mm). Over 24 frames (tracker mean's SE ~2 mm) it lost on 5 and 603 (fifth
# and sixth passes), which the SE gate leaves alone; at 200 frames it lost on 508 (seventh pass), which it does not.
#: fewer frames than this never count as pinned: their shoulder scatter is too few samples to estimate the SE from
PINNED_MIN_FRAMES = 60
PINNED_SEQUENCE = {"sequence_fit_skeleton": True, "sequence_fit_root": True, "sequence_depth_huber_only": True,
                   "sequence_torso_pair_weight": 0.0, "sequence_tracker_weight": 10.0, "norm_limit": 0.05}


# The last per-frame pose refit (``CaptureOptions.pose_refit``): ``refine.refit_arm_poses_to_depth``'s keywords. The
# tracker's joints nearer the weight their noise warrants (10 mm per axis plus 3 % bone-length jitter per frame,
# against ~1-2 mm per depth pair) than the sequence fit's 30; each frame's angles weakly held to the sequence fit's.
# Chosen by the depth energy of held-out frames (``benchmarks.muscle_owners.heldout_energy_mm``), never the truth:
# lowest of the 8 settings tried on 501 / 504 / 507 / 508 (200 frames). Measured there (the joint fit, 20 % norm
# limit; docs/muscle.md eleventh pass), median / p90 mm 3.69 / 6.48, 4.19 / 7.10, 3.64 / 7.43, 3.94 / 7.90 -> 3.63 /
# 5.81, 3.64 / 5.81, 3.16 / 6.29, 3.40 / 7.03; ~33 ms CPU per frame.
POSE_REFIT = {"tracker_weight": 0.03, "prior_weight": 0.1, "iterations": 3}


#: The frame rate the capture's temporal filters were measured at (every synthetic arm session's). Their fields below
#: count frames at this rate (``sigma_frames``, ``pose_sigma_frames``, ...: a time in units of 1 / 30 s);
#: :func:`options_at_frame_rate` turns them into the recording's frames, so a 30 fps capture is the one measured.
CAPTURE_FPS = 30.0
#: Below this rate the temporal filters have nothing left to average (the refinement's Eq. 13-14 window of
#: sigma 1/30 s puts 1 % of its weight on the neighbouring frames at 10 fps, none below) and the model-based tracking
#: starts each frame from a previous one 100 ms or more away: a recording this slow is refused.
MIN_CAPTURE_FPS = 10.0
#: ... and above this it is no camera's (``capture import`` refuses it too).
MAX_CAPTURE_FPS = 240.0


@dataclass(frozen=True)
class CaptureOptions:
    """Switches and parameters of the whole pipeline (defaults: Kinect v2 at about 1 m).

    The temporal ones (``sigma_frames``, ``refine_window_frames``, ``detail_sigma_frames``, ``detail_window_frames``,
    ``pose_sigma_frames``, ``smooth_weight``, ``sequence_smooth_weight``, ``body_rest_frame_stride``) are times in
    frames at :data:`CAPTURE_FPS`; the capture turns them into the recording's frames
    (:func:`options_at_frame_rate`)."""

    mode: str = "full"  # full | nicp (no model, Fig. 6a) | model (no refinement)
    depth: DepthCleanupOptions = DepthCleanupOptions()
    nicp: NicpOptions = NicpOptions()
    first_frame_nicp_iterations: int = 12  # the first frame starts farther from the data
    shape_frames: int = 8  # frames at the start of the sequence the shape parameters are fitted on
    # shape/root fit alternated with those frames' joint angles. Measured (6k, 24 frames, measured shape,
    # tracker_pose_weight 30; subjects 2 / 5): 2 rounds -> 5.87 / 6.15 mm median, 4 -> 4.91 / 5.51, 6 worse.
    shape_rounds: int = 4
    # Eq. 12's displacement-norm limit (Sec. 8.2): every pose displacement cut at (1 - this) x the pose's largest. The
    # paper's 90 % left the biceps 10 % of its pose bulge (8.5 -> 0.9 mm at 90 deg flexion), which the sensor cannot
    # show at strong flexion (the forearm hides 82 % of the biceps at 80-120 deg). Measured (6k, 501, 200 frames,
    # measured shape, with refine_visible_only; docs/muscle.md sixth pass): 0.9 -> 0.5: bulge 1.72 -> 0.96 mm, median
    # 4.76 -> 4.71 mm; 24-frame subjects 5 / 602 (little flexion) within 0.1 mm. 0.5 -> 0.2 with the body rest shape and
    # the joint fit (the default below; docs/muscle.md tenth pass): with the placement right the model's biceps is
    # too low at strong flexion, and a smaller cut keeps more of the pose bulge (501's bulge 2.51 -> 1.91 mm).
    norm_limit: float = 0.2
    refine_pose: bool = True
    sigma_frames: float = 1.0  # Eq. 14
    refine_window_frames: int = 1  # Eq. 13's window: frames i-1, i, i+1
    refine_data_weight: float = 0.3  # measured (6k, 24 frames): 1.0 -> 0.3: 6.4 -> 6.2 mm, jitter 2.2 -> 1.8 mm
    refine_iterations: int = 4
    # Sec. 7 pairs only for vertices the model mesh itself does not hide from the sensor (a z-buffer of the mesh);
    # off: the front-side filter alone (Eq. 1, the normal), which pairs the hidden biceps with the forearm's points
    # in front of it and lifts it 3.5-4 mm at strong flexion. Measured (6k, 501, 200 frames, measured shape, norm
    # limit 0.9; docs/muscle.md sixth pass): median / p90 5.10 / 8.57 -> 4.76 / 7.73 mm, jitter +0.19 -> +0.15 mm,
    # bulge 1.21 -> 1.72 mm (the lift had hidden the norm limit's cut: norm_limit 0.5 takes it to 0.96 mm).
    refine_visible_only: bool = True
    # The vertices the sensor does not see (no Sec. 7 correspondence and facing away from it: ``hold_seen_vertices``)
    # held to the model mesh in the last ARAP (``refine.unseen_hold_weights``: this weight, 1 = one agreeing pair,
    # ramped in over ``refine_unseen_band_m`` from the nearest seen vertex). 0: off, the unseen side follows the seen
    # side's pull as a rigid piece, which made the full pipeline worse than the model stage once the pose refit put the
    # model on the depth. Chosen by data-side figures (the residual of held-out rim pairs, the held-out frames' depth
    # energy; ``benchmarks.muscle_refine_hold``); measured on the four 200-frame sessions (docs/muscle.md twelfth pass),
    # median / p90 / back mm, off -> 1: 501 3.63 / 5.81 / 4.35 -> 3.20 / 5.36 / 3.77, 504 3.64 / 5.81 / 4.12 -> 3.42 /
    # 5.35 / 3.76, 507 3.16 / 6.29 / 3.72 -> 2.83 / 5.75 / 3.21, 508 3.40 / 7.03 / 4.01 -> 3.28 / 6.22 / 3.68 (model
    # stage 3.21 / 5.38 / 3.72, 3.46 / 5.37 / 3.74, 2.90 / 5.75 / 3.17, 3.39 / 6.22 / 3.66); jitter +0.09-0.11 ->
    # +0.04-0.05 mm; bulge 1.58 / 1.13 / 0.57 / 0.72 -> 1.69 / 1.23 / 0.49 / 0.77 mm.
    refine_unseen_hold: float = 1.0
    refine_unseen_band_m: float = 0.02
    # Sec. 7 pairs dropped where the model vertex's normal meets the sensor's ray at |cos| below this (the rim of the
    # seen side, ``refine.edge_on_pairs``; 0: off), and the refinement's own depth clean-up: the median filter's
    # aperture (1: off, 3 or 5) and the Gaussian's sigma (px, 0: off) of the clouds its correspondences are made with
    # (``refinement_depth_options``; None: the pipeline's ``depth``, median 5 and Gaussian 1). Measured on 501 (200
    # frames; docs/muscle.md fourteenth capture pass): the seen side's error is 0.51 mm along the true normal and 2.46
    # mm tangential; the pipeline's filters put the face-on targets 0.54 mm behind the skin (smoothing a convex surface)
    # and the rim's (|cos| < 0.25) 3.5 mm outside it. The refinement averages its pairs over three frames (Eq. 13-14)
    # and its detail over five, so it needs less of the filters' noise removal. Chosen on 501 (a grid of 9 clean-ups and
    # 4 rim cuts), then held-out 504 / 507 / 508, median / p90 / front / bulge mm, off -> on: 501 3.29 / 5.48 / 2.65 /
    # 1.56 -> 3.20 / 5.41 / 2.54 / 1.22, 504 2.89 / 4.75 / 2.34 / 1.23 -> 2.84 / 4.68 / 2.24 / 0.73, 507 2.80 / 5.66 /
    # 2.47 / 0.31 -> 2.70 / 5.59 / 2.33 / 0.29, 508 3.18 / 6.25 / 2.79 / 0.70 -> 3.11 / 6.23 / 2.73 / 0.39; back and
    # jitter better on all four.
    refine_min_facing_cos: float = 0.35
    refine_depth_median_px: int | None = 1
    refine_depth_gaussian_sigma_px: float | None = 0.5
    detail_sigma_frames: float = 1.5  # refinement detail averaged over +-2 frames (0: off)
    detail_window_frames: int = 2
    joint_radius_m: float = 0.06  # Sec. 7.2 closeness-to-joint factor
    joint_gain: float = 1.0
    # Body-tracker joints in the shape fit, per coordinate vs 1 per depth pair. Measured (6k, subject 2,
    # 24 frames, fitted shape): weight 1 -> 15.5 mm median, 30 -> 9.9 mm, 100 -> 12.7 mm.
    tracker_weight: float = 30.0
    # With a known shape only the torso placement is fitted; there the tracker's noise costs more than it
    # helps (same sequence, known shape: weight 30 -> 7.5 mm, 1 -> 6.2 mm).
    tracker_root_weight: float = 1.0
    # ... and in each frame's joint angles. The error decomposition (true root / true angles plugged in,
    # docs/muscle.md) put the elbow 6-7 deg off with weight 10: the short, hand-blended forearm surface
    # barely constrains it, the tracker's wrist does. Measured (6k, 24 frames, subjects 2 / 5, 4 rounds):
    # 10 -> 5.97 / 6.41 mm median, 30 -> 4.91 / 5.51, 50 -> 4.73 / 5.19 (jitter +0.69 / +0.74), 100 worse.
    tracker_pose_weight: float = 30.0
    # Joint angles smoothed over +-5 frames (Gaussian, sigma in frames) before the refinement (0: off). Measured
    # (6k, measured shape; subjects 2 / 5 / 7 / 9 24 frames, 501 200 frames), sigma 1.5 over +-2 frames -> 2.5
    # over +-5: median 4.91 / 5.51 / 7.94 / 8.28 / 5.52 -> 4.73 / 5.37 / 7.82 / 8.29 / 5.37 mm, jitter
    # +0.52 / +0.63 / - / - / +0.78 -> +0.26 / +0.26 / +0.23 / +0.22 / +0.26 mm; sigma 4 worse on both 2 and 5.
    # Since the fifteenth pass (docs/muscle.md) a local quadratic over +-10 frames, sigma 5 (``pose_smoothing_degree``
    # 2): the mean at sigma 2.5 cut the flexion cycle's turning points (elbow hinge 0.6-0.8 deg off there).
    pose_sigma_frames: float = 5.0
    # The smoothing's polynomial degree: 0 the Gaussian-weighted mean, 2 a local quadratic over the same window
    # (``refine.smooth_arm_poses``), which keeps the motion's turning points. Measured (200 frames, noise seed 0,
    # sigma chosen on 501): the mean at sigma 2.5 -> the quadratic at sigma 5, median / p90 mm 501 2.62 / 4.64 ->
    # 2.40 / 4.20, 504 2.57 / 4.50 -> 2.43 / 4.26, 507 2.76 / 5.51 -> 2.58 / 5.33, 508 3.08 / 5.91 -> 3.10 / 5.85;
    # noise seeds used for no choice 501:1 2.47 / 4.69 -> 2.46 / 4.71, 501:2 2.25 / 4.18 -> 2.14 / 4.11; bulge and
    # jitter unchanged or lower.
    pose_smoothing_degree: int = 2
    # The shoulder rotation's own degree (None: ``pose_smoothing_degree``): 0 keeps the mean for the slow shoulder,
    # whose twist about the upper arm the quadratic leaves noisier. Measured (fifteenth pass, the four sessions): the
    # twist 0.1-0.3 deg truer, the capture not better (mean median / p90 2.63 / 4.91 -> 2.63 / 5.07 mm): off.
    shoulder_smoothing_degree: int | None = None
    # Fitted shape only: the arm length (a shape parameter) held near the tracker's shoulder-elbow-wrist chain
    # length averaged over every frame, per frame of the sequence (1 per depth pair). The depth's point-to-plane
    # pairs let the arm slide along itself, and the 8-frame tracker term left it 0.9-1.4 cm short. Measured (6k,
    # 24 frames, fitted shape, subjects 2 / 5 / 7): arm length 0.478 / 0.506 / 0.476 -> 0.497 / 0.510 / 0.480 m
    # (true 0.492 / 0.515 / 0.474), median 6.11 / 7.81 / 11.50 -> 6.35 / 7.79 / 11.23 mm, p90 12.69 / 16.68 /
    # 21.90 -> 10.66 / 14.09 / 21.13 mm; 3000 (nearly fixed) no better.
    tracker_arm_length_weight: float = 100.0
    # Fitted shape only: the shape fit's population prior (``refine.population_shape_prior``: the model's training
    # subjects of the run's sex, the height from the tracker's arm length), this weight per parameter in its spreads
    # (0: off, the paper's unregularised fit). Without it the 8 frames' fit moved with the noise seed (518: BMI 24.3 /
    # 23.4, height 1.607 / 1.475 m at seeds 0 / 1, true 20.4 / 1.582; 512 height 1.647 / 1.574, true 1.567): the arm's
    # depth hardly sees BMI, muscularity or height. Weight 0.1: the smallest at which the seeds' fits agree (0.1 and 1
    # within 0.1 BMI of each other; chosen on 518 / 512's shape fits alone). Measured end to end (docs/muscle.md
    # mus12a; no --shape, mixed model, 200 frames), median / p90 mm, off -> 0.1: 518:0 3.51 / 5.68 -> 2.12 / 3.94,
    # 518:1 5.61 / 11.32 -> 2.06 / 4.86 (518:2 2.21 / 3.97), 522:0 (held out) 4.40 / 9.40 -> 3.36 / 5.15, 516:2 3.74 /
    # 7.27 -> 3.46 / 6.35, 512:1 3.09 / 6.00 -> 3.39 / 5.54; men (100 frames) 501:0 2.74 / 4.80 -> 2.38 / 4.39, 507:0
    # 4.54 / 7.92 -> 3.63 / 6.38. A given shape (--shape) is not touched.
    shape_prior_weight: float = 0.1
    # Model-based tracking of the whole sequence after the per-frame fit (``refine.fit_arm_sequence``): the
    # torso placement and every frame's angles solved together (0 rounds: off).
    # Robust (Huber, scale in metres) residuals in the per-frame pose and shape/root fits (0: plain least
    # squares). Measured (6k, 24 frames, measured shape, subjects 2 / 5): 0.004 -> 4.73 / 5.37 mm median went to
    # 7.19 / 6.69: the tracker and prior residuals lose their pull. Off.
    huber_m: float = 0.0
    # Model-based tracking of the whole sequence after the per-frame fit (``refine.fit_arm_sequence``): every
    # frame's shoulder and elbow angles solved together against all frames' depth points and tracker joints,
    # with a second-difference prior (no lag) and Huber residuals, the torso placement held (0 rounds: off).
    # Measured (6k, 24 frames, measured shape; subjects 2 / 5 / 601 / 602 / 603), median mm: off 4.73 / 5.37 /
    # 9.35 / 7.99 / 7.54; 3 rounds (15 evaluations each) 4.42 / 5.14 / 9.19 / 7.48 / 7.12 (501, 200 frames:
    # 5.37 -> 5.10, p90 9.56 -> 8.58; more in docs/muscle.md); with the
    # placement fitted too (2 rounds) 4.08 / 5.46 / 10.09 / - / 10.25 (the root absorbs the out-of-range
    # subjects' model mismatch); without Huber residuals (placement fitted) 5.30 on subject 2.
    sequence_rounds: int = 3
    sequence_smooth_weight: float = 10.0
    sequence_huber_m: float = 0.004
    sequence_max_nfev: int = 15
    sequence_fit_root: bool = False
    # The tracker's joints in the sequence fit, per coordinate (1 per depth pair). None: weighted by their noise
    # (``capture.sequence_tracker_weight``: (depth sigma / tracker sigma)^2, both estimated from the data before each
    # sequence fit; ~0.1 then ~0.02 on the 200-frame sessions). Not the default: measured on the cached state of 501
    # / 507 (200 frames, with the pose refit; docs/muscle.md thirteenth capture pass) median / p90 mm 3.63 / 5.81,
    # 3.16 / 6.29 -> 3.57 / 5.77, 3.22 / 6.45; at 3: 3.62 / 5.81, 3.17 / 6.35. The depth pairs carry the rest arm's
    # error (on 507 they pull the elbow 1-2 mm towards the sensor), which the tracker's unbiased joints hold back.
    sequence_tracker_weight: float | None = 30.0
    # The tracker's joints in the body rest-shape fit (``refine.fit_body_rest_shape[_and_poses]``), per coordinate;
    # None: the sequence fit's (the two fits shared one weight before the thirteenth capture pass). The eleventh
    # pass's gain of ``sequence_tracker_weight=3`` on 501 was this fit's (cached state, with the refit: both at 3
    # 2.92 / 4.97 mm, the sequence fit alone at 3 3.62 / 5.81, default 3.63 / 5.81), and so was most of its loss on
    # 507 (3.30 / 6.86, 3.17 / 6.35, default 3.16 / 6.29); this fit alone at 3 / 10: 501 2.91 / 4.98, 3.20 / 5.34,
    # 507 3.24 / 6.74, 3.16 / 6.45 (the held-out depth energy prefers both on 507: it cannot see the back side).
    # 10 by default since the fourteenth pass (mus11o), with ``sequence_min_facing_cos=0.3``: measured together on the
    # four 200-frame sessions (median / p90 mm) 501 3.29 / 5.48 -> 2.70 / 4.72, 504 2.89 / 4.75 -> 2.63 / 4.57, 507
    # 2.80 / 5.66 -> 2.84 / 5.60, 508 3.18 / 6.25 -> 3.14 / 5.91 (mean 3.04 / 5.53 -> 2.83 / 5.20; the bulge error
    # 0.95 -> 1.10 mm, 501 over the 1.5 mm goal either way); this weight alone: 3.12 / 5.09, 2.74 / 4.68, 2.88 / 5.79,
    # 3.03 / 6.00 (docs/muscle.md, fourteenth pass, the rest arm). With the refinement's own depth and rim filter
    # (``refine_min_facing_cos`` above) as well, the default: 2.62 / 4.64, 2.57 / 4.50, 2.76 / 5.51, 3.08 / 5.91, mean
    # 2.76 / 5.14, bulge 1.43 / 0.86 / 0.43 / 0.69 (docs/muscle.md, "the two branches together").
    body_rest_tracker_weight: float | None = 10.0
    # The subject's skeleton (rest shoulder, elbow, wrist; the elbow hinge with them) fitted once per sequence
    # with every frame's angles in the sequence fit (``refine.fit_arm_sequence_skeleton``), held to the
    # model's regression by ``sequence_skeleton_prior_weight`` per coordinate (1 per depth pair). Off: measured
    # (6k, 24 frames, measured shape, docs/muscle.md "fourth pass"), with the placement fitted and Huber on the
    # depth only, median 5 / 7 / 601 / 602 / 603 / 604: 5.13 / 7.09 / 9.21 / 7.48 / 7.12 / 11.16 -> 6.63 / 3.28 /
    # 9.43 / 4.51 / 9.69 / 6.56 mm: 3 subjects better, 3 worse; the dataset extension -0.0 -> -7.2 % (set A).
    sequence_fit_skeleton: bool = False
    sequence_skeleton_prior_weight: float = 100.0
    sequence_free_joints: tuple = (True, True, True)  # shoulder, elbow, wrist: which rest joints are fitted
    # Huber weights (IRLS) on the depth pairs only, the tracker, prior and skeleton terms quadratic. On by default
    # (the thread count pass, docs/muscle.md "Capture, the thread count"): with scipy's Huber loss on every residual
    # the sequence fit's trf stopped at its evaluation limit in every call (15, 50 or 200 alike), so its result was
    # wherever the optimiser happened to be and a 1e-12 m input change moved the 4-frame capture by 5.5 mm; with
    # IRLS it stops on ftol after 5-10 evaluations and the same change moves it 5e-5 mm
    # (``benchmarks/muscle_sequence_stability.py``). 6k, 200 frames, median / p90 mm (``muscle_sequences``, "hub"):
    # 501 3.20 / 5.35 -> 3.29 / 5.48, 504 3.42 / 5.33 -> 2.89 / 4.75, 507 2.83 / 5.73 -> 2.80 / 5.66, 508 3.29 / 6.21
    # -> 3.18 / 6.25 (mean 3.18 / 5.66 -> 3.04 / 5.54); CPU 852 -> 570 ms per frame.
    sequence_depth_huber_only: bool = True
    # The chest's (torso part's) depth pairs in the sequence fit, scaled by this weight (1: as the arm's). A model
    # whose chest does not match the subject's drags the fitted placement. Measured with the fourth pass's variant
    # (skeleton and placement fitted, Huber on the depth only; 6k, 24 frames, measured shape; docs/muscle.md, fifth
    # pass), median mm of 5 / 7 / 602 / 603: 6.63 / 3.28 / 4.51 / 9.69 -> 6.81 / 3.33 / 4.55 / 8.51 at 0, and with
    # sequence_tracker_weight 10 too 6.48 / 3.08 / 4.34 / 8.48 (better than that variant on all four, and on two
    # more noise seeds of 5 and one of 603), but the default (5.13 / 7.09 / 7.53 / 7.12) stays: 603 loses.
    sequence_torso_pair_weight: float = 1.0
    # The placement tied to the tracker's sequence-mean shoulder by one prior, weight (this / SE)^2 per coordinate
    # with SE the mean's standard error from the tracked shoulder's scatter (``refine.tracker_placement_prior_weight``),
    # and each frame's tracker joints counted relative to the tracker's mean shoulder (they inform the angles and
    # bones, not the placement). 0: off, the tracker's joints are absolute observations every frame.
    sequence_placement_prior_m: float = 0.0
    # A sequence whose tracker pins the torso placement (the standard error of the tracker's sequence-mean shoulder,
    # ``refine.tracker_mean_standard_error``, at most this many metres; ~120 frames or more of the Kinect v2's
    # 10-12 mm per-frame noise: 1.2 mm) is captured with :data:`PINNED_SEQUENCE`, which then replaces those six
    # fields; a shorter or noisier one (24 frames: SE 1.9-2.6 mm; under ``PINNED_MIN_FRAMES`` frames always), or one
    # without tracker joints, keeps the fields as given. 0: off (the default). Measured at 0.0012 (6k, 200 frames,
    # measured shape; docs/muscle.md seventh pass), median mm of 501 seeds 0 / 1, 504, 507, 508: 4.61 / 5.30 / 5.47 /
    # 4.74 / 6.44 -> 3.15 / 3.12 / 5.10 / 4.22 / 8.72: four better, 508 (the model's floor 5.25 mm) 2.3 mm worse.
    sequence_pinned_se_m: float = 0.0
    # Per-subject rest shape (``refine.fit_rest_shape_correction``: population PCA over all frames' depth, poses
    # held) alternated with the sequence fit, this many rounds (0: the model's rest mesh). Off: 2 rounds gave
    # 5 / 601 / 602 / 603 / 604 5.13 / 9.21 / 7.48 / 7.12 / 11.16 -> 5.24 / 9.58 / 6.78 / 7.39 / 10.50 mm and the
    # extension -0.1 % (set A).
    personal_rounds: int = 0
    personal_prior_weight: float = 0.05
    # Rest arm and skeleton from the body model's own shape space (``model.body_shape_space``): the regressed rest
    # mesh (Eq. 6-9) projected into it (``model.project_to_body_space``: the subject's MakeHuman macro parameters and
    # local arm, shoulder and torso target weights), its joints MakeHuman's for that shape; then ``body_rest_rounds``
    # rounds of ``refine.fit_body_rest_shape`` (the parameters fitted to the depth with the poses held, the projection
    # as the prior's centre) alternated with the sequence fit. Off: the model's rest mesh and regressed joints.
    # Measured (6k, 200 frames, measured shape, Kinect v2 at 1 m; docs/muscle.md eighth pass), median / p90 mm of
    # 501 / 504 / 507 / 508: default 4.61 / 7.74, 5.47 / 9.07, 4.74 / 7.99, 6.44 / 13.45; 2 rounds at prior 100
    # 3.52 / 6.29, 5.57 / 8.15, 7.65 / 12.95, 4.48 / 7.88 (507 loses), the bulge error on 501 1.06 -> 1.75 mm (goal
    # 1.5), ~900 ms CPU per frame. Projection only: 501 4.41 / 7.60, 504 5.98 / 9.79. On by default (2 rounds) with
    # the joint fit of the poses below and norm_limit 0.2 (docs/muscle.md tenth pass).
    body_rest_shape: bool = True
    body_rest_rounds: int = 2
    body_rest_prior_weight: float = 100.0  # per frame, one population standard deviation vs a pair 1 mm off
    # The prior's spread of the body space's local target weights: with ``body_rest_population_locals`` > 0 the body
    # population's own spread times it on the targets the population varies and ``body_rest_local_sigma`` on the 84
    # others (``model.population_local_sigma``); with 0, ``body_rest_local_sigma`` on every target (0.25,
    # ``model.BODY_LOCAL_PRIOR_SIGMA``: the prior before the fifteenth pass). Every target at one spread, the fit
    # explained the seen front with targets no subject of the population carries (the neck moved down, the forearm
    # narrowed, the torso's depth shrunk) and the shoulder's unseen back, armpit and deltoid followed them 2-4 mm inside
    # the skin: the vertex-frames over 5 mm on 507 / 508 (docs/muscle.md, fifteenth pass, mus11r). Measured (200
    # frames, median / p90 mm, before -> 1.0 with 0.1): 501 2.62 / 4.64 -> 2.41 / 4.24, 504 2.57 / 4.50 -> 2.31 / 4.26,
    # 507 2.76 / 5.51 -> 2.36 / 5.02, 508 3.08 / 5.91 -> 3.06 / 5.96 (mean 2.76 / 5.14 -> 2.54 / 4.87); used for no
    # choice: subject 513 3.73 / 6.16 -> 3.50 / 5.75, 501's noise seed 1 2.47 / 4.69 -> 2.38 / 4.66. 0.05 for the
    # others: 507 2.13 / 4.70 but 508 3.26 / 6.20 (its upper arm 3.4 population sd fat); every target at 0.1: 507
    # 2.71 / 6.12, 508 4.21 / 9.02.
    # Since the sixteenth pass (with the outline pairs below) the population's spread doubled: the outline says how far
    # from the population's middle the arm's girth is, so the prior may let it go (docs/muscle.md, sixteenth pass).
    body_rest_local_sigma: float = 0.1
    body_rest_population_locals: float = 2.0
    body_rest_iterations: int = 3  # Gauss-Newton steps per round (re-paired each)
    body_rest_frame_stride: int = 4  # every this-many-th frame enters the rest-shape fit (it is shared)
    body_rest_arm_length_weight: float = 100.0  # measured arm length (known shape), per frame, vs one depth pair
    body_rest_fit_placement: bool = True  # the shared torso translation solved with the rest shape
    # The strided frames' joint angles solved with the rest shape in one Gauss-Newton
    # (``refine.fit_body_rest_shape_and_poses``) instead of held (docs/muscle.md, ninth pass). Measured (6k, 200
    # frames, measured shape, 2 rounds), median / p90 mm of 501 / 504 / 507 / 508: default 4.61 / 7.74, 5.47 / 9.07,
    # 4.74 / 7.99, 6.44 / 13.45 -> 3.72 / 6.52, 4.21 / 7.12, 3.64 / 7.43, 3.97 / 7.89, but 501's bulge error 1.06 ->
    # 2.51 mm (goal 1.5). The default, with norm_limit 0.2 (end to end: 3.69 / 6.46, 4.19 / 7.10, 3.63 / 7.45,
    # 3.94 / 7.89 mm; bulge 1.91 / 1.07 / 1.12 / 0.74 mm, 501 over the 1.5 mm goal; docs/muscle.md tenth pass).
    body_rest_fit_poses: bool = True
    # Rounds of the rest-shape fit stop when the depth energy (``refine.depth_energy_mm`` of the sequence fit's
    # meshes on the frames the rest-shape fit does not use) stops falling, and the round with the lowest energy is
    # kept (a data-side choice, never the truth). Measured (200 frames, docs/muscle.md ninth pass): 507's second
    # round raised it (every 4th frame: 2.49 -> 2.70 mm) while the error rose 4.90 -> 7.65 mm (model stage; bones
    # 4-6 mm too long).
    body_rest_keep_best: bool = True
    body_rest_angle_damping: float = 1.0  # per angle coordinate times a 0.3 m lever, per Gauss-Newton step
    # The grazing pairs left out of the rest-shape fit (``refine.grazing_pairs``: vertices whose normal makes less
    # than this cosine with the direction to the sensor; 0: off). Near a limb's silhouette the cleaned depth stops
    # short of the surface and a grazing vertex's pair plane lies outside the convex limb (501, the truth's own
    # vertices at cos < 0.3: 4.6 mm behind their pairs' planes, mean), which pulls the fitted arm's sides outwards
    # (docs/muscle.md, fourteenth pass, rest arm). ``sequence_min_facing_cos``: the same in the fits of the poses (the
    # sequence fit and the last pose refit). Measured (200 frames, median / p90 mm, bulge): the rest fit's at 0.3 takes
    # 501's rest arm 3.09 -> 2.77 mm but the capture 3.29 / 5.48 -> 3.49 / 6.05; the pose fits' at 0.3: 501 3.10 /
    # 5.25, 504 2.84 / 4.77, 507 2.82 / 5.44, 508 3.26 / 6.19 (default 3.29 / 5.48, 2.89 / 4.75, 2.80 / 5.66, 3.18 /
    # 6.25), the bulge error up on all four (mean 0.95 -> 1.08). The rest fit's off; the pose fits' 0.3 by default
    # since the fourteenth pass (mus11o), with ``body_rest_tracker_weight=10``: the figures there.
    body_rest_min_facing_cos: float = 0.0
    sequence_min_facing_cos: float = 0.3
    # Outline pairs in the rest-shape fit (``refine.outline_pairs``: each rim vertex of the arm region against the raw
    # depth map's occluding contour along its normal's image direction; 0: off), per pair relative to a depth pair,
    # each target moved ``body_rest_outline_offset_m`` outwards (the contour's bias: on the truth's own rim of 501 /
    # 504 / 507 it lies 0.37-0.40 mm inside, mean over every 5th frame's rim vertices). The
    # sensor sees the upper arm's sides edge-on: their outline bounds the arm's girth where no depth pair reaches
    # (docs/muscle.md, sixteenth pass). Measured (200 frames, median / p90 mm, the fifteenth pass's default -> weight 1
    # with the population's spread doubled): 501 2.18 / 3.94 -> 1.65 / 3.75, 504 2.31 / 4.21 -> 1.95 / 3.63, 507 2.20 /
    # 4.89 -> 2.13 / 4.34, 508 3.11 / 5.93 -> 2.10 / 3.75; used for no choice: 513 3.62 / 5.88 -> 2.85 / 4.81.
    body_rest_outline_weight: float = 1.0
    body_rest_outline_offset_m: float = 0.0004
    smooth_weight: float = 10.0  # joint angles held near the previous frame's (per coordinate, 0.3 m lever)
    # Sec. 5.1's scale: off by default. Point-to-point pairs of a one-sided view shrink the template
    # (measured: scale 0.77, 38 mm median error on the first frame vs 14 mm rigid); the model's shape
    # parameters (height, arm length) carry the subject's size instead.
    with_scale: bool = False
    # Rotation likewise: a one-sided view of a near-cylinder leaves the roll about the arm free
    # (measured: 18 deg roll, 18 -> 25 mm on the first frame; translation only: 18 -> 15.5 mm).
    with_rotation: bool = False
    # A last per-frame refit of the shoulder and elbow angles against each frame's depth on the rest arm and skeleton
    # the sequence stage settled on (``refine.refit_arm_poses_to_depth`` with :data:`POSE_REFIT`), before the pose
    # smoothing (docs/muscle.md, eleventh pass). On by default: end to end on the four held-out 200-frame sessions
    # (`benchmarks.muscle_sequences ... --variant "refit:pose_refit=True"`) median / p90 mm 501 3.69 / 6.46 -> 3.62 /
    # 5.79, 504 4.19 / 7.10 -> 3.64 / 5.83, 507 3.63 / 7.45 -> 3.16 / 6.28, 508 3.94 / 7.89 -> 3.40 / 7.01; bulge 1.91
    # / 1.07 / 1.12 / 0.74 -> 1.59 / 1.13 / 0.57 / 0.72 mm; jitter +0.09-0.11 mm; 760-776 ms CPU per frame.
    pose_refit: bool = True
    # At a rate other than 30 fps, the pose smoothing (``pose_sigma_frames``) and the two pose priors
    # (``smooth_weight``, ``sequence_smooth_weight``) kept at their frame values, the refinement's windows and the
    # rest fit's stride still scaled (:func:`options_at_frame_rate`). Off: every temporal filter keeps its width in
    # seconds. Measured (round rel5b, docs/muscle.md "Frame rate"; 200 frames at 30 fps sampled at 15, median / p90
    # mm; chosen on 501, 504 and 507 held out): all in time 1.80 / 3.57, 2.13 / 3.92, 2.70 / 5.58 -> this 1.71 / 3.11,
    # 2.09 / 3.48, 2.71 / 5.36 (30 fps: 1.65 / 3.75, 1.95 / 3.63, 2.13 / 4.34); half the frames in a window average
    # half the noise, which a window twice as long in time makes up for on this slow motion. Off by default: three
    # sessions of one motion and one noise seed, and at 10 fps it spans three times the time (a faster motion's turning
    # points are cut).
    pose_filters_per_frame: bool = False
    # Without the subject's shape (``known_shape``, ``--shape``) and with a model that knows women, the capture is run
    # as a man and as a woman from the Sec. 6.2 shape fit through the sequence stage, and the sex whose model meshes
    # explain the held-out frames' depth better (:func:`held_out_depth_energy_mm`) is kept (:func:`candidate_sexes`,
    # :func:`sex_from_depth_energies`); two energies within ``sex_margin_mm`` are recorded as ambiguous (the capture
    # warns). Off: the subject taken as male (the paper's), as with an all-male model. Measured (docs/muscle.md, "The
    # sex from the depth"; mixed model, 100 frames, no --shape), the energies as a man / as a woman, mm: the women
    # 512 4.48 / 3.45, 516 3.91 / 3.63, 518 3.62 / 3.27 (median 10.70 / 5.37, 6.95 / 3.33, 7.30 / 3.76 mm); the men
    # 501 3.51 / 4.83, 504 3.94 / 5.04, 507 3.75 / 5.02 (kept male: the capture as before). The evidence of the first 8
    # frames' shape fit alone took 504 and 519 for women (0.7 / 1.5 mm the wrong way), that of the sequence fit's first
    # round 518 for a man. The margin: a third of the smallest gap of those seven, 516's 0.28 mm.
    sex_from_depth: bool = True
    sex_margin_mm: float = 0.1

    def __post_init__(self):
        if self.mode not in MODES:
            raise InputError(f"capture mode {self.mode!r} is not one of {', '.join(MODES)}")
        if not 0 < self.norm_limit <= 1:
            raise InputError(f"norm_limit must be in (0, 1], got {self.norm_limit}")
        if self.refine_depth_median_px not in (None, 1, 3, 5):
            raise InputError(f"refine_depth_median_px must be 1 (off), 3 or 5, got {self.refine_depth_median_px}")
        if self.refine_depth_gaussian_sigma_px is not None and not self.refine_depth_gaussian_sigma_px >= 0:
            raise InputError(f"refine_depth_gaussian_sigma_px must be >= 0, got {self.refine_depth_gaussian_sigma_px}")
        if not 0 <= self.refine_min_facing_cos < 1:
            raise InputError(f"refine_min_facing_cos must be in [0, 1), got {self.refine_min_facing_cos}")
        if not (self.refine_unseen_hold >= 0 and self.refine_unseen_band_m >= 0):
            raise InputError(f"refine_unseen_hold and refine_unseen_band_m must be >= 0, got "
                             f"{self.refine_unseen_hold} and {self.refine_unseen_band_m}")
        if self.sigma_frames <= 0 or self.shape_frames < 1:
            raise InputError("sigma_frames must be > 0 and shape_frames >= 1")
        for name in ("refine_window_frames", "detail_window_frames"):
            window = getattr(self, name)
            if isinstance(window, bool) or not isinstance(window, int | np.integer) or window < 1:
                raise InputError(f"{name} must be a whole number of frames >= 1, got {window!r}")
        if self.sequence_rounds < 0 or self.sequence_huber_m < 0 or self.huber_m < 0:
            raise InputError("sequence_rounds, sequence_huber_m and huber_m must be >= 0")
        if not self.sequence_placement_prior_m >= 0:
            raise InputError(f"sequence_placement_prior_m must be >= 0, got {self.sequence_placement_prior_m}")
        if not self.sequence_torso_pair_weight >= 0:
            raise InputError(f"sequence_torso_pair_weight must be >= 0, got {self.sequence_torso_pair_weight}")
        if not (self.body_rest_local_sigma > 0 and self.body_rest_population_locals >= 0):
            raise InputError(f"body_rest_local_sigma must be > 0 and body_rest_population_locals >= 0, got "
                             f"{self.body_rest_local_sigma} and {self.body_rest_population_locals}")
        if self.body_rest_rounds < 0 or self.body_rest_frame_stride < 1 or not self.body_rest_prior_weight > 0:
            raise InputError("body_rest_rounds must be >= 0, body_rest_frame_stride >= 1, body_rest_prior_weight > 0")
        if self.personal_rounds > 0 and self.body_rest_shape and self.body_rest_rounds > 0:
            raise InputError("personal_rounds and the body rest shape's rounds are two rest-shape fits and only one "
                             "runs; set body_rest_shape=False to use personal_rounds")
        if not (self.body_rest_outline_weight >= 0 and abs(self.body_rest_outline_offset_m) <= 0.01):
            raise InputError(f"body_rest_outline_weight must be >= 0 and body_rest_outline_offset_m within +-0.01 m, "
                             f"got {self.body_rest_outline_weight} and {self.body_rest_outline_offset_m}")
        if not (0 <= self.body_rest_min_facing_cos < 1 and 0 <= self.sequence_min_facing_cos < 1):
            raise InputError(f"body_rest_min_facing_cos and sequence_min_facing_cos must be in [0, 1), got "
                             f"{self.body_rest_min_facing_cos} and {self.sequence_min_facing_cos}")
        for name in ("pose_smoothing_degree", "shoulder_smoothing_degree"):
            degree = getattr(self, name)
            if degree is None and name == "shoulder_smoothing_degree":
                continue
            if isinstance(degree, bool) or not isinstance(degree, int | np.integer) or not 0 <= degree <= 3:
                raise InputError(f"{name} must be 0 (the Gaussian mean), 1, 2 or 3, got {degree!r}")
        if not self.pose_sigma_frames >= 0:
            raise InputError(f"pose_sigma_frames must be >= 0 (0: no smoothing), got {self.pose_sigma_frames}")
        if not self.sequence_pinned_se_m >= 0:
            raise InputError(f"sequence_pinned_se_m must be >= 0, got {self.sequence_pinned_se_m}")
        if not self.shape_prior_weight >= 0:
            raise InputError(f"shape_prior_weight must be >= 0 (0: no prior on the fitted shape), got "
                             f"{self.shape_prior_weight}")
        if not self.sex_margin_mm >= 0:
            raise InputError(f"sex_margin_mm must be >= 0 (the held-out depth energies' difference below which the sex "
                             f"from the depth is ambiguous), got {self.sex_margin_mm}")


def options_at_frame_rate(options: CaptureOptions, fps: float, source: str = "the recording") -> CaptureOptions:
    """``options`` for a recording at ``fps``: every temporal field (a time in frames at :data:`CAPTURE_FPS`) in the
    recording's frames; ``options`` itself at 30 fps (the measured capture, bit for bit).

    The Gaussian windows keep their width in seconds (Eq. 14's sigma, the refinement detail's, the pose smoothing's,
    whose reach follows its sigma), and the windows' reach too (at least one frame each side). The previous-frame
    prior of the per-frame fit (``smooth_weight``) is an exponential smoother whose time constant is ~weight / data
    frames: its weight scales with the rate. The sequence fit's second-difference prior is a smoothing spline whose
    width in frames goes as weight^(1/4): its weight scales with the rate^4. The rest-shape fit takes every
    ``body_rest_frame_stride``-th frame: the same spacing in seconds. ``shape_frames`` stays a count: it is how many
    depth frames the shape fit sees, not a filter. ``options.pose_filters_per_frame`` (off): the pose smoothing and
    the two pose priors keep their frame values. A rate outside [:data:`MIN_CAPTURE_FPS`,
    :data:`MAX_CAPTURE_FPS`] is refused (InputError naming ``source``)."""
    if not (np.isfinite(fps) and MIN_CAPTURE_FPS <= fps <= MAX_CAPTURE_FPS):
        low = np.isfinite(fps) and fps < MIN_CAPTURE_FPS
        why = (f"below the {MIN_CAPTURE_FPS:g} fps the arm capture's temporal filters need (Eq. 13-14's window, the "
               "pose smoothing and the model-based tracking span 1/30 s and more); record at 15 fps or more"
               if low else f"not a depth camera's rate ({MIN_CAPTURE_FPS:g}-{MAX_CAPTURE_FPS:g} fps); fix the "
               "session's metadata.fps (bodystudio capture import records it from the frame times)")
        raise InputError(f"{source}: recorded at {fps:g} fps, {why}")
    if fps == CAPTURE_FPS:
        return options
    s = float(fps) / CAPTURE_FPS
    o = options
    pose = {} if o.pose_filters_per_frame else dict(
        pose_sigma_frames=o.pose_sigma_frames * s, smooth_weight=o.smooth_weight * s,
        sequence_smooth_weight=o.sequence_smooth_weight * s ** 4)
    return replace(o, sigma_frames=o.sigma_frames * s,
                   refine_window_frames=max(1, round(o.refine_window_frames * s)),
                   detail_sigma_frames=o.detail_sigma_frames * s,
                   detail_window_frames=max(1, round(o.detail_window_frames * s)),
                   body_rest_frame_stride=max(1, round(o.body_rest_frame_stride * s)), **pose)


def capture_frame_rate(session) -> float:
    """The session's recorded frame rate (``metadata.fps``: synthetic sessions, imports with frame times), or
    :data:`CAPTURE_FPS` when it records none (readers assume 30). A rate that is no number, or outside
    [:data:`MIN_CAPTURE_FPS`, :data:`MAX_CAPTURE_FPS`], is refused naming the session (InputError)."""
    metadata = getattr(session, "metadata", None)
    fps = metadata.get("fps") if isinstance(metadata, dict) else None
    if fps is None:
        return CAPTURE_FPS
    source = f"{session.path}"
    if isinstance(fps, bool) or not isinstance(fps, int | float):
        raise InputError(f"{Path(session.path) / 'session.json'}: metadata.fps {fps!r} is not a frame rate; fix it "
                         "or re-import the recording (bodystudio capture import records it from the frame times)")
    options_at_frame_rate(CaptureOptions(), float(fps), source)  # refuses a rate the filters cannot serve
    return float(fps)


@dataclass
class ArmCapture:
    """A captured arm sequence: per-frame meshes in the template's topology, poses, shape, timings."""

    vertices: np.ndarray  # (T, n, 3) world metres
    faces: np.ndarray  # (m, 3)
    poses: list  # ArmPose per frame, in the template's space (None in mode "nicp")
    shape: object | None  # ArmShapeParams (None in mode "nicp")
    similarity: tuple  # (s, R, t): template space -> world (Sec. 5.1)
    mode: str
    template_key: str
    timings_ms: dict = field(default_factory=dict)  # step -> total milliseconds over the sequence
    frame_ids: list = field(default_factory=list)
    session_path: str | None = None  # the captured session (set by capture_arm_sequence)
    stages: dict = field(default_factory=dict)  # "nicp" / "model": (T, n, 3) world meshes of the earlier steps
    # Rest shoulder, elbow, wrist (3, 3) in the template's space that ``poses`` turn about (the subject's fitted
    # skeleton; the rest mesh sits at the model's regressed shoulder). None: the model's regressed joints.
    joints: np.ndarray | None = None
    # sha256 over the captured frames' depth files (capture.session.stream_fingerprint): which recording this is
    source_fingerprint: str | None = None
    # (3, 3) the rest joints the capture's model regresses for ``shape`` (where its rest mesh sits): the
    # extension's "regressed" centre, kept so that extending another model (a later one) still uses these
    regressed_joints: np.ndarray | None = None
    # the capture's self-check (muscle.plausibility.check_after_capture): figures, warnings, problems
    plausibility: dict | None = None
    # the subject's sex chosen from the depth (no --shape, a model that knows women): :func:`sex_from_depth_energies`
    sex_fit: dict | None = None
    # rel7a: each captured frame's position in the captured range (None: 0..T-1, nothing skipped), and the frames
    # skipped as bad (:func:`read_arm_frames`): ``[{"frame", "position", "file", "why"}]``; a skipped frame has no
    # mesh and no pose (never a neighbour's copy)
    frame_positions: list | None = None
    skipped: list = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return len(self.vertices)

    @property
    def ms_per_frame(self) -> float:
        return float(sum(self.timings_ms.values()) / max(self.n_frames, 1))

    @property
    def positions(self) -> list[int]:
        """Each captured frame's position in the captured range (its mesh is ``meshes/{position:05d}.ply``)."""
        return list(range(self.n_frames)) if self.frame_positions is None else [int(p) for p in self.frame_positions]

    def is_from(self, session) -> bool | None:
        """Whether ``session`` holds the recording this was captured from (its captured frames' depth files
        have the recorded fingerprint); None when unknown (a capture written before the fingerprint existed)."""
        if self.source_fingerprint is None:
            return None
        from bodystudio.capture.session import stream_fingerprint

        return stream_fingerprint(session, "kinect_depth", self.frame_ids) == self.source_fingerprint


class _Timer:
    def __init__(self):
        self.ms: dict[str, float] = {}

    def add(self, step: str, t0: float) -> float:
        t1 = time.perf_counter()
        self.ms[step] = self.ms.get(step, 0.0) + 1000.0 * (t1 - t0)
        return t1


def _shifted(pose: ArmPose, translation: np.ndarray) -> ArmPose:
    root = pose.root.copy()
    root[:3, 3] += translation
    return ArmPose(root, pose.angles)


def _inverse_similarity(S):
    s, R, t = S
    return (1.0 / s, R.T, -(R.T @ t) / s)


def sequence_options(options: CaptureOptions, tracker_joints: np.ndarray) -> CaptureOptions:
    """The options a sequence is captured with: :data:`PINNED_SEQUENCE` over ``options`` when the tracker's
    sequence-mean shoulder has a standard error of at most ``options.sequence_pinned_se_m`` (the whole-sequence fit
    can then share one placement and skeleton across frames without taking on the tracker's sample mean; Sec. 6.2's
    per-frame fit extended over the sequence), else ``options`` unchanged."""
    se_max, tracker = options.sequence_pinned_se_m, np.asarray(tracker_joints, np.float64)
    if se_max > 0 and len(tracker) >= PINNED_MIN_FRAMES and tracker_mean_standard_error(tracker) <= se_max:
        return replace(options, **PINNED_SEQUENCE)
    return options


def capture_arm_frames(depths: list[np.ndarray], camera, template: ArmTemplate, model=None,
                       options: CaptureOptions = CaptureOptions(), tracker_joints: np.ndarray | None = None,
                       frame_ids: list | None = None, known_shape=None, fps: float = CAPTURE_FPS,
                       depth_sources: list[str] | None = None, frame_positions: list[int] | None = None,
                       ) -> ArmCapture:
    """The Arm-Muscle Capture pipeline on depth maps (metres, 0 = none) of one depth ``camera``.

    ``tracker_joints`` (T, 3, 3): shoulder, elbow, wrist per frame from the body tracker (world). The
    first frame's start the alignment when the arm is not in the base pose (without them the template
    starts in its base pose at the cloud's centroid, as the paper's Sec. 5.1 prescribes for the
    subject); the first ``shape_frames`` inform the arm length in the shape fit.
    ``known_shape`` (ArmShapeParams): the subject's measured BMI, muscularity, height and arm length
    (the paper's Table 1 lists them per subject); only the torso placement is then fitted.
    ``fps``: the recording's frame rate; the options' temporal fields are times at 30 fps
    (:func:`options_at_frame_rate`; a rate below 10 fps is refused). ``depth_sources``: each depth map's file, named
    in the errors (default "depth frame N").
    ``frame_positions``: each depth map's frame number in the recording (increasing) when bad frames were skipped
    (:func:`read_arm_frames`, rel7a); the temporal filters then weigh neighbours by their distance in recorded frames
    (Eq. 13-14's window, the refinement detail's, the pose smoothing, the sequence fit's second differences), the
    previous-frame prior of the frame after a gap is weakened by the gap (a random walk's variance grows with it),
    and that frame's non-rigid ICP starts from the mesh before the gap (logged). None: consecutive frames.
    """
    o = options_at_frame_rate(options, fps)
    if o.mode != "nicp" and model is None:
        raise InputError(f"capture mode {o.mode!r} needs a statistical arm model; pass one or use mode 'nicp'")
    if model is not None and getattr(model, "template_key", template.key) != template.key:
        raise InputError(f"the arm model was built for template {model.template_key}, not {template.key}; "
                         "rebuild the model for this template resolution/side")
    if len(depths) == 0:
        raise InputError("no depth frames to capture")
    if model is not None and tracker_joints is not None and len(tracker_joints) == len(depths):
        o = sequence_options(o, tracker_joints)
    timer = _Timer()
    F = np.asarray(template.faces, np.int64)
    W = template.part_weights
    arm = template.arm_mask
    shape = sex_fit = None
    if model is not None:
        # The model's own mesh at the population's mean shape is the template (the paper's base mesh).
        from bodystudio.muscle.model import ArmShapeParams, model_joints, model_rest_vertices
        from bodystudio.muscle.refine import _shape_bounds

        shape = known_shape or ArmShapeParams.from_vector(_shape_bounds(model, None)[2])
        base, J = model_rest_vertices(model, shape), model_joints(model, shape)
    else:
        base, J = template.vertices, template.joints
    adjacency = vertex_neighbourhoods(F, len(base), rings=2)
    ids = list(range(len(depths))) if frame_ids is None else list(frame_ids)
    positions = frame_gaps = None
    if frame_positions is not None:
        positions = np.asarray(frame_positions, np.int64)
        if positions.shape != (len(depths),) or np.any(np.diff(positions) < 1):
            raise InputError(f"frame_positions: {len(depths)} increasing frame numbers, one per depth map")
        frame_gaps = np.r_[1, np.diff(positions)]
        if np.all(frame_gaps == 1):
            positions = frame_gaps = None  # consecutive: the capture as without them, bit for bit
    gap_kw = {} if positions is None else {"positions": positions}  # the steps' calls as before without a gap

    # Sec. 4: clean-up and point clouds of every frame (world coordinates).
    clouds = []
    for k, d in enumerate(depths):
        t0 = time.perf_counter()
        source = f"depth frame {ids[k]}" if depth_sources is None else str(depth_sources[k])
        if k and np.ndim(d) == 2 and np.count_nonzero(segment_by_distance(d, o.depth.near_m, o.depth.far_m)) \
                < o.depth.min_pixels:
            # the frames before had the arm: it left the view (rel6b: "move the subject to about 1 m" misled)
            raise InputError(f"{source}: no arm in the {o.depth.near_m:g}-{o.depth.far_m:g} m depth window in frame "
                             f"{ids[k]}, though the {k} frame(s) before had it: the arm left the view; capture the "
                             f"first {k} frames (--frames {k}) or record the arm in view throughout")
        dc = clean_depth(d, o.depth, source=source)
        P, N = depth_point_cloud(dc, camera, source=source)
        if len(P) < o.depth.min_pixels:
            raise InputError(f"{source}: {len(P)} usable depth points; no arm in range")
        clouds.append((P, N))
        timer.add("depth", t0)

    # Sec. 5.1: similarity of the (started) template onto the first cloud, for the whole sequence.
    t0 = time.perf_counter()
    C_world = camera.center
    if tracker_joints is not None:
        tracker_joints = np.asarray(tracker_joints, np.float64).reshape(-1, 3, 3)
        if len(tracker_joints) != len(depths):
            raise InputError(f"{len(tracker_joints)} tracker joint frames for {len(depths)} depth frames")
        pose0 = initial_arm_pose_from_joints(J, tracker_joints[0])
    else:
        pose0 = ArmPose.rest()
    posed0 = pose_arm(base, W, J, ArmPose(np.eye(4), pose0.angles))
    P0 = clouds[0][0]
    start_t = (tracker_joints[0, 0] - J[0]) if tracker_joints is not None else None
    initial = None if start_t is None else (1.0, np.eye(3), start_t)
    S = rigid_alignment_with_scale(posed0, F, P0, C_world, arm, initial=initial, with_scale=o.with_scale,
                                   with_rotation=o.with_rotation)
    Sinv = _inverse_similarity(S)
    C = apply_similarity(Sinv, C_world[None])[0]
    clouds_t = [(apply_similarity(Sinv, P), N @ S[1]) for P, N in clouds]
    trees = [cKDTree(P) for P, _ in clouds_t]
    tracker_t = None if tracker_joints is None else \
        apply_similarity(Sinv, tracker_joints.reshape(-1, 3)).reshape(-1, 3, 3)
    frames_t = [DepthFrame(P, N, tree, C, arm, adjacency, o.nicp.filters, F)
                for (P, N), tree in zip(clouds_t, trees, strict=True)]
    frames_t = with_outlines(frames_t, depths, camera, S, template, o)
    timer.add("rigid_alignment", t0)

    n_frames = len(depths)
    # The arm length (shoulder-elbow plus elbow-wrist) the body tracker measures, averaged over every frame.
    tracked_arm_length = None if tracker_joints is None else float(np.mean(
        np.linalg.norm(np.diff(tracker_joints, axis=1), axis=2).sum(axis=1)))
    nicp_meshes, kept_masks = [], []
    system_rest = arap_system(posed0, F)
    current = posed0
    first_iters = replace(o.nicp, iterations=o.first_frame_nicp_iterations)
    n_shape = min(o.shape_frames, n_frames)
    # Non-rigid ICP from the rest pose: the shape fit's first frames (every frame without a model), shared by the
    # sexes a subject of unknown sex is captured as.
    for k in range(n_shape if model is not None else n_frames):
        t0 = time.perf_counter()
        X, pairs = nonrigid_icp(system_rest, F, current, *clouds_t[k], C, arm, adjacency,
                                first_iters if k == 0 else o.nicp, tree=trees[k])
        nicp_meshes.append(X)
        kept_masks.append(pairs.kept.astype(np.float64))
        timer.add("nonrigid_icp", t0)
        current = X

    def shape_stage(start):
        """Sec. 6.2: shape parameters (and the torso placement), once per sequence, from the first frames; alternated
        with those frames' joint angles (the root and the shoulder trade off)."""
        shape, root = start, np.eye(4)
        base, J = model_rest_vertices(model, shape), model_joints(model, shape)
        fit_poses = [arm_pose_from_part_transforms(procrustes_part_transforms(base, m, W, w + 0.05))
                     for m, w in zip(nicp_meshes[:n_shape], kept_masks[:n_shape], strict=True)]
        fit_poses = [ArmPose(np.eye(4), np.vstack([p.angles[:2], np.zeros((1, 3))])) for p in fit_poses]
        for _ in range(o.shape_rounds):
            shape, root = fit_shape_parameters(
                model, nicp_meshes[:n_shape], fit_poses, frames_t[:n_shape], shape,
                tracker_joints=None if tracker_t is None else tracker_t[:n_shape],
                tracker_weight=o.tracker_weight if known_shape is None else o.tracker_root_weight,
                fixed_shape=known_shape is not None, arm_length=tracked_arm_length,
                arm_length_weight=o.tracker_arm_length_weight * n_frames, huber_m=o.huber_m,
                prior=None if known_shape is not None or o.shape_prior_weight <= 0 else
                (*population_shape_prior(model, start.sex, tracked_arm_length), o.shape_prior_weight))
            base, J = model_rest_vertices(model, shape), model_joints(model, shape)
            fit_poses = [model_based_filtering(model, shape, root, nicp_meshes[j], base, W, kept_masks[j],
                                               frames_t[j], J, o.norm_limit, o.refine_pose,
                                               None if tracker_t is None else tracker_t[j],
                                               o.tracker_pose_weight, huber_m=o.huber_m)[1]
                         for j in range(n_shape)]
        return shape, root, base, J

    def tracked(start):
        """The shape fit from ``start`` (its sex), every frame's model-based filtering (the frames after the first
        ones registered from the previous model mesh) and the sequence stage: (nicp meshes, kept masks, model meshes,
        poses, shape, rest mesh, rest joints)."""
        t0 = time.perf_counter()
        shape, root, base, J = shape_stage(start)
        t0 = timer.add("shape_fit", t0)
        meshes, kept, model_meshes, poses = list(nicp_meshes), list(kept_masks), [], []
        for j in range(n_frames):
            if j >= n_shape:
                if frame_gaps is not None and frame_gaps[j] > 1:
                    log.info("frame %s: non-rigid ICP starts from frame %s's model mesh, %d frames before (skipped "
                             "frames between)", ids[j], ids[j - 1], frame_gaps[j])
                system = arap_system(model_meshes[-1], F)
                X, pairs = nonrigid_icp(system, F, model_meshes[-1], *clouds_t[j], C, arm, adjacency, o.nicp,
                                        tree=trees[j])
                meshes.append(X)
                kept.append(pairs.kept.astype(np.float64))
                t0 = timer.add("nonrigid_icp", t0)
            mm, pp = model_based_filtering(model, shape, root, meshes[j], base, W, kept[j], frames_t[j],
                                           J, o.norm_limit, o.refine_pose,
                                           None if tracker_t is None else tracker_t[j], o.tracker_pose_weight,
                                           poses[-1] if poses else None,
                                           o.smooth_weight if frame_gaps is None else o.smooth_weight / frame_gaps[j],
                                           o.huber_m)
            model_meshes.append(mm)
            poses.append(pp)
            if j >= n_shape - 1:
                t0 = timer.add("model_filtering", t0)
        if o.sequence_rounds > 0:
            t0 = time.perf_counter()
            poses, base, J = sequence_stage(model, template, shape, poses, frames_t, tracker_t, base, J, o,
                                            known_shape, **gap_kw)
            model_meshes = [skeleton_model_mesh(model, p, base, J, o.norm_limit) for p in poses]
            timer.add("sequence_fit", t0)
        return meshes, kept, model_meshes, poses, shape, base, J

    model_meshes, poses = [], []
    if model is not None:
        sexes = candidate_sexes(model, o, known_shape)
        runs = {sex: tracked(replace(shape, sex=sex)) for sex in sexes}
        if len(runs) > 1:  # the subject's sex from the depth: the capture as each sex, the one the depth prefers kept
            energies = {sex: held_out_depth_energy_mm(model, r[3], frames_t, r[5], r[6], o, **gap_kw)
                        for sex, r in runs.items()}
            sex_fit = sex_from_depth_energies(energies, o.sex_margin_mm)
            log.info("the subject's sex from the depth: %s (held-out depth energy as a man %.3f, as a woman %.3f mm)",
                     sex_fit["chosen"], energies[1.0], energies[0.0])
            sexes = (sex_fit["sex"],)
        nicp_meshes, kept_masks, model_meshes, poses, shape, base, J = runs[sexes[0]]
    if model is not None and o.pose_refit:
        t0 = time.perf_counter()
        refit = dict(POSE_REFIT)
        poses = refit_arm_poses_to_depth(model, poses, facing_frames(frames_t, o.sequence_min_facing_cos), base, J,
                                         o.norm_limit, o.sequence_huber_m, tracker_t, refit.pop("tracker_weight"),
                                         **refit)
        model_meshes = [skeleton_model_mesh(model, p, base, J, o.norm_limit) for p in poses]
        timer.add("pose_refit", t0)
    if model is not None and o.pose_sigma_frames > 0:
        t0 = time.perf_counter()
        poses = smooth_arm_poses(poses, o.pose_sigma_frames, degree=o.pose_smoothing_degree,
                                 shoulder_degree=o.shoulder_smoothing_degree, **gap_kw)
        model_meshes = [skeleton_model_mesh(model, p, base, J, o.norm_limit) for p in poses]
        timer.add("model_filtering", t0)
    if model is None:
        out_t = nicp_meshes
        poses = [None] * n_frames
    elif o.mode == "model":
        out_t = model_meshes
    else:
        refine_clouds, refine_trees = clouds_t, trees
        refine_depth = refinement_depth_options(o)
        if refine_depth != o.depth:
            t0 = time.perf_counter()
            refine_clouds = []
            for k, d in enumerate(depths):
                P, N = depth_point_cloud(clean_depth(d, refine_depth, source=f"depth frame {ids[k]}"), camera,
                                         source=f"depth frame {ids[k]}")
                refine_clouds.append((apply_similarity(Sinv, P), N @ S[1]))
            refine_trees = [cKDTree(P) for P, _ in refine_clouds]
            timer.add("depth", t0)
        out_t = _refinement(model_meshes, poses, refine_clouds, refine_trees, F, C, arm, adjacency, J, o, timer,
                            camera=camera, similarity=S, **gap_kw)
    out = np.stack([apply_similarity(S, X) for X in out_t])
    stages = {"nicp": np.stack([apply_similarity(S, X) for X in nicp_meshes])}
    if model_meshes:
        stages["model"] = np.stack([apply_similarity(S, X) for X in model_meshes])
    from bodystudio.muscle.model import model_joints

    return ArmCapture(out, F, poses, shape, S, o.mode, template.key, timer.ms, ids, stages=stages,
                      joints=None if model is None else np.asarray(J, np.float64),
                      regressed_joints=None if model is None else np.asarray(model_joints(model, shape), np.float64),
                      sex_fit=sex_fit, frame_positions=None if frame_positions is None else
                      [int(p) for p in frame_positions])


def every_nth_frame(n: int, stride: int, start: int = 0, positions: np.ndarray | None = None):
    """The frames ``start, start + stride, ...`` of a sequence of ``n``: a slice, or with ``positions`` (the frames'
    recorded numbers when frames were skipped, rel7a) the indices of the frames whose recorded number is
    ``start`` modulo ``stride``, so a skipped frame drops out of the sample and the others stay the clean capture's
    (a slice over the captured frames shifted every sample after a gap)."""
    if positions is None:
        return slice(start, None, stride)
    return [k for k in range(n) if positions[k] % stride == start]


def _pick(items, which):
    """``items[which]`` for a slice, or the listed indices (a list or an array)."""
    if isinstance(which, slice):
        return items[which]
    return items[np.asarray(which, np.int64)] if isinstance(items, np.ndarray) else [items[k] for k in which]


def held_out_depth_energy_mm(model, poses: list[ArmPose], frames_t: list[DepthFrame], rest: np.ndarray,
                              joints: np.ndarray, o: CaptureOptions, positions: np.ndarray | None = None) -> float:
    """The depth energy (``refine.depth_energy_mm``) of the model meshes on the frames the rest-shape fit leaves out
    (every ``o.body_rest_frame_stride``-th from its middle; all with a stride of 1), their grazing pairs dropped as in
    the sequence fit: the figure the rest-shape rounds keep their best by, here the evidence between two sexes."""
    stride = o.body_rest_frame_stride
    held_out = every_nth_frame(len(poses), stride, stride // 2, positions) if stride > 1 else slice(None)
    return depth_energy_mm(model, _pick(poses, held_out), _pick(facing_frames(frames_t, o.sequence_min_facing_cos),
                                                                held_out), rest,
                           joints, o.norm_limit, o.sequence_huber_m)


def model_knows_women(model) -> bool:
    """Whether ``model`` was trained on a woman (a training row of sex < 0.5: Eq. 6's female column ``1 - sex`` is
    then learned, non-zero; ``muscle model build --women K``, ``muscle model extend`` with women)."""
    rows = getattr(model, "shape_rows", None)
    return rows is not None and np.ndim(rows) == 2 and np.shape(rows)[1] > 4 and bool(np.min(rows[:, 4]) < 0.5)


def candidate_sexes(model, o: CaptureOptions, known_shape=None) -> tuple[float, ...]:
    """The sexes the Sec. 6.2 shape fit is run with: the given one (``known_shape``, ``--shape``); without it male
    (1.0, the paper's subjects) and female (0.0) when ``o.sex_from_depth`` and the model knows women
    (:func:`model_knows_women`), else male alone (what an all-male model describes; the capture warns)."""
    if known_shape is not None:
        return (float(known_shape.sex),)
    if o.sex_from_depth and model_knows_women(model):
        return (1.0, 0.0)
    return (1.0,)


def sex_from_depth_energies(energies: dict, margin_mm: float) -> dict:
    """The subject's sex from the depth energies (``refine.depth_energy_mm``, mm) of the shape fitted as a man
    (key 1.0) and as a woman (0.0) on the same frames: the lower one's, ``ambiguous`` when the two lie within
    ``margin_mm`` (the capture then warns with the figures: give the sex with --shape). Returns the run record's
    ``sex_fit``: ``{"sex", "chosen", "energy_mm": {"male", "female"}, "margin_mm", "ambiguous"}``."""
    male, female = float(energies[1.0]), float(energies[0.0])
    sex = 0.0 if female < male else 1.0
    return {"sex": sex, "chosen": "female" if sex == 0.0 else "male", "energy_mm": {"male": male, "female": female},
            "margin_mm": float(margin_mm), "ambiguous": bool(abs(male - female) <= margin_mm)}


def refinement_depth_options(o: CaptureOptions) -> DepthCleanupOptions:
    """The Sec. 4 clean-up of the depth the Sec. 7 refinement pairs with: ``o.depth`` with the refinement's own median
    aperture and Gaussian sigma where they are set."""
    changes = {k: v for k, v in (("median_px", o.refine_depth_median_px),
                                 ("gaussian_sigma_px", o.refine_depth_gaussian_sigma_px)) if v is not None}
    return replace(o.depth, **changes) if changes else o.depth


def sequence_tracker_weight(o: CaptureOptions, model, poses: list[ArmPose], frames_t: list[DepthFrame],
                            rest: np.ndarray, joints: np.ndarray, tracker_t: np.ndarray | None) -> float:
    """The tracker's weight per coordinate in the sequence fit: ``o.sequence_tracker_weight``, or with None the
    noise-weighted one (``refine.noise_weighted_tracker_weight``) of the depth pairs' spread at ``poses`` on
    ``rest`` and ``joints`` and the tracker's own noise (0 without a tracker)."""
    if o.sequence_tracker_weight is not None:
        return o.sequence_tracker_weight
    if tracker_t is None:
        return 0.0
    sigma_d = depth_residual_sigma_m(model, poses, frames_t, rest, joints, o.norm_limit)
    weight = noise_weighted_tracker_weight(sigma_d, tracker_noise_sigma_m(tracker_t))
    log.info("the sequence fit's tracker weight %.4f (depth %.2f mm)", weight, 1000 * sigma_d)
    return weight


def body_rest_local_sigma(o: CaptureOptions, space) -> np.ndarray | None:
    """The rest-shape fit's prior spread of the body space's local target weights (``model.population_local_sigma``
    with ``o.body_rest_population_locals`` > 0, the default), or None: every target at
    ``model.BODY_LOCAL_PRIOR_SIGMA`` (``o.body_rest_population_locals`` 0 and ``o.body_rest_local_sigma`` that
    spread)."""
    from bodystudio.muscle.model import BODY_LOCAL_PRIOR_SIGMA, population_local_sigma

    if o.body_rest_population_locals > 0:
        return population_local_sigma(space, o.body_rest_local_sigma, o.body_rest_population_locals)
    if o.body_rest_local_sigma != BODY_LOCAL_PRIOR_SIGMA:
        return np.full(len(space.local_names), o.body_rest_local_sigma)
    return None


def with_outlines(frames: list[DepthFrame], depths: list[np.ndarray], camera, S, template: ArmTemplate,
                  o: CaptureOptions) -> list[DepthFrame]:
    """The frames with their raw depth maps for the rest-shape fit's outline pairs (``refine.DepthOutline``) when
    ``o.body_rest_outline_weight`` > 0 (the other fits use the depth pairs only), else the frames as they are."""
    if o.body_rest_outline_weight <= 0:
        return frames
    return [replace(f, outline=DepthOutline(np.asarray(d, np.float64), camera, S, o.body_rest_outline_weight,
                                            template.arm_mask, o.body_rest_outline_offset_m, o.depth.near_m,
                                            o.depth.far_m))
            for f, d in zip(frames, depths, strict=True)]


def facing_frames(frames: list[DepthFrame], min_facing_cos: float) -> list[DepthFrame]:
    """The frames with their grazing pairs dropped (``refine.grazing_pairs``; 0: the frames as they are)."""
    return frames if min_facing_cos <= 0 else [replace(f, min_facing_cos=min_facing_cos) for f in frames]


def sequence_stage(model, template: ArmTemplate, shape, poses: list[ArmPose], frames_t: list[DepthFrame],
                   tracker_t: np.ndarray | None, base: np.ndarray, J: np.ndarray, o: CaptureOptions,
                   known_shape=None, positions: np.ndarray | None = None,
                   ) -> tuple[list[ArmPose], np.ndarray, np.ndarray]:
    """Model-based tracking of the whole sequence (Sec. 6.2 over every frame) after the per-frame fit, in the
    template's space: the sequence fit, with the rest shape of ``o.personal_rounds`` / ``o.body_rest_shape``
    alternated with it. Returns the poses, the rest mesh and the rest joints the model meshes are built on."""
    J_model = J
    body_rounds = o.body_rest_rounds if o.body_rest_shape else 0
    if o.body_rest_shape:
        from bodystudio.muscle.model import body_shape_space, project_to_body_space

        space = body_shape_space(template)
        prior_mean, prior_sigma = space.prior(shape, body_rest_local_sigma(o, space))
        anchor = J[0].copy()  # the rest mesh's shoulder stays where the model's sits (the placement's frame)
        body_x = prior_mean = project_to_body_space(space, base, J, prior_mean, prior_sigma)
        base, J_model = space.rest_and_joints(body_x, anchor)
    rest_frames = facing_frames(frames_t, o.body_rest_min_facing_cos)
    frames_t = facing_frames(frames_t, o.sequence_min_facing_cos)
    best = None
    stride = o.body_rest_frame_stride
    held_out = every_nth_frame(len(poses), stride, stride // 2, positions) if stride > 1 else slice(None)
    for r in range(max(o.personal_rounds, body_rounds) + 1):
        # the depth's spread at the current poses (round 0: the per-frame stage's, on the projected rest arm)
        seq_tw = sequence_tracker_weight(o, model, poses, frames_t, base, J if r > 0 else J_model, tracker_t)
        if r > 0 and body_rounds > 0:  # poses -> the body model's rest shape and skeleton -> poses
            sub = every_nth_frame(len(poses), o.body_rest_frame_stride, 0, positions)
            common = (o.body_rest_prior_weight, o.norm_limit, o.sequence_huber_m, o.body_rest_iterations)
            length = (None if known_shape is None else known_shape.arm_length_m, o.body_rest_arm_length_weight)
            tracked = None if tracker_t is None else _pick(tracker_t, sub)
            rest_tw = seq_tw if o.body_rest_tracker_weight is None else o.body_rest_tracker_weight
            if o.body_rest_fit_poses:
                body_x, shift, _ = fit_body_rest_shape_and_poses(
                    space, model, _pick(poses, sub), _pick(rest_frames, sub), body_x, anchor, prior_mean, prior_sigma,
                    *common,
                    *length, tracked, rest_tw, o.body_rest_angle_damping)
            else:
                body_x, shift = fit_body_rest_shape(
                    space, model, _pick(poses, sub), _pick(rest_frames, sub), body_x, anchor, prior_mean, prior_sigma,
                    *common,
                    o.body_rest_fit_placement, *length, tracked, rest_tw)
            base, J_model = space.rest_and_joints(body_x, anchor)
            poses = [_shifted(p, shift) for p in poses]
        elif r > 0:  # poses -> rest shape -> poses (the rest shape and the poses stop trading errors)
            base = fit_rest_shape_correction(model, shape, poses, frames_t, base, J, o.personal_prior_weight,
                                             o.norm_limit, o.sequence_huber_m)
        poses, J = fit_arm_sequence_skeleton(
            model, shape, poses, frames_t, J_model, o.norm_limit, tracker_t, seq_tw, o.sequence_smooth_weight,
            o.sequence_rounds, o.sequence_max_nfev, o.sequence_huber_m,
            o.sequence_fit_root, o.sequence_fit_skeleton, o.sequence_skeleton_prior_weight,
            o.sequence_depth_huber_only, rest=base, free_joints=o.sequence_free_joints,
            torso_pair_weight=o.sequence_torso_pair_weight,
            tracker_placement_weight=None if o.sequence_placement_prior_m <= 0 or tracker_t is None
            else tracker_placement_prior_weight(tracker_t, o.sequence_placement_prior_m),
            **({} if positions is None else {"positions": positions}))
        if body_rounds > 0 and o.body_rest_keep_best:
            energy = depth_energy_mm(model, _pick(poses, held_out), _pick(frames_t, held_out), base, J, o.norm_limit,
                                     o.sequence_huber_m)
            log.info("rest-shape round %d: depth energy %.3f mm", r, energy)
            if best is not None and energy >= best[0]:
                return best[1:]  # the energy stopped falling: the previous round's
            best = (energy, poses, base, J)
    return poses, base, J


def _refinement(model_meshes, poses, clouds_t, trees, F, C, arm, adjacency, joints, o: CaptureOptions, timer,
                camera=None, similarity=None, positions=None):
    """Sec. 7 over the sequence: per-frame correspondences, Eq. 13-14 averaging, Sec. 7.2 weights, last ARAP.

    ``o.refine_visible_only`` (needs ``camera`` and the Sec. 5.1 ``similarity``): pairs of vertices the model mesh
    itself hides from the sensor are dropped (:func:`model_visible_vertices`). ``o.refine_unseen_hold``: the vertices
    with no pair that face away from the sensor (:func:`hold_seen_vertices`) are held to the model mesh
    (``refine.unseen_hold_weights``). ``positions``: the frames' recorded numbers when frames were skipped (the
    windows then in recorded frames: :func:`refinement_windows`).
    """
    t0 = time.perf_counter()
    vecs, valid, seen = [], [], []
    for M, (P, N), tree in zip(model_meshes, clouds_t, trees, strict=True):
        Nv = vertex_normals(M, F)
        pairs = closest_point_correspondences(M, P, N, tree)
        pairs = filter_correspondences(M, Nv, pairs, C, arm, adjacency, o.nicp.filters)
        visible = None
        if o.refine_visible_only and camera is not None:
            visible = model_visible_vertices(apply_similarity(similarity, M), F, camera)
            pairs.kept &= visible
        if o.refine_min_facing_cos > 0:
            pairs.kept &= ~edge_on_pairs(M, Nv, C, o.refine_min_facing_cos)
        # Along the depth point's normal only (point-to-plane, as in NICP): the rest is sliding.
        vecs.append(np.where(pairs.kept[:, None], plane_targets(M, pairs) - M, 0.0))
        valid.append(pairs.kept)
        seen.append(hold_seen_vertices(M, Nv, C, pairs.kept, visible))
    out = []
    n = len(model_meshes)
    r = o.refine_window_frames
    for i, M in enumerate(model_meshes):
        lo, hi = max(i - r, 0), min(i + r, n - 1)
        idx = list(range(lo, hi + 1))
        if positions is not None:  # skipped frames (rel7a): the captured neighbours at their offsets in recorded
            # frames (Eq. 14's weight falls with them: 0.14 at two frames, 0.01 at three); a wider window (faster than
            # 30 fps) keeps those within its r recorded frames
            idx = [j for j in idx if r == 1 or abs(positions[j] - positions[i]) <= r]
            deltas = [int(positions[j] - positions[i]) for j in idx] if len(idx) > 1 else None
        elif r == 1:  # the paper's i-1, i, i+1 (at a sequence end: the frame and its one neighbour)
            if len(idx) == 2:
                idx = [i, hi if hi != i else lo]
            deltas = None
        else:  # a recording faster than 30 fps: the same time span, more frames
            deltas = [j - i for j in idx]
        window = ([vecs[j] for j in idx], [valid[j] for j in idx], o.sigma_frames)
        c, ok = time_consistent_correspondences(*window) if deltas is None else \
            time_consistent_correspondences(*window, deltas)
        w = correspondence_weights(c, vertex_normals(M, F), M, posed_joints(joints, poses[i]), ok,
                                   o.joint_radius_m, o.joint_gain)
        hold = None if o.refine_unseen_hold <= 0 else unseen_hold_weights(M, ok | seen[i], o.refine_unseen_hold,
                                                                          o.refine_unseen_band_m)
        out.append(refine_surface(M, F, c, w, o.refine_data_weight, o.refine_iterations, hold=hold))
    if o.detail_sigma_frames > 0 and n >= 3:
        # The refinement's detail (refined minus model mesh) of each vertex, averaged over +-2 frames
        # with Gaussian weights: Eq. 13-14 applied to the result of the last ARAP as well.
        D = np.stack(out) - np.stack(model_meshes)
        k = np.arange(-o.detail_window_frames, o.detail_window_frames + 1)
        g = np.exp(-(k ** 2) / (2.0 * o.detail_sigma_frames ** 2))
        smoothed = []
        for i in range(n):
            if positions is None:
                idx, gi = np.clip(i + k, 0, n - 1), g
            else:  # skipped frames: the offsets that land on a captured frame (beyond an end: the end, as above)
                at = np.clip(positions[i] + k, positions[0], positions[-1])
                j = np.searchsorted(positions, at)
                j = np.minimum(j, n - 1)
                here = positions[j] == at
                idx, gi = j[here], g[here]
            smoothed.append(model_meshes[i] + np.tensordot(gi / gi.sum(), D[idx], axes=1))
        out = smoothed
    timer.add("refinement", t0)
    return out




def hold_seen_vertices(vertices: np.ndarray, normals: np.ndarray, sensor_center: np.ndarray, paired: np.ndarray,
                       visible: np.ndarray | None = None) -> np.ndarray:
    """The vertices ``refine.unseen_hold_weights`` leaves free: the paired ones and those facing the sensor (Eq. 1's
    front side; the z-buffer's ``visible`` vertices face it too). A front-facing vertex hidden behind the forearm is
    the biceps the seen side's pull may lift, not the back; chosen over the z-buffer alone (the hidden front-facing
    vertices held too) by the held-out depth energy, docs/muscle.md twelfth pass."""
    facing = np.einsum("kd,kd->k", normals, sensor_center - vertices) > 0
    out = np.asarray(paired, bool) | facing
    return out if visible is None else out | visible


def model_visible_vertices(vertices: np.ndarray, faces: np.ndarray, camera, tolerance_m: float = 0.01) -> np.ndarray:
    """Vertices (n,) of a world-space mesh that the depth ``camera`` sees: facing it and not hidden by the mesh
    itself (z-buffer within ``tolerance_m``). Sec. 5.2's front-side filter tests the normal only, so at strong
    elbow flexion a biceps vertex facing the sensor behind the forearm keeps a pair with the forearm's points."""
    from bodystudio.muscle.evaluate import visible_vertices

    return visible_vertices(vertices, faces, camera, tolerance_m)


#: rel7a: the share of a capture's frames that may be skipped as bad (:func:`read_arm_frames`); more, and the capture
#: is refused. Chosen, not measured at that share: 1, 3 and a run of 5 bad frames in 200 of seq_501 captured the good
#: frames within 0.08 mm (median) of the clean capture on them (docs/muscle.md, "Bad frames skipped (rel7a)"); the
#: rest-shape fit samples every 4th recorded frame and the sequence fit's prior needs most of the recording.
MAX_SKIPPED_FRACTION = 0.25
#: ... and the longest run of consecutive bad frames, in seconds (at 30 fps: 5 frames). The pose smoothing's Gaussian
#: (sigma 5 frames) and the sequence fit's second-difference prior bridge a gap this long on the arm's quasi-static
#: motion (the measured run of 5: 2.016 mm against 2.084 on the same frames); longer was not measured and leaves the
#: frame after it to start from a pose more than 1/6 s old.
MAX_SKIPPED_RUN_S = 5.0 / CAPTURE_FPS


def capture_arm_sequence(session, model, template: ArmTemplate, options: CaptureOptions = CaptureOptions(),
                         frames: slice | None = None, known_shape=None, skip_bad_frames: bool = True) -> ArmCapture:
    """Capture the arm of a Kinect session (``bodystudio.capture.session``), Sec. 4-7 of Arm-Muscle Capture.

    ``skip_bad_frames`` (rel7a): a frame whose depth image cannot be read or shows no arm, or whose tracker joints
    of the subject are missing, is skipped with a warning and listed in ``capture.skipped``
    (:func:`read_arm_frames`); too many is refused. False: the first bad frame refuses the capture."""
    from bodystudio.capture.session import stream_fingerprint, stream_path

    sensor = session.kinect
    if sensor is None:
        raise SessionError(f"{session.path}: no Kinect calibration; the arm capture needs a depth session")
    fps = capture_frame_rate(session)  # before any frame is read: a rate the filters cannot serve is refused
    ids = list(session.frame_ids[frames] if frames is not None else session.frame_ids)
    try:
        read = read_arm_frames(session, ids, template.side, options.depth, fps) if skip_bad_frames else None
    except NoGoodFrameError:  # nothing to skip to: the capture as without skipping, with the first frame's own
        read, skip_bad_frames = None, False  # refusal and advice (e.g. "move the subject to about 1 m")
    if skip_bad_frames:
        good, depths, tracker, skipped = read
    else:
        good, skipped, depths = ids, [], []
        for fid in ids:
            d = session.frame(fid).kinect_depth_m
            if d is None:
                raise SessionError(f"{session.path}: frame {fid} has no Kinect depth image")
            depths.append(d)
        tracker = session_arm_tracker(session, ids, template.side)
    sources = [Path(session.path) / stream_path("kinect_depth", fid) for fid in good]
    positions = [ids.index(fid) for fid in good] if skipped else None
    capture = capture_arm_frames(depths, sensor.depth, template, model, options, tracker, list(good), known_shape,
                                 fps, depth_sources=sources,
                                 **({} if positions is None else {"frame_positions": positions}))
    capture.skipped = skipped
    capture.session_path = str(Path(session.path).resolve())
    capture.source_fingerprint = stream_fingerprint(session, "kinect_depth", good)
    return capture


class NoGoodFrameError(SessionError):
    """No frame of the capture is good (:func:`check_skipped_frames`): :func:`capture_arm_sequence` then refuses as
    without skipping, with the first frame's own message and advice."""


def _frame_problem(exc: Exception, path: Path) -> str:
    """The why of a bad frame: the error's text without its leading file name (the record names the file)."""
    text = str(exc)
    return text[len(f"{path}: "):] if text.startswith(f"{path}: ") else text


def read_arm_frames(session, ids: list, side: str, depth: DepthCleanupOptions = DepthCleanupOptions(),
                    fps: float = CAPTURE_FPS) -> tuple[list, list[np.ndarray], np.ndarray | None, list[dict]]:
    """The frames of ``ids`` the arm capture can use, the bad ones skipped (rel7a): ``(good ids, their depth maps
    (metres), their tracker shoulder / elbow / wrist (T, 3, 3) or None, skipped)``.

    A frame is bad when its depth image cannot be read (truncated, not 16-bit, none), is not the depth camera's
    size, or shows fewer than ``depth.min_pixels`` pixels in the depth window (the arm left the view), or when the
    subject's shoulder, elbow or wrist of ``side`` is missing or null in its joints file, or the subject is not
    among its tracked people (:func:`session_arm_tracker_rows`); a session whose tracker gives no joints at all is
    captured from the depth alone, as before. ``skipped``: ``[{"frame", "position" (in ``ids``), "file", "why"}]``,
    each logged as a warning.

    Refused (SessionError naming the first bad frame's file, the frames and the fix) when nothing is left, when more
    than :data:`MAX_SKIPPED_FRACTION` of the frames are bad, or when a run of consecutive bad frames lasts longer
    than :data:`MAX_SKIPPED_RUN_S` at ``fps``: the temporal filters cannot bridge it."""
    from bodystudio.capture.session import stream_path
    from bodystudio.errors import BodyStudioError
    from bodystudio.muscle.depth import segment_by_distance

    camera = session.kinect.depth
    rows, tracker_problems = session_arm_tracker_rows(session, ids, side)
    use_tracker = any(r is not None for r in rows.values())
    problems: dict = {}
    depths: dict = {}
    for fid in ids:
        path = Path(session.path) / stream_path("kinect_depth", fid)
        try:
            d = session.frame(fid).kinect_depth_m
        except BodyStudioError as exc:
            problems[fid] = (path, _frame_problem(exc, path))
            continue
        if d is None:
            problems[fid] = (path, "no Kinect depth image in this frame")
        elif hasattr(camera, "height") and d.shape != (camera.height, camera.width):
            problems[fid] = (path, f"depth map is {d.shape[1]}x{d.shape[0]} but the depth camera is "
                                   f"{camera.width}x{camera.height}")
        elif np.count_nonzero(segment_by_distance(d, depth.near_m, depth.far_m)) < depth.min_pixels:
            problems[fid] = (path, f"no arm in the {depth.near_m:g}-{depth.far_m:g} m depth window")
        elif use_tracker and fid in tracker_problems:
            problems[fid] = tracker_problems[fid]
        else:
            depths[fid] = d
    skipped = [{"frame": int(fid), "position": k, "file": str(problems[fid][0]), "why": problems[fid][1]}
               for k, fid in enumerate(ids) if fid in problems]
    check_skipped_frames(skipped, len(ids), fps, session.path)
    for s in skipped:
        log.warning("%s: frame %d skipped: %s", s["file"], s["frame"], s["why"])
    good = [fid for fid in ids if fid not in problems]
    tracker = np.stack([rows[fid] for fid in good]) if use_tracker else None
    return good, [depths[fid] for fid in good], tracker, skipped


def _frame_ranges(frames: list[int]) -> str:
    """``[3, 4, 5, 9]`` -> ``3-5, 9``."""
    out, start = [], None
    for k, f in enumerate(frames):
        if start is None:
            start = f
        if k + 1 == len(frames) or frames[k + 1] != f + 1:
            out.append(str(start) if start == f else f"{start}-{f}")
            start = None
    return ", ".join(out)


def longest_run(positions: list[int]) -> tuple[int, int]:
    """The longest run of consecutive numbers in the increasing ``positions``: ``(its length, its first)``;
    ``(0, -1)`` when empty."""
    best, first, start, n = (0, -1), None, None, 0
    for k, p in enumerate(positions):
        if k and p == positions[k - 1] + 1:
            n += 1
        else:
            start, n = p, 1
        if n > best[0]:
            best = (n, start)
    del first
    return best


def ids_at(skipped: list[dict], position: int) -> int:
    """The frame id of the skipped record at ``position``."""
    return next(s["frame"] for s in skipped if s["position"] == position)


def check_skipped_frames(skipped: list[dict], n_frames: int, fps: float, session_path) -> None:
    """Refuse (SessionError, one line) a capture whose skipped frames (:func:`read_arm_frames`) exceed the bounds:
    every frame, more than :data:`MAX_SKIPPED_FRACTION`, or a run longer than :data:`MAX_SKIPPED_RUN_S`. The fix
    names the first frames that keep within them (``--frames N``) where there are some."""
    if not skipped:
        return
    positions = [s["position"] for s in skipped]
    run, run_start = longest_run(positions)
    max_run = max(1, int(np.floor(MAX_SKIPPED_RUN_S * fps + 1e-9)))
    first = skipped[0]
    what = (f"{first['file']}: frame {first['frame']} cannot be captured ({first['why']})"
            + (f", nor {len(skipped) - 1} more of the {n_frames} frames (frames "
               f"{_frame_ranges([s['frame'] for s in skipped])})" if len(skipped) > 1 else ""))
    if len(skipped) == n_frames:
        raise NoGoodFrameError(f"{what}: no frame of {session_path} can be captured")
    too_many = len(skipped) > MAX_SKIPPED_FRACTION * n_frames
    if not too_many and run <= max_run:
        return

    def fits(n):  # the first n frames within both bounds, with a good one
        head = [p for p in positions if p < n]  # ... ending on a good frame
        return (n - 1 not in head and len(head) <= MAX_SKIPPED_FRACTION * n
                and longest_run(head)[0] <= max_run)

    keep = next((n for n in range(n_frames - 1, 0, -1) if fits(n)), 0)
    why = (f"bad frames: {len(skipped)} of {n_frames}, more than the {MAX_SKIPPED_FRACTION:.0%} the capture skips"
           if too_many else f"{run} bad frames in a row from frame {ids_at(skipped, run_start)}, more than the "
           f"{max_run} ({1000 * MAX_SKIPPED_RUN_S:.0f} ms) the temporal filters bridge")
    fix = f"capture the first {keep} frames (--frames {keep}), or " if keep else ""
    raise SessionError(f"{what}; {why}: {fix}re-export the bad frames")


def session_arm_tracker_rows(session, ids, side: str) -> tuple[dict, dict]:
    """The body tracker's shoulder, elbow and wrist of ``side`` of the capture's subject (the first frame's person,
    followed by its joints: :func:`bodystudio.capture.subject.follow_subject`) per frame of ``ids``:
    ``({frame: (3, 3) or None}, {frame: (joints file, why)})``, the second for the frames without them (the joints
    missing or null, or the subject not tracked while someone else is)."""
    from bodystudio.capture.session import stream_path
    from bodystudio.capture.subject import frame_bodies, session_follower

    want = TRACKER_JOINTS[side]
    rows, problems = {}, {}
    follower = session_follower(session)
    for fid in ids:
        path = Path(session.path) / stream_path("kinect_joints", fid)
        try:
            bodies = frame_bodies(session.frame(fid))
        except Exception as exc:  # an unreadable joints file: this frame's problem
            from bodystudio.errors import BodyStudioError

            if not isinstance(exc, BodyStudioError):
                raise
            rows[fid], problems[fid] = None, (path, _frame_problem(exc, path))
            follower.follow([])
            continue
        joints = follower.follow(bodies)
        arm = None
        if joints is not None and all(n in joints["names"] for n in want):
            arm = np.asarray(joints["positions"], np.float64)[[joints["names"].index(n) for n in want]]
        if arm is None or not np.all(np.isfinite(arm)):
            rows[fid] = None
            if joints is None and bodies:
                players = sorted(b["player"] for b in bodies)
                problems[fid] = (path, f"the capture's subject is not tracked (the tracker reports player"
                                       f"{'s' if len(players) > 1 else ''} {', '.join(map(str, players))}: another "
                                       f"person{follower.lost_reason()})")
            else:
                problems[fid] = (path, f"the body tracker's {', '.join(want)} are missing or null")
        else:
            rows[fid] = arm
    return rows, problems


def session_arm_tracker(session, ids, side: str) -> np.ndarray | None:
    """The body tracker's shoulder, elbow and wrist of ``side`` in every frame of ``ids`` (T, 3, 3), or None when
    no frame has them (the capture then fits the depth alone). A sequence tracked in some frames only is refused
    (SessionError naming the first frame without them): a joint stored as null (NaN) stopped the shape fit with
    a traceback, and an absent one dropped the tracker from every frame, which left the fit without its hold on
    the arm and the self-check blaming the calibration or the arm side."""
    from bodystudio.capture.session import stream_path
    from bodystudio.capture.subject import follow_subject, frame_bodies, session_step_m

    want = TRACKER_JOINTS[side]
    rows, gaps, absent = [], [], {}
    # the first frame's person, followed (a second person coming into view with a lower player id is not taken)
    bodies = [frame_bodies(session.frame(fid)) for fid in ids]
    for fid, joints, others in zip(ids, follow_subject(bodies, step_m=session_step_m(session)), bodies, strict=True):
        arm = None
        if joints is not None and all(n in joints["names"] for n in want):
            arm = np.asarray(joints["positions"], np.float64)[[joints["names"].index(n) for n in want]]
        if arm is None or not np.all(np.isfinite(arm)):
            gaps.append(fid)
            if joints is None and others:  # people tracked, the subject not among them
                absent[fid] = sorted(b["player"] for b in others)
        else:
            rows.append(arm)
    if not rows:
        return None
    if gaps:
        before = list(ids).index(gaps[0])
        fix = f", or capture the {before} frames before it (--frames {before})" if before else ""
        if gaps[0] in absent:  # rel6b: the tracker gave the lost subject's id to someone else
            players = absent[gaps[0]]
            raise SessionError(f"{Path(session.path) / stream_path('kinect_joints', gaps[0])}: the capture's subject "
                               f"(the first frame's person, followed by its joints) is not tracked in {len(gaps)} of "
                               f"{len(ids)} frames (first {gaps[0]}, where the tracker reports "
                               f"player{'s' if len(players) > 1 else ''} {', '.join(map(str, players))}: another "
                               f"person); the arm capture needs the subject in every frame{fix}")
        raise SessionError(f"{Path(session.path) / stream_path('kinect_joints', gaps[0])}: the body tracker's "
                           f"{', '.join(want)} are missing or null in {len(gaps)} of {len(ids)} frames (first "
                           f"{gaps[0]}); the arm capture needs them in every frame or in none: re-export the joints "
                           f"with the gaps filled{fix}")
    return np.stack(rows)


def session_fps(session_path) -> float:
    """The frame rate of the session at ``session_path`` (:func:`capture_frame_rate`): the rate ``arm.glb`` is played
    at and the capture's temporal filters are scaled to (a 15 fps recording's was written at 30, twice as fast)."""
    from bodystudio.capture.session import open_session

    return capture_frame_rate(open_session(session_path))


def session_arm_choice(session, resolution: str | None = None, side: str | None = None) -> tuple[str, str]:
    """The arm template's resolution and side: as given, else the session's (a synthetic arm session records
    them in its ground truth), else 6k / left."""
    arm = (session.gt_subject or {}).get("arm") or {}
    return resolution or arm.get("resolution", "6k"), side or arm.get("side", "left")


def capture_session_arm(session_path: str | Path, model_path: str | Path | None, mode: str = "full",
                        resolution: str | None = None, side: str | None = None, frames: int | None = None,
                        known_shape=None, sequence_fit: bool = True, for_extension: bool = False,
                        accept_implausible: bool = False, skip_bad_frames: bool = True) -> ArmCapture:
    """``bodystudio muscle capture SESSION``: the session opened, the arm template chosen
    (:func:`session_arm_choice`), the model read, the first ``frames`` frames captured (Sec. 4-7).
    ``for_extension``: the capture setting for extending a model (:data:`EXTENSION_CAPTURE`).

    One call per sequence: the shape fit (Sec. 6.2) uses the sequence's first frames and the pose smoothing
    and refinement (Sec. 7) neighbouring frames, so a sequence is one work unit of a batch.

    The capture checks itself (:mod:`bodystudio.muscle.plausibility`): depth in another unit, the other arm
    facing the sensor, the arm beyond the depth window, a fit that does not explain the depth raise
    ImplausibleResultError unless ``accept_implausible``; the verdict is kept in ``capture.plausibility``.
    ``skip_bad_frames``: a bad frame is skipped and listed (:func:`read_arm_frames`) rather than refusing the
    capture (rel7a)."""
    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.muscle.arm import arm_template

    if mode not in MODES:
        raise InputError(f"capture mode {mode!r}: valid: {', '.join(MODES)}")
    session = open_session(session_path)
    capture_frame_rate(session)  # a rate the temporal filters cannot serve: refused before the body and model load
    if frames is not None and frames > len(session.frame_ids):
        raise InputError(f"--frames {frames}: {session_path} has {len(session.frame_ids)} frames")
    resolution, side = session_arm_choice(session, resolution, side)
    if resolution not in ("6k", "2k", "full") or side not in ("left", "right"):
        raise InputError(f"arm template {resolution!r} {side!r}: valid: 6k, 2k, full and left, right")
    template = arm_template(build_body(resolution=resolution), side)
    model = None
    if model_path is not None:
        from bodystudio.muscle.model import load_arm_model

        model = load_arm_model(model_path, template)
    if for_extension and not (sequence_fit and mode != "nicp"):
        raise InputError("the capture for extension fits the skeleton in the sequence fit: it needs the model and "
                         "the sequence fit")
    options = CaptureOptions(mode=mode, **(EXTENSION_CAPTURE if for_extension else {}),
                             **({} if sequence_fit else {"sequence_rounds": 0}))
    from bodystudio.muscle.plausibility import check_after_capture, check_before_capture

    selected = slice(0, frames) if frames is not None else slice(None)
    before = check_before_capture(session, session.frame_ids[selected], side, accept_implausible)
    capture = capture_arm_sequence(session, model, template, options,
                                   frames=None if frames is None else slice(0, frames), known_shape=known_shape,
                                   **({} if skip_bad_frames else {"skip_bad_frames": False}))
    capture.plausibility = check_after_capture(capture, session, template, model, before, accept_implausible,
                                               shape_given=known_shape is not None)
    return capture


def write_arm_capture(out_dir: str | Path, capture: ArmCapture, fps: float = 30.0) -> Path:
    """PLY sequence, ``arm.glb`` (morph-target animation), ``params.json`` and manifest, committed as one folder."""
    from bodystudio.muscle.export import staged_output_folder

    with staged_output_folder(out_dir, "arm capture folder") as stage:
        write_arm_capture_files(lambda rel: stage / rel, capture, fps)
    return Path(out_dir)


def write_arm_capture_files(path_for: Callable[[str], Path], capture: ArmCapture, fps: float = 30.0) -> None:
    """Write the files of an arm capture folder, each at ``path_for(relative name)`` (a staging area: the
    caller commits them as one unit, :func:`write_arm_capture` or a batch unit's RunWriter)."""
    from bodystudio.fileio import write_json
    from bodystudio.muscle.export import write_morph_glb, write_ply_sequence

    positions = None if capture.frame_positions is None else capture.positions
    gap_kw = {} if positions is None else {"positions": positions}
    write_ply_sequence(path_for("meshes"), capture.vertices, capture.faces, **gap_kw)
    write_morph_glb(path_for("arm.glb"), capture.vertices, capture.faces, fps=fps, **gap_kw)
    s, R, t = capture.similarity
    params = {"mode": capture.mode, "template_key": capture.template_key, "frame_ids": list(capture.frame_ids),
              "shape": None if capture.shape is None else _shape_dict(capture.shape),
              "poses": [None if p is None else p.to_dict() for p in capture.poses],
              "similarity": {"scale": float(s), "R": np.asarray(R).tolist(), "t": np.asarray(t).tolist()},
              "timings_ms": capture.timings_ms, "ms_per_frame": capture.ms_per_frame,
              "session": capture.session_path, "session_fingerprint": capture.source_fingerprint,
              "joints": None if capture.joints is None else np.asarray(capture.joints, float).tolist(),
              "regressed_joints": None if capture.regressed_joints is None
              else np.asarray(capture.regressed_joints, float).tolist(),
              "sex_fit": capture.sex_fit}
    if capture.skipped or capture.frame_positions is not None:  # rel7a: the frames skipped as bad, no mesh there
        params["frame_positions"] = capture.positions
        params["skipped_frames"] = list(capture.skipped)
    write_json(path_for("params.json"), params)
    if capture.plausibility is not None:
        write_json(path_for("plausibility.json"), capture.plausibility)
    manifest = {"format": "bodystudio-arm-capture", "version": 1, "n_frames": capture.n_frames,
                "meshes": "meshes/NNNNN.ply", "params": "params.json"}
    if positions is not None:  # the mesh files are numbered by recorded frame; a skipped frame has none
        manifest["missing_meshes"] = sorted(set(range(positions[-1] + 1)) - set(positions))
    write_json(path_for("manifest.json"), manifest)


def _shape_dict(shape) -> dict:
    try:
        return {k: float(v) for k, v in asdict(shape).items()}
    except TypeError:
        return {"vector": np.asarray(shape.as_vector(), float).tolist()}


def _capture_shape(shape, source: str):
    """The fitted shape of a capture's params.json: ArmShapeParams, ``{"vector": [...]}`` or None; unknown
    names or NaN / infinite values are refused (a NaN shape would be learnt into an extended model)."""
    if shape is None:
        return None
    if "vector" in shape:
        vector = np.asarray(shape["vector"], float)
        if not np.all(np.isfinite(vector)):
            raise ValueError("shape vector is NaN or infinite")
        return shape
    from bodystudio.muscle.model import SHAPE_NAMES, ArmShapeParams

    unknown = set(shape) - {*SHAPE_NAMES, "sex"}
    if unknown:
        raise ValueError(f"shape has unknown names {sorted(unknown)}")
    parsed = ArmShapeParams.from_dict(shape, f"{source} shape")
    if not np.all(np.isfinite(parsed.as_vector())):
        raise ValueError("shape is NaN or infinite")
    return parsed


def load_arm_capture(folder: str | Path) -> ArmCapture:
    """Read a folder written by :func:`write_arm_capture`; junk or missing files raise FileFormatError."""
    from bodystudio.geometry.mesh import load_mesh

    folder = Path(folder)
    p = folder / "params.json"
    try:
        params = json.loads(p.read_text())
        n = int(json.loads((folder / "manifest.json").read_text())["n_frames"])
        positions = params.get("frame_positions")
        if positions is not None:
            positions = [int(k) for k in positions]
            if len(positions) != n or any(b <= a for a, b in zip(positions, positions[1:], strict=False)):
                raise ValueError(f"frame_positions: {n} increasing frame numbers expected")
        skipped = params.get("skipped_frames") or []
        if not isinstance(skipped, list) or not all(isinstance(x, dict) and {"frame", "file", "why"} <= set(x)
                                                    for x in skipped):
            raise ValueError("skipped_frames is not a list of {frame, file, why} records")
        meshes = [load_mesh(folder / "meshes" / f"{k:05d}.ply") for k in (positions or range(n))]
        sim = params["similarity"]
        S = (float(sim["scale"]), np.asarray(sim["R"], float).reshape(3, 3), np.asarray(sim["t"], float).reshape(3))
        poses = [None if d is None else ArmPose.from_dict(d, str(p)) for d in params["poses"]]
        V = np.stack([np.asarray(m.vertices, float) for m in meshes])
        F = np.asarray(meshes[0].faces, np.int64)
        joints = params.get("joints")
        joints = None if joints is None else np.asarray(joints, float).reshape(3, 3)
        regressed = params.get("regressed_joints")
        regressed = None if regressed is None else np.asarray(regressed, float).reshape(3, 3)
        shape = _capture_shape(params.get("shape"), str(p))
        sex_fit = params.get("sex_fit")
        if sex_fit is not None and not isinstance(sex_fit, dict):
            raise ValueError(f"sex_fit {sex_fit!r} is not a record")
    except (OSError, ValueError, KeyError, TypeError, IndexError, InputError) as exc:
        raise FileFormatError(f"{folder}: not a readable arm capture folder ({type(exc).__name__}: {exc}); "
                              "re-run bodystudio muscle capture") from None
    for name, value in (("similarity", np.r_[S[0], S[1].ravel(), S[2]]), ("joints", joints),
                        ("regressed_joints", regressed)):
        if value is not None and not np.all(np.isfinite(value)):
            raise FileFormatError(f"{p}: {name} is NaN or infinite; re-run bodystudio muscle capture")
    return ArmCapture(V, F, poses, shape, S, params.get("mode", "full"), params.get("template_key", ""),
                      dict(params.get("timings_ms", {})), list(params.get("frame_ids", range(n))),
                      params.get("session"), joints=joints, source_fingerprint=params.get("session_fingerprint"),
                      regressed_joints=regressed, sex_fit=sex_fit, frame_positions=positions, skipped=skipped)


__all__ = ["CAPTURE_FPS", "EXTENSION_CAPTURE", "MIN_CAPTURE_FPS", "MODES", "ArmCapture", "CaptureOptions",
           "CorrespondenceFilters", "NicpOptions", "capture_arm_frames", "capture_arm_sequence", "capture_frame_rate",
           "capture_session_arm", "load_arm_capture", "options_at_frame_rate", "session_arm_choice",
           "write_arm_capture", "write_arm_capture_files"]
