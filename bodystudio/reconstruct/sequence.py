"""Rapid Skin over a capture session: per-frame pose initialisation, deformation, outputs and scores.

Frames are processed in order. Each is initialised from its joints (§IV.A); by default that pose is
then refined by an articulated fit of its bone transforms to the frame's silhouettes
(:func:`bodystudio.reconstruct.articulated_fit.refine_bone_transforms`): to the implicit visual hull of
the per-camera distance fields (:mod:`bodystudio.reconstruct.tracking`, default) or to the carved
visual hull, which corrects the limb directions a noisy tracker gets wrong before the deformation
(§III) starts. With ``tracking`` a frame starts from the previous frame's pose instead, and the joints
are used only at the first frame and when the lost-track check fires. With ``warm_start`` the
rest shape posed for a frame is the running mean of the previous results un-skinned into the
template's rest pose (inverting the blended LBS transforms), so the subject's shape carries over. It is
off by default: with per-frame tracker noise each result also corrects its own frame's joint error, and
carrying that over measured slightly worse (p90 +0.4-0.6 mm on 6-frame walks) than starting every frame
from the generic template; the hull joint source warm-starts its articulated fit from the previous pose.
Results go to ``SESSION/reconstruct/``: ``meshes/NNNNN.ply``, ``frames.json`` (per-frame timings, constraint
counts and, for synthetic sessions, errors) and ``run.json`` (parameters, and the run id and sha256 of every
file). The run is written as a whole (:mod:`bodystudio.runfolder`: lock, staging, commit, ``run.json`` last),
so a failed, killed or concurrent re-run never leaves a folder that mixes two runs.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.capture.subject import subject_body
from bodystudio.errors import ImplausibleResultError, InputError, SessionError
from bodystudio.fileio import read_json
from bodystudio.geometry.laplacian import cotangent_weights
from bodystudio.geometry.mesh import Mesh, load_mesh, save_mesh
from bodystudio.reconstruct.articulated_fit import (
    REFINE_BONES_WITH_HEAD,
    PoseRefineParams,
    fit_body_to_hull,
    refine_bone_transforms,
)
from bodystudio.reconstruct.depth import depth_observation
from bodystudio.reconstruct.evaluate import (
    joint_error_mm,
    region_errors,
    silhouette_iou,
    surface_error,
    vertex_regions,
    visible_vertices,
)
from bodystudio.reconstruct.plausibility import (
    coherence_frames,
    frame_plausibility,
    run_plausibility,
    tracker_joint_residual,
    untracked_limb_joints,
)
from bodystudio.reconstruct.pose_depth import DEPTH_BONES, bone_vertices, combined_data_term, depth_data_term
from bodystudio.reconstruct.pose_init import (
    initialise_pose,
    joints_from_mapping,
    neck_at_joint,
    pose_template,
    sequence_bone_lengths,
    smooth_joint_track,
    unpose,
    with_bone_lengths,
)
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations
from bodystudio.reconstruct.shape_prior import (
    back_patch,
    deformed_shape_coefficients,
    posed_shape,
    region_blend_weights,
    rim_reach,
    shape_prior_mesh,
)
from bodystudio.reconstruct.tracking import (
    SilhouetteFields,
    TrackParams,
    carry_deformed_mesh,
    energy_jumped,
    limbs_far,
    lost_track_reason,
    outside_fraction,
    silhouette_data_term,
    torso_joint_jump_m,
    track_bone_transforms,
)
from bodystudio.reconstruct.visual_hull import visual_hull
from bodystudio.runfolder import RunLayout, RunWriter, check_readable, verify_run_files

log = logging.getLogger(__name__)

TEMPLATES = {"13k": "full", "6k": "6k", "2k": "2k", "full": "full", "2.5k": "2k"}
JOINT_SOURCES = ("tracker", "file", "hull")
#: The body-shape prior for surfaces no view sees (:mod:`bodystudio.reconstruct.shape_prior`): none, a second
#: pass per frame from the shape space's fit to the first, or the run's fitted shape as each later frame's start.
SHAPE_PRIORS = ("off", "frame", "run", "carried")
#: Where the shape prior acts (``shape_prior_region``): everywhere, or the named regions of
#: :func:`bodystudio.reconstruct.evaluate.vertex_regions` (and ``lower_torso``), joined by ``+``.
SHAPE_PRIOR_REGIONS = ("head", "torso", "lower_torso", "crotch", "arms", "hands", "legs", "feet")
#: A tracked run's shape prior when none is asked for (``shape_prior="auto"``; docs/reconstruct.md, rec15p / rec15q):
#: the shape space fitted to a (re-)initialised frame whose back the rims reach on less than 0.4 of its vertices,
#: carried into the tracked frames, everywhere but the crotch. Without tracking ``auto`` is ``off``.
TRACKED_SHAPE_PRIOR = {"shape_prior": "carried", "shape_prior_reach": 0.4,
                       "shape_prior_region": "head+torso+arms+hands+legs+feet"}
#: What the pose refinement fits: the silhouettes' distance fields (an implicit visual hull, default) or
#: the carved visual hull.
REFINE_DATA = ("fields", "hull")
#: Bone lengths of the pose initialisation: each frame's tracked lengths, or one median set per run.
BONE_LENGTHS = ("frame", "sequence")
OUTPUT_DIR = "reconstruct"
RUN_MANIFEST = "run.json"
#: The largest distance between two joints of one person (arms raised, ~2.3 m) with a margin, in metres.
MAX_JOINT_SPAN_M = 3.5
#: The Kinect v2 Neck joint's row (:func:`bodystudio.reconstruct.pose_init.neck_at_joint`).
NECK_JOINT = kinect_joint_names("v2").index("Neck")
#: Kinect v1 joint names that have a v2 counterpart.
V1_TO_V2 = {"HipCenter": "SpineBase", "Spine": "SpineMid", "ShoulderCenter": "SpineShoulder"}


def parse_frames(text: str | None, frame_ids: list[int]) -> list[int]:
    """``"A:B"`` (B exclusive, either side optional) or ``"N"`` -> the session frames selected."""
    if text is None or text == "":
        return list(frame_ids)
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            lo = int(a) if a.strip() else min(frame_ids)
            hi = int(b) if b.strip() else max(frame_ids) + 1
        else:
            lo = int(text)
            hi = lo + 1
    except ValueError:
        raise InputError(f"--frames {text!r} must be A:B (B exclusive) or a single frame number") from None
    first, end = min(frame_ids), max(frame_ids) + 1
    if lo >= hi:
        raise InputError(f"--frames {text!r}: A must be below B (B exclusive), e.g. {first}:{end}")
    if lo < first or hi > end:  # a clipped range would run fewer frames than asked for, with exit 0
        raise InputError(f"--frames {text!r} reaches outside the session, which has {len(frame_ids)} frames "
                         f"({first}:{end}); give a range within {first}:{end}")
    sel = [f for f in frame_ids if lo <= f < hi]
    if not sel:
        raise InputError(f"--frames {text!r} selects no frame; the session has frames "
                         f"{min(frame_ids)}..{max(frame_ids)}")
    return sel


def joints_v2(names: list[str], positions: np.ndarray, tracked: np.ndarray | None = None) -> np.ndarray:
    """Kinect v2 joint array (25, 3) from named joints (v1 or v2 names); untracked -> NaN."""
    pos = np.asarray(positions, dtype=np.float64).reshape(len(names), 3).copy()
    if tracked is not None:
        pos[~np.asarray(tracked, bool)] = np.nan
    mapping = {V1_TO_V2.get(n, n): pos[k] for k, n in enumerate(names)}
    return joints_from_mapping(mapping, kinect_joint_names("v2"))


def frame_joints(session, frame, source: str, joints_dir: Path | None, player: int | None = None) -> np.ndarray:
    """The frame's tracker joints (studio frame) from the session or a folder of per-frame JSON files; ``player``:
    the run's subject in this frame (:func:`run_subject`; None: the frame's lowest player id)."""
    where = f"{session.path} frame {frame.frame_id}"
    if source == "tracker":
        data = frame.kinect_joints if player is None else subject_body(frame, player)
        if data is None and frame.kinect_joints is not None:
            raise SessionError(f"{where}: the run's subject (player {player}) is not among the tracked bodies; "
                               "reconstruct the frames before it (--frames A:B)")
        if data is None:
            raise SessionError(f"{where}: no Kinect tracker joints; use --joints file --joints-path DIR")
        J = joints_v2(data["names"], data["positions"], data["tracked"])
    elif source == "file":
        if joints_dir is None:
            raise InputError("--joints file needs --joints-path DIR with NNNNN.json files ({names, positions})")
        data = read_json(Path(joints_dir) / f"{frame.frame_id:05d}.json", "joints file")
        try:
            J = joints_v2(list(data["names"]), np.asarray(data["positions"], float), data.get("tracked"))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{joints_dir}/{frame.frame_id:05d}.json: needs names and positions ({exc})") from None
    else:
        raise InputError(f"unknown joint source {source!r}; valid: {', '.join(JOINT_SOURCES)}")
    finite = np.all(np.isfinite(J), axis=1)
    if np.count_nonzero(finite) < 3:
        raise InputError(f"{where}: no valid joints (fewer than 3 tracked); check the tracker output")
    P = J[finite]
    span = float(np.max(np.linalg.norm(P[:, None] - P[None], axis=2)))
    if span > MAX_JOINT_SPAN_M:  # millimetres or centimetres gave a giant skeleton and a meaningless fit, exit 0
        what = f"{joints_dir}/{frame.frame_id:05d}.json" if source == "file" else where
        raise InputError(f"{what}: the joints span {span:.4g} m, more than a person ({MAX_JOINT_SPAN_M} m); give "
                         "positions in metres in the studio's world frame")
    return J


def run_joints(session, selected, joints: str, joints_path, smoothing: int = 0,
               subject: dict | None = None) -> np.ndarray:
    """The ``selected`` frames' joints ``(T, 25, 3)``, smoothed over time with a half window of ``smoothing``
    frames (:func:`bodystudio.reconstruct.pose_init.smooth_joint_track`; 0: as tracked); ``subject``: the run's
    player per frame (:func:`run_subject`)."""
    jdir = Path(joints_path) if joints_path else None
    subject = subject or {}
    raw = np.array([frame_joints(session, session.frame(f), joints, jdir, subject.get(f)) for f in selected])
    return smooth_joint_track(np.asarray(selected), raw, smoothing)


def run_bone_lengths(session, selected, joints: str, joints_path, subject: dict | None = None) -> np.ndarray:
    """One set of bone lengths for a run (``--bone-lengths sequence``): the median over its ``selected``
    frames of the tracked lengths (:func:`bodystudio.reconstruct.pose_init.sequence_bone_lengths`) of the run's
    subject (``subject``: its player per frame, :func:`run_subject`)."""
    jdir = Path(joints_path) if joints_path else None
    subject = subject or {}
    return sequence_bone_lengths([frame_joints(session, session.frame(f), joints, jdir, subject.get(f))
                                  for f in selected])


def subject_record(subject: dict | None) -> dict:
    """run.json's record of the run's subject (:func:`run_subject`): ``subject_player``, the tracker's id of the
    person reconstructed (at the first frame), and ``subject_players`` ``{frame: id}`` where the tracker gave them
    another id later; empty when the joints are not the session's tracker's."""
    if subject is None:
        return {}
    ids = [p for p in subject.values() if p is not None]
    first = ids[0] if ids else None
    out: dict = {"subject_player": first}
    if any(p != first for p in ids):
        out["subject_players"] = {str(f): p for f, p in subject.items()}
    return out


def subject_depth(session, frame, depth_m: np.ndarray, player: int) -> np.ndarray:
    """The frame's depth without the pixels the tracker's player mask gives to another person
    (:func:`bodystudio.capture.subject.other_players_removed`; unchanged where the frame has no mask)."""
    from bodystudio.capture.session import stream_path
    from bodystudio.capture.subject import other_players_removed

    try:
        return other_players_removed(depth_m, frame.kinect_player, player)
    except ValueError as exc:
        raise SessionError(f"{session.path / stream_path('kinect_player', frame.frame_id)}: {exc}; "
                           "regenerate the session") from None


def run_subject(session, selected, joints: str, player: int | None = None) -> dict[int, int | None] | None:
    """The run's subject: ``{frame id: player id}`` over ``selected`` (:func:`bodystudio.capture.subject.
    session_subject`: chosen at the first frame with a tracked body, its lowest id unless ``player``, and followed),
    None unless ``joints`` is the session's tracker. A frame whose tracked bodies do not include the subject is
    refused (SessionError naming its joints file and the fix) rather than fitted to another person."""
    from bodystudio.capture.session import stream_path
    from bodystudio.capture.subject import absent_frames, frame_bodies, session_subject

    if joints != "tracker":
        return None
    reasons: dict = {}
    subject = session_subject(session, selected, player, reasons=reasons)
    gone = absent_frames(subject, session)
    if gone:
        chosen = next((p for p in subject.values() if p is not None), player)
        before = [f for f in selected if f < gone[0]]
        others = sorted(b["player"] for b in frame_bodies(session.frame(gone[0])))
        fix = f"reconstruct the frames before it (--frames {before[0]}:{gone[0]})" if before else \
            "choose the frames where the subject is tracked (--frames A:B)"
        how = "given" if player is not None else "the first tracked frame's lowest id"
        raise SessionError(f"{session.path / stream_path('kinect_joints', gone[0])}: the run's subject (player "
                           f"{chosen}, {how}) is not tracked in {len(gone)} of {len(selected)} frames (first "
                           f"{gone[0]}, where the tracker reports player{'s' if len(others) > 1 else ''} "
                           f"{', '.join(map(str, others))}: another person{reasons.get(gone[0], '')}); {fix}, "
                           "choose the person with "
                           "--player N, or use --joints hull")
    return subject


def gt_kinect_joints(frame, skeleton_names) -> np.ndarray | None:
    """Ground-truth Kinect v2 joints of a synthetic frame (from the posed GT skeleton)."""
    gt = frame.gt_joints
    if gt is None:
        return None
    from bodystudio.body.skeleton import Skeleton

    n = len(gt["bone_names"])
    sk = Skeleton(tuple(gt["bone_names"]), np.full(n, -1), gt["heads"], gt["tails"], np.zeros(n))
    try:
        return kinect_joints(sk, gt["heads"], gt["tails"], "v2")
    except InputError:
        return None


def score_frame(V: np.ndarray, F: np.ndarray, frame, cameras, regions=None, joints=None) -> dict | None:
    """Errors of one reconstructed frame against the session's ground truth (None without GT)."""
    gt = frame.gt_mesh
    if gt is None:
        return None
    visible = visible_vertices(gt.vertices, gt.faces, cameras)
    err = surface_error(V, F, gt.vertices, gt.faces, visible)
    out = err.as_dict()
    masks = frame.gt_masks if "gt_mask" in frame.session.streams else frame.masks
    iou = silhouette_iou(V, F, cameras, {c.name: masks[c.name] for c in cameras})
    out["iou"] = iou
    out["iou_min"] = min(iou.values())
    if regions is not None:
        out["regions"] = region_errors(V, gt.vertices, gt.faces, regions)
    if joints is not None:
        gtj = gt_kinect_joints(frame, None)
        if gtj is not None:
            out["joint_error_mm"] = joint_error_mm(joints, gtj)
    return out


def reconstruct_session(path: str | Path, solver: str = "gs", template: str = "13k", joints: str = "tracker",
                        constraints: tuple[str, ...] = ("silhouette",), frames: str | None = None,
                        joints_path: str | Path | None = None, params: RapidSkinParams | None = None,
                        warm_start: bool = False, refine_pose: bool = True, score: bool = True,
                        progress: bool = False, tracking: bool = False, track_params: TrackParams | None = None,
                        refine_with: str = "fields", rest_cotangents: bool = True,
                        refine_params: PoseRefineParams | None = None, bone_lengths: str = "sequence",
                        joint_smoothing: int = 0, accept_implausible: bool = False, shape_prior: str = "auto",
                        shape_prior_outer: int = 0, shape_prior_first_outer: int = 0,
                        refine_depth: float = 0.0, refine_depth_bones="neck",
                        refine_depth_guard: float = 0.0, smoothing_guard: float = 0.0,
                        player: int | None = None, shape_prior_region: str | None = None,
                        shape_prior_reach: float | None = None) -> dict:
    """Reconstruct every selected frame of a session; writes ``SESSION/reconstruct/`` and returns a summary.

    The run checks itself (:mod:`bodystudio.reconstruct.plausibility`): a camera whose silhouette the fit
    cannot explain, or depth that does not fit the body, raises :class:`ImplausibleResultError` and writes
    nothing unless ``accept_implausible`` (then the verdict is kept in ``run.json``).

    ``refine_pose`` corrects the pose initialised from the joints (§IV.A) by an articulated fit of the
    2.5K template's bone transforms to the silhouettes' visual hull before the deformation (§III);
    off, the template is posed from the joints alone, as in the paper. ``tracking`` starts each frame
    from the previous one's pose unless the lost-track check fires; off (default: measured more
    accurate, docs/reconstruct.md), every frame is initialised from its joints (:func:`reconstruct_frames`).
    ``refine_with``: ``fields`` (default) fits the refinement to the implicit visual hull of the
    silhouettes' distance fields, ``hull`` to the carved visual hull.
    ``shape_prior`` (issue 15's unseen surfaces, :mod:`bodystudio.reconstruct.shape_prior`; ``auto``, the default:
    :data:`TRACKED_SHAPE_PRIOR` with ``tracking``, ``off`` without, :func:`resolve_shape_prior`; measured in
    docs/reconstruct.md): ``frame`` fits the statistical body model's shape space to each frame's
    deformation and runs Algorithm 1 again from that shape (``shape_prior_outer`` re-matchings, 0: the
    frame's own), ``run`` starts every later frame from the mean shape fitted to the frames before it,
    ``carried`` fits it to the (re-)initialised frames' one pass only and starts the tracked frames from it
    (with ``tracking``; no second pass, so ``shape_prior_outer`` / ``shape_prior_first_outer`` do not apply, and no
    fit on a tracked frame). ``shape_prior_region`` (``all``, or region
    names joined by ``+``, :data:`SHAPE_PRIOR_REGIONS`) restricts the fitted shape to those regions, the
    template's elsewhere (:func:`bodystudio.reconstruct.shape_prior.region_blend_weights`).
    ``shape_prior_region`` / ``shape_prior_reach`` None: the ``auto`` setting's, else ``all`` / 0.
    ``shape_prior_reach`` (``carried`` only; 0: off) gates ``carried`` by the run's own data: a (re-)initialised
    frame's fitted shape is carried only where the silhouettes' rims reached less than this share of the middle of
    the back (:func:`bodystudio.reconstruct.shape_prior.back_patch` / ``rim_reach``, the deformation's last outer
    iteration): a back the rims reach is carried out by the side views (the walks) and the fitted shape would
    take that up, a back no rim reaches (a stout subject's, behind the arms) is the template's (issue 15, rec15q).
    ``refine_depth`` (issue 15's neck front; 0: off) weights the Kinect's point-to-plane residuals in the pose
    refinement beside the silhouettes (:mod:`bodystudio.reconstruct.pose_depth`; with depth constraints), of
    the vertices of ``refine_depth_bones`` (``neck``: the neck and head, default; ``all``; or bone names).
    ``player``: the Kinect player id of the person to reconstruct (default: the lowest id of the first frame with
    a tracked body), followed over the run (:func:`run_subject`).
    """
    from bodystudio.capture.session import MAX_PLAYERS, open_session

    if template not in TEMPLATES:
        raise InputError(f"unknown template {template!r}; valid: 13k, 6k, 2k")
    if joints not in JOINT_SOURCES:
        raise InputError(f"unknown joint source {joints!r}; valid: {', '.join(JOINT_SOURCES)}")
    if joints == "file" and joints_path is None:
        raise InputError("--joints file needs --joints-path DIR with NNNNN.json files ({names, positions})")
    if player is not None and (type(player) is not int or not 1 <= player <= MAX_PLAYERS):
        raise InputError(f"player {player!r}: the Kinect SDK numbers players 1 to {MAX_PLAYERS}")
    if player is not None and joints != "tracker":
        raise InputError(f"player {player}: chooses among the session's tracked bodies; use joints 'tracker' "
                         f"(not {joints!r}) or no player")
    session = open_session(path)
    params = params or RapidSkinParams(solver=solver, constraints=tuple(constraints))
    cameras = list(session.cameras)
    if set(session.camera_names) != {c.name for c in cameras}:
        raise SessionError(f"{session.path}: the manifest lists cameras {', '.join(session.camera_names)} but "
                           f"calibration/cameras.json has {', '.join(c.name for c in cameras)}; "
                           "camera/session mismatch")
    selected = parse_frames(frames, session.frame_ids)
    sensor = session.kinect
    if "depth" in params.constraints and sensor is None:
        raise SessionError(f"{session.path}: no Kinect calibration, so no depth constraints; "
                           "use --constraints silhouette")
    subject = run_subject(session, selected, joints, player)  # refused here, before the run folder is touched
    layout = reconstruction_layout(session.path)
    with RunWriter(layout, "bodystudio reconstruct", {"session": str(session.path), "template": template}) as writer:
        return reconstruct_frames(session, writer, selected, cameras, sensor, params, solver, template, joints,
                                   joints_path, warm_start, refine_pose, score, progress, tracking=tracking,
                                   track_params=track_params, refine_with=refine_with,
                                   rest_cotangents=rest_cotangents, refine_params=refine_params,
                                   bone_lengths=bone_lengths, joint_smoothing=joint_smoothing,
                                   accept_implausible=accept_implausible, shape_prior=shape_prior,
                                   shape_prior_outer=shape_prior_outer,
                                   shape_prior_first_outer=shape_prior_first_outer, refine_depth=refine_depth,
                                   refine_depth_bones=refine_depth_bones, refine_depth_guard=refine_depth_guard,
                                   smoothing_guard=smoothing_guard, subject=subject,
                                   shape_prior_region=shape_prior_region, shape_prior_reach=shape_prior_reach)


def resolve_shape_prior(tracking: bool, shape_prior: str = "auto", reach: float | None = None,
                        region: str | None = None) -> tuple[str, float, str]:
    """The run's shape prior, gate and region: ``auto`` is :data:`TRACKED_SHAPE_PRIOR` with ``tracking`` (its gate
    and region unless given) and ``off`` without; any other prior keeps what is given (``reach`` None: 0, ungated;
    ``region`` None: ``all``)."""
    if shape_prior == "auto":
        if tracking:
            auto = TRACKED_SHAPE_PRIOR
            return (auto["shape_prior"], auto["shape_prior_reach"] if reach is None else reach,
                    auto["shape_prior_region"] if region is None else region)
        shape_prior = "off"
    return shape_prior, 0.0 if reach is None else reach, "all" if region is None else region


def reconstruction_layout(session_path: str | Path) -> RunLayout:
    """Lock, staging and manifest (``run.json``) of ``SESSION/reconstruct/``."""
    out_dir = Path(session_path) / OUTPUT_DIR
    return RunLayout(out_dir, RUN_MANIFEST, ".", str(out_dir))


def reconstruct_frames(session, writer: RunWriter, selected, cameras, sensor, params, solver, template, joints,
                       joints_path, warm_start, refine_pose, score, progress, tracking: bool = False,
                       track_params: TrackParams | None = None, refine_with: str = "fields",
                       rest_cotangents: bool = True, refine_params: PoseRefineParams | None = None,
                       bone_lengths="sequence", joint_smoothing: int = 0, accept_implausible: bool = True,
                       shape_prior: str = "auto", shape_prior_outer: int = 0, shape_prior_first_outer: int = 0,
                       refine_depth: float = 0.0, refine_depth_bones="neck",
                       refine_depth_guard: float = 0.0, smoothing_guard: float = 0.0, subject: dict | None = None,
                       player: int | None = None, shape_prior_region: str | None = None,
                       shape_prior_reach: float | None = None) -> dict:
    """Reconstruct the ``selected`` frames into the open ``writer`` (warm start and tracking within the
    list); the sequential run and each batch chunk (:mod:`bodystudio.batch`) call it.

    With ``tracking`` (off by default) a frame starts from the previous frame's pose fitted to its
    silhouettes (:mod:`bodystudio.reconstruct.tracking`); the joints' initialisation and the hull fit
    run at the first frame and when the lost-track check fires. frames.json records per frame
    ``track`` (``tracked``, or why it was initialised: first, joint_jump, silhouette, energy_jump,
    limbs_far, per_frame) and the whole-frame time by step. With ``rest_cotangents`` (default) the cotangent
    weights of Eq. 8 come from the template's rest shape, computed once per run, and only the delta
    coordinates are taken of each frame's posed template: measured equal in accuracy to weights of the
    posed template (p90 within +-0.3 mm on 3 frames of a 13K walk), ~15 ms per 13K frame saved.
    Each frame's self-check (:func:`bodystudio.reconstruct.plausibility.frame_plausibility`) goes to
    frames.json and the run's verdict to run.json (``plausibility``); an implausible run raises
    :class:`ImplausibleResultError` before anything is committed unless ``accept_implausible`` (the default
    here, for a batch chunk, whose whole run is judged by :func:`bodystudio.batch.reconstruct_batch`).
    ``subject`` (``{frame id: player id}``, :func:`run_subject`) is the person the tracker joints, the bone
    lengths and the depth are taken of; None: chosen over ``selected`` (``player``: its id, else the first
    tracked frame's lowest), which a batch chunk must not do (it gets the whole run's).
    """
    from bodystudio.body import build_body
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import progress_bar

    track_params = track_params or TrackParams()
    if refine_with not in REFINE_DATA:
        raise InputError(f"unknown pose refinement data {refine_with!r}; valid: {', '.join(REFINE_DATA)}")
    lengths = None
    if not isinstance(bone_lengths, str):  # lengths given (a batch chunk gets the whole run's)
        lengths = np.asarray(bone_lengths, dtype=np.float64)
        if lengths.shape != (len(kinect_joint_names("v2")),):
            raise InputError(f"bone lengths: need one per Kinect v2 joint ({len(kinect_joint_names('v2'))}), "
                             f"got shape {lengths.shape}")
        bone_lengths = "given"
    elif bone_lengths not in BONE_LENGTHS:
        raise InputError(f"unknown bone lengths {bone_lengths!r}; valid: {', '.join(BONE_LENGTHS)}")
    if not 0 <= int(joint_smoothing) <= 50:
        raise InputError(f"--joint-smoothing {joint_smoothing}: give a half window of 0..50 frames")
    if subject is None:
        subject = run_subject(session, selected, joints, player)
    players = subject or {}
    smoothed = None
    if refine_params is None and joint_smoothing and joints != "hull":
        # with steadier Neck and Head joints the head's own pitch pays (docs/reconstruct.md)
        refine_params = PoseRefineParams(bones=REFINE_BONES_WITH_HEAD)
    if joint_smoothing and joints != "hull":
        # the run's tracked joints smoothed over time (and the bone lengths taken of them)
        smoothed = dict(zip(selected, run_joints(session, selected, joints, joints_path, joint_smoothing, players),
                            strict=True))
        if bone_lengths == "sequence":
            lengths = sequence_bone_lengths(list(smoothed.values()))
    elif bone_lengths == "sequence" and joints != "hull":
        lengths = run_bone_lengths(session, selected, joints, joints_path, players)
    body = build_body(resolution=TEMPLATES[template])
    F = body.faces
    if not 0 <= int(shape_prior_first_outer) <= 100:
        raise InputError(f"shape_prior_first_outer {shape_prior_first_outer}: give 0 (the run's No) to 100 outer "
                         "iterations")
    if not 0 <= int(shape_prior_outer) <= 100:
        raise InputError(f"shape_prior_outer {shape_prior_outer}: give 0 (the run's No) to 100 outer iterations")
    for name, guard in (("refine_depth_guard", refine_depth_guard), ("smoothing_guard", smoothing_guard)):
        if not (np.isfinite(guard) and 0.0 <= guard <= 10.0):
            raise InputError(f"{name} {guard:g}: give a relative tolerance in [0, 10] (0: off)")
    if not (np.isfinite(refine_depth) and 0.0 <= refine_depth <= 1000.0):
        raise InputError(f"refine_depth {refine_depth:g}: give a weight in [0, 1000] (0: the refinement fits the "
                         "silhouettes only)")
    if shape_prior not in (*SHAPE_PRIORS, "auto"):
        raise InputError(f"unknown shape prior {shape_prior!r}; valid: auto, {', '.join(SHAPE_PRIORS)}")
    shape_prior, shape_prior_reach, shape_prior_region = resolve_shape_prior(tracking, shape_prior, shape_prior_reach,
                                                                             shape_prior_region)
    if shape_prior == "carried" and not tracking:
        raise InputError("shape prior 'carried' carries the initialised frames' shape into the tracked frames; "
                         "use it with tracking, or shape_prior 'run' / 'frame'")
    if not (np.isfinite(shape_prior_reach) and 0.0 <= shape_prior_reach <= 1.0):
        raise InputError(f"shape_prior_reach {shape_prior_reach:g}: give a share of the back's vertices in [0, 1] "
                         "(0: off)")
    if shape_prior_reach > 0 and shape_prior != "carried":
        raise InputError(f"shape_prior_reach {shape_prior_reach:g} gates the carried shape prior; use it with "
                         f"shape_prior 'carried' (not {shape_prior!r}) or leave it 0")
    back = back_patch(body) if shape_prior_reach > 0 else None
    prior_regions = () if shape_prior_region == "all" else tuple(str(shape_prior_region).split("+"))
    unknown = [r for r in prior_regions if r not in SHAPE_PRIOR_REGIONS]
    if unknown or (shape_prior_region != "all" and not prior_regions):
        raise InputError(f"shape_prior_region {shape_prior_region!r}: give all or region names joined by + "
                         f"({', '.join(SHAPE_PRIOR_REGIONS)})")
    use_shape = shape_prior != "off"
    # loaded on first use: a gated run whose rims reach every initialised frame's back never fits a shape
    shape_model = functools.cache(lambda: load_statistical_model(TEMPLATES[template], progress=False))
    shape_coeffs = []  # shape_prior "run" / "carried": the coefficients fitted to each (initialised) frame so far
    regions = vertex_regions(body) if score else None
    prior_kw = {}  # the shape prior's region weights, only when a region is asked for
    if prior_regions and use_shape:
        prior_kw["region_weights"] = region_blend_weights(
            body, regions if regions is not None else vertex_regions(body), prior_regions)
    hold = {}  # Algorithm 1's hold_vertices, only when a region is asked for
    if params.surface_hold_k > 0 and params.surface_hold_region != "all":
        # issue 15's drift is the torso's: limbs need the later re-matchings
        hold["hold_vertices"] = (regions if regions is not None else vertex_regions(body)) == params.surface_hold_region
    rest_delta = cotangent_weights(body.vertices, F) if rest_cotangents else None
    rest = body.vertices
    shape_sum, n_seen = body.vertices.copy(), 1
    hull_pose = None
    fit_body = build_body(resolution="2k") if refine_pose or joints == "hull" or tracking else None
    depth_rows = None
    if refine_depth > 0 and fit_body is not None and refine_depth_bones != "all":
        bones = refine_depth_bones
        if isinstance(bones, str):  # "neck" or bone names joined by "+"
            bones = DEPTH_BONES if bones == "neck" else tuple(b for b in bones.split("+") if b)
        missing = [b for b in bones if b not in fit_body.skeleton.bone_names]
        if missing or not bones:
            raise InputError(f"refine_depth_bones: no bone(s) {', '.join(missing) or '(none given)'} in the template; "
                             "give neck, all or bone names joined by +")
        depth_rows = bone_vertices(fit_body, bones)
    def placed_neck(T, J):
        """The transforms the deformed template is posed with: a tracked run's neck on the frame's tracked Neck
        joint (issue 15, rec15l: :func:`neck_at_joint`), the tracker's pose ``T`` kept as the next frame's prior."""
        if not (tracking and track_params.neck_joint) or J is None:
            return T
        return neck_at_joint(body, T, J[NECK_JOINT], unstretch_head=track_params.unstretch_head)

    state = None  # the previous frame's (bone transforms, global scale, tracker joints, silhouette energy)
    records = []
    probe = coherence_frames(len(selected))
    with progress_bar(progress) as bar:
        task = bar.add_task(f"rapid skin {solver} {template}", total=len(selected))
        for fid in selected:
            t_start = time.perf_counter()
            frame = session.frame(fid)
            masks = None
            if "silhouette" in params.constraints or joints == "hull" or refine_pose or tracking:
                masks = {name: frame.masks[name] for name in frame.masks}
            depth_image = None
            if "depth" in params.constraints:
                depth_image = frame.kinect_depth_m
                if depth_image is None:
                    raise SessionError(f"{session.path} frame {fid}: no Kinect depth image; "
                                       "use --constraints silhouette")
                if players.get(fid) is not None and "kinect_player" in session.streams:
                    depth_image = subject_depth(session, frame, depth_image, players[fid])
            t_read = time.perf_counter() - t_start
            t0 = time.perf_counter()
            J = None
            if joints != "hull":
                J = (smoothed[fid] if smoothed is not None
                     else frame_joints(session, frame, joints, Path(joints_path) if joints_path else None,
                                       players.get(fid)))
                if lengths is not None:
                    J = with_bone_lengths(J, lengths)
            t1 = time.perf_counter()
            fields = (SilhouetteFields(cameras, masks, exact=track_params.exact_fields or not tracking)
                      if tracking or (refine_pose and refine_with == "fields") else None)
            t_fields = time.perf_counter() - t1
            track = "per_frame"
            detail = {}
            if smoothed is not None and smoothing_guard > 0 and fields is not None and fit_body is not None:
                # issue 15: the smoothing assumes video rate; where the smoothed joints' pose leaves more of the
                # template outside the silhouettes than the frame's own joints', the motion was not a line
                J_raw = frame_joints(session, frame, joints, Path(joints_path) if joints_path else None,
                                     players.get(fid))
                if lengths is not None:
                    J_raw = with_bone_lengths(J_raw, lengths)
                e_smooth, e_raw = (outside_fraction(initialise_pose(fit_body, X).vertices, fields,
                                                    track_params.outside_px) for X in (J, J_raw))
                detail["smoothing_outside"] = [e_raw, e_smooth]
                if e_smooth > (1.0 + smoothing_guard) * e_raw + 1e-4:
                    J = J_raw
            init = fit_T = None
            t_track = 0.0
            if tracking:
                t1 = time.perf_counter()
                jump = torso_joint_jump_m(J, state["joints"]) if state else 0.0
                prior_out = (outside_fraction(pose_template(fit_body, state["T"]).vertices, fields,
                                              track_params.outside_px) if state else 1.0)
                detail.update(joint_jump_m=jump, prior_outside=prior_out)
                track = lost_track_reason(state is None, jump, prior_out, track_params) or "tracked"
                if track == "tracked":
                    T_joints = (initialise_pose(fit_body, J).bone_transforms
                                if J is not None and track_params.joint_weight > 0 else None)
                    T = track_bone_transforms(fit_body, state["T"], fields, track_params, T_joints)
                    fitted = pose_template(fit_body, T)
                    energy = outside_fraction(fitted.vertices, fields, track_params.outside_px)
                    detail["energy"] = energy
                    # rec15r: a limb lost inside the visual hull of few or small views leaves the tracker's joint
                    residual = tracker_joint_residual(fitted.joints, J)
                    if residual is not None:
                        detail["limb_joint_mm"] = residual["max_mm"]
                    if energy_jumped(energy, state["energy"], track_params):
                        track = "energy_jump"
                    elif limbs_far(residual and residual["max_mm"], track_params):
                        track = "limbs_far"
                    else:
                        fit_T = T  # the posing below places the neck (one LBS of the 13K template a frame)
                        init = pose_template(body, placed_neck(T, J), state["scale"], rest_vertices=rest)
                t_track = time.perf_counter() - t1
            hull = None
            depth = None
            t_refine = 0.0
            if init is None:
                if joints == "hull":
                    # Rapid Skin contribution 4: joints from the silhouettes' visual hull (articulated fit of
                    # a 2.5K template, warm-started from the previous frame's pose).
                    hull = visual_hull(cameras, masks)
                    fit = fit_body_to_hull(fit_body, hull, previous_pose=hull_pose)
                    J, hull_pose = fit.joints, fit.pose
                init = initialise_pose(body, J, rest_vertices=rest)
                if refine_pose:
                    t1 = time.perf_counter()
                    # The template and the refinement's 2.5K template share one skeleton, so the corrected
                    # bone transforms pose the template directly.
                    if refine_with == "fields":
                        term = silhouette_data_term(fields, track_params)
                        if refine_depth > 0 and depth_image is not None:
                            # issue 15: the depth sees the neck's front, which the silhouettes do not
                            depth = depth_observation(depth_image, sensor.depth)
                            both = combined_data_term(term, depth_data_term(depth, fit_body.faces, refine_depth,
                                                                             vertices=depth_rows))
                            T = refine_bone_transforms(fit_body, init.bone_transforms, None, refine_params,
                                                       data_term=both)
                            if refine_depth_guard > 0:
                                # the depth's pose only where the silhouettes do not contradict it
                                T_sil = refine_bone_transforms(fit_body, init.bone_transforms, None, refine_params,
                                                               data_term=term)
                                e_sil, e_both = (outside_fraction(pose_template(fit_body, X).vertices, fields,
                                                                  track_params.outside_px) for X in (T_sil, T))
                                detail["refine_depth_outside"] = [e_sil, e_both]
                                if e_both > (1.0 + refine_depth_guard) * e_sil + 1e-4:
                                    T = T_sil
                        else:
                            T = refine_bone_transforms(fit_body, init.bone_transforms, None, refine_params,
                                                       data_term=term)
                    else:
                        if hull is None:
                            hull = visual_hull(cameras, masks)
                        T = refine_bone_transforms(fit_body, init.bone_transforms, hull, refine_params)
                    init = pose_template(body, T, init.global_scale, rest_vertices=rest)
                    t_refine = time.perf_counter() - t1
                if tracking:
                    t1 = time.perf_counter()
                    detail["energy"] = outside_fraction(pose_template(fit_body, init.bone_transforms).vertices,
                                                        fields, track_params.outside_px)
                    t_track += time.perf_counter() - t1
            if fit_T is None:  # a (re-)initialised frame: its fitted pose, posed again with the neck placed
                fit_T = init.bone_transforms
                placed = placed_neck(fit_T, J)
                if placed is not fit_T:
                    init = pose_template(body, placed, init.global_scale, rest_vertices=rest)
            V_start, frame_params = init.vertices, params
            if tracking and track != "tracked" and (track_params.initial_outer_iterations
                                                    or track_params.initial_inner_iterations):
                # issue 15: the first frame's later re-matchings drift the upper back outwards (rec15m); more
                # sweeps carry the rims' pull to what no rim reaches (rec15n)
                no, ni = track_params.initial_outer_iterations, track_params.initial_inner_iterations
                frame_params = replace(params, outer_iterations=min(params.outer_iterations, no) if no
                                       else params.outer_iterations, inner_iterations=ni or params.inner_iterations)
            if track == "tracked":
                if track_params.warm_mesh:
                    V_start = carry_deformed_mesh(state["V"], state["posed"], init.vertices)
                if track_params.outer_iterations:  # never more re-matchings than the run's No
                    frame_params = replace(params, outer_iterations=min(params.outer_iterations,
                                                                        track_params.outer_iterations))
                frame_params = replace(frame_params, matching=track_params.matching)
                if track_params.tau_px:  # the nearer start's search range, never above the run's
                    frame_params = replace(frame_params, tau_px=min(frame_params.tau_px, track_params.tau_px))
                if track_params.inner_iterations:
                    frame_params = replace(frame_params, inner_iterations=track_params.inner_iterations)
            if tracking:
                state = {"T": fit_T, "scale": init.global_scale, "joints": J,
                         "energy": detail["energy"], "posed": init.vertices}
            # The smoothness prior keeps the generic template's delta coordinates, so shape errors in
            # regions no silhouette sees are not baked in and carried from frame to frame.
            reference = init.vertices if rest is body.vertices else pose_template(body, init.bone_transforms).vertices
            t_init = time.perf_counter() - t0
            if depth is None and depth_image is not None:
                depth = depth_observation(depth_image, sensor.depth)
            if "silhouette" not in params.constraints:
                masks = None
            carried = shape_prior == "carried"
            if (use_shape and shape_coeffs
                    and (shape_prior == "run" or (carried and track == "tracked"))):
                # the run's shape so far: this frame's start and smoothness reference (one pass)
                t1 = time.perf_counter()
                reference = posed_shape(shape_model(), body, np.mean(shape_coeffs, axis=0), init.bone_transforms,
                                        init.global_scale, **prior_kw)
                V_start = reference
                t_init += time.perf_counter() - t1
            delta = rest_delta if rest_delta is not None else cotangent_weights(reference, F)
            first_params = frame_params
            if (use_shape and shape_prior_first_outer and not carried
                    and (shape_prior == "frame" or not shape_coeffs)):
                # the pass the shape space is fitted to stops before the outer iterations drift
                first_params = replace(frame_params, outer_iterations=min(frame_params.outer_iterations,
                                                                          shape_prior_first_outer))
            result = deform_to_observations(V_start, F, cameras, masks, first_params, depth=depth, delta=delta,
                                            smooth_reference=reference, fields=fields, **hold)
            if use_shape and not carried and (shape_prior == "frame" or not shape_coeffs):
                # issue 15: the shape space's fit to the first pass starts and regularises a second pass, so
                # the surfaces no view sees take the fitted body's shape instead of the generic template's
                t1 = time.perf_counter()
                prior = shape_prior_mesh(shape_model(), body, result.vertices, init.bone_transforms,
                                         init.global_scale, **prior_kw)
                t_prior = time.perf_counter() - t1
                second_params = frame_params
                if shape_prior_outer:  # the second pass starts closer: fewer re-matchings
                    second_params = replace(frame_params, outer_iterations=min(frame_params.outer_iterations,
                                                                                 shape_prior_outer))
                second = deform_to_observations(prior, F, cameras, masks, second_params, depth=depth, delta=delta,
                                                smooth_reference=prior, fields=fields, **hold)
                second.solver_s += result.solver_s
                second.matching_s += result.matching_s
                second.n_silhouette = result.n_silhouette + second.n_silhouette
                second.n_depth = result.n_depth + second.n_depth
                t_init += t_prior
                result = second
            reached = False
            if back is not None and carried and track != "tracked":
                detail["back_rim_reach"] = rim_reach(result.silhouette_vertices, back)
                reached = detail["back_rim_reach"] >= shape_prior_reach  # the rims carry this back: not a shape
            if use_shape and (shape_prior == "run" or (carried and track != "tracked" and not reached)):
                t1 = time.perf_counter()
                shape_coeffs.append(deformed_shape_coefficients(shape_model(), body, result.vertices,
                                                                init.bone_transforms))
                t_init += time.perf_counter() - t1
            t_frame = time.perf_counter() - t_start
            V = result.vertices
            if tracking:
                state["V"] = V
            check_masks = masks
            if check_masks is None and "mask" in session.streams:
                check_masks = {name: frame.masks[name] for name in frame.masks}
            plausibility = frame_plausibility(V, F, cameras, check_masks, depth_image,
                                              sensor.depth if depth_image is not None else None,
                                              coherence=len(records) in probe)
            if joints != "hull":
                residual = tracker_joint_residual(init.joints, J)
                if residual is not None:  # a tracked frame's limbs follow the silhouettes alone (adv4's tiny session)
                    plausibility["tracker_joint_residual"] = {**residual, "frame": int(fid),
                                                              "tracked": track == "tracked"}
            untracked = untracked_limb_joints(J)
            if untracked:  # recorded where the tracker missed a limb joint (frames.json stays as it was elsewhere)
                plausibility["untracked_limb_joints"] = untracked
            save_mesh(writer.path_for(f"meshes/{fid:05d}.ply"), Mesh(V, F))
            if warm_start:
                # Running mean of the un-skinned results: the subject's shape accumulates while each
                # frame's correction of its own tracker-joint error (independent per frame) averages out.
                n_seen += 1
                shape_sum += unpose(V, body.weights, init.bone_transforms)
                rest = shape_sum / n_seen
            rec = {"frame": fid, "track": track, "solver_ms": 1000 * result.solver_s,
                   "matching_ms": 1000 * result.matching_s, "init_ms": 1000 * t_init, "refine_ms": 1000 * t_refine,
                   "track_ms": 1000 * t_track, "fields_ms": 1000 * t_fields, "read_ms": 1000 * t_read,
                   "frame_ms": 1000 * t_frame,
                   "other_ms": 1000 * (t_frame - t_read - t_init - result.solver_s - result.matching_s),
                   "n_silhouette": result.n_silhouette, "n_depth": result.n_depth,
                   "ms_per_frame": 1000 * (result.solver_s + result.matching_s + t_init),
                   "plausibility": plausibility}
            if "smoothing_outside" in detail:
                rec["smoothing_outside"] = [float(e) for e in detail.pop("smoothing_outside")]
            if "refine_depth_outside" in detail:
                rec["refine_depth_outside"] = [float(e) for e in detail.pop("refine_depth_outside")]
            if "back_rim_reach" in detail:
                rec["back_rim_reach"] = float(detail.pop("back_rim_reach"))
            if detail:
                rec["track_check"] = {k: float(v) for k, v in detail.items()}
            if score:
                rec["metrics"] = score_frame(V, F, frame, cameras, regions, init.joints)
            records.append(rec)
            bar.advance(task)
    verdict = judge_run(records, session.path, accept_implausible)
    writer.write_json("frames.json", {"frames": records})
    previous = [f"meshes/{p.name}" for p in (writer.layout.root / "meshes").glob("*.ply")]
    writer.commit({"solver": params.solver, "template": template, "joints": joints,
                   "constraints": list(params.constraints), "frames": selected,
                   "warm_start": warm_start, "refine_pose": refine_pose, "tracking": tracking,
                   "refine_with": refine_with, "rest_cotangents": rest_cotangents, "bone_lengths": bone_lengths,
                   "joint_smoothing": int(joint_smoothing), "shape_prior": shape_prior,
                   "shape_prior_outer": int(shape_prior_outer),
                   "shape_prior_first_outer": int(shape_prior_first_outer),
                   "shape_prior_region": str(shape_prior_region),
                   "shape_prior_reach": float(shape_prior_reach),
                   "refine_depth": float(refine_depth),
                   "refine_depth_guard": float(refine_depth_guard), "smoothing_guard": float(smoothing_guard),
                   "refine_depth_bones": (refine_depth_bones if isinstance(refine_depth_bones, str)
                                          else "+".join(refine_depth_bones)),
                   "refine_bones": list((refine_params or PoseRefineParams()).bones) if refine_pose else [],
                   "params": asdict(params), "n_vertices": int(len(body.vertices)),
                   "track_params": asdict(track_params) if tracking else None,
                   **subject_record(subject), "plausibility": verdict}, deletes=previous)
    return summarize(records)


def judge_run(records: list[dict], session_path, accept_implausible: bool) -> dict:
    """The run's self-check verdict (:func:`bodystudio.reconstruct.plausibility.run_plausibility`) over its
    frame records; raises :class:`ImplausibleResultError` (one line: the camera or input, and the fix) when it
    found a problem, unless ``accept_implausible`` (then the problems are logged as warnings)."""
    verdict = run_plausibility([r["plausibility"] for r in records if r.get("plausibility")], session_path)
    if not verdict["ok"] and not accept_implausible:
        raise ImplausibleResultError(f"{session_path}: reconstruction not written, {verdict['problems'][0]}; "
                                     "or pass --accept-implausible")
    for line in verdict["warnings"] + verdict["problems"]:
        log.warning("%s: %s", session_path, line)
    return verdict


def summarize(records: list[dict]) -> dict:
    """Session summary: timings and, when scored, visible-surface errors (mean over frames of each figure)."""
    out = {"frames": len(records),
           "ms_per_frame": float(np.mean([r["ms_per_frame"] for r in records])),
           "solver_ms": float(np.mean([r["solver_ms"] for r in records])),
           "matching_ms": float(np.mean([r["matching_ms"] for r in records])),
           "init_ms": float(np.mean([r.get("init_ms", 0.0) for r in records])),
           "refine_ms": float(np.mean([r.get("refine_ms", 0.0) for r in records]))}
    for key in ("frame_ms", "read_ms", "fields_ms", "track_ms", "other_ms"):
        if all(key in r for r in records):
            out[key] = float(np.mean([r[key] for r in records]))
    out["n_tracked"] = sum(r.get("track") == "tracked" for r in records)
    scored = [r["metrics"] for r in records if r.get("metrics")]
    if scored:
        out.update({
            "median_mm": float(np.mean([m["visible_median_mm"] for m in scored])),
            "p90_mm": float(np.mean([m["visible_p90_mm"] for m in scored])),
            "hausdorff_mm": float(np.max([m["hausdorff_mm"] for m in scored])),
            "pct_under_10mm": float(np.mean([m["pct_under_10mm"] for m in scored])),
            "iou_min": float(np.min([m["iou_min"] for m in scored])),
            "median_all_mm": float(np.mean([m["median_mm"] for m in scored])),
            "p90_all_mm": float(np.mean([m["p90_mm"] for m in scored])),
        })
        je = [m["joint_error_mm"] for m in scored if "joint_error_mm" in m]
        if je:
            out["init_joint_error_mm"] = float(np.mean(je))
    return out


def evaluate_session(path: str | Path) -> dict:
    """Score the meshes in ``SESSION/reconstruct/`` against the session's ground truth (JSON-ready dict)."""
    from bodystudio.capture.session import open_session

    session = open_session(path)
    out_dir = session.path / OUTPUT_DIR
    if not (out_dir / RUN_MANIFEST).is_file() and not (out_dir / "frames.json").is_file():
        check_readable(reconstruction_layout(session.path))
        raise SessionError(f"{out_dir}: no reconstruction yet; run `bodystudio reconstruct {session.path}` first")
    run, _ = read_reconstruction(session.path)
    frames = read_json(out_dir / "frames.json", "reconstruction record")["frames"]
    cameras = list(session.cameras)
    records = []
    for rec in frames:
        frame = session.frame(rec["frame"])
        if frame.gt_mesh is None:
            raise SessionError(f"{session.path}: frame {rec['frame']} has no ground-truth mesh to score against")
        mesh_path = out_dir / "meshes" / f"{rec['frame']:05d}.ply"
        mesh = load_mesh(mesh_path)
        if len(mesh.vertices) != run["n_vertices"]:
            raise SessionError(f"{mesh_path}: {len(mesh.vertices)} vertices but {RUN_MANIFEST} says template "
                               f"{run['template']} ({run['n_vertices']}); the folder mixes two runs, "
                               "re-run reconstruct")
        records.append(dict(rec, metrics=score_frame(mesh.vertices, mesh.faces, frame, cameras)))
    return summarize(records)


def read_reconstruction(session_path: str | Path, frame: int | None = None) -> tuple[dict, dict[int, Path]]:
    """``(run.json, frame -> mesh path)`` of a complete reconstruction, checked as one run.

    Refused with one line: a reconstruct writing it now, an interrupted commit (run ``bodystudio recover``),
    a run.json without checksums, or files whose sha256 disagree with run.json (two runs mixed). With
    ``frame`` only that frame's mesh (and frames.json) is checksummed.
    """
    layout = reconstruction_layout(session_path)
    check_readable(layout)
    if not layout.manifest_path.is_file():
        raise SessionError(f"{layout.manifest_path}: missing (a reconstruction by an older bodystudio, or files "
                           f"copied in by hand); re-run `bodystudio reconstruct {session_path}`")
    run = read_json(layout.manifest_path, "reconstruction run record")
    if not isinstance(run, dict) or not isinstance(run.get("frames"), list) or "n_vertices" not in run:
        raise SessionError(f"{layout.manifest_path}: not a reconstruction run record; re-run reconstruct")
    only = None if frame is None else ("frames.json", f"meshes/{frame:05d}.ply")
    verify_run_files(layout, run.get("run"), only)
    meshes = {int(f): layout.root / f"meshes/{int(f):05d}.ply" for f in run["frames"]
              if f"meshes/{int(f):05d}.ply" in run["run"]["files"]}
    return run, meshes
