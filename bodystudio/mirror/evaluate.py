"""Scores of a mirror run against the synthetic ground truth (issue 12, acceptance).

:func:`evaluate_mirror` reads a synthetic mirror session (``bodystudio synth mirror``), its source body
(``SESSION/mirror/source_body.npz`` of ``bodystudio mirror init``) and a run folder (``bodystudio mirror
run``: ``frames/``, ``masks/foreground/``, ``masks/warped/``, ``run.json``) and returns:

* ``init_stature_err_mm``, ``init_mass_err_kg``: |stature| and |mass| of the source body (measured on its
  rest mesh) minus those measured on the actor's true rest mesh (§4);
* ``joint_err_mm``: mean distance of the Kinect joints of the source skeleton posed by the IK (§5.2)
  from the true joints, over the scored frames;
* ``fg_iou`` (the run's refined foreground, §5.3) and ``fg_iou_raw`` (the SDK player mask mapped into
  colour) against the true person mask; ``warp_iou``: the run's warped foreground against the target
  body's true silhouette (``warp_iou_unwarped``: the input's true silhouette against it, the score of
  doing nothing);
* ``psnr_person`` (dB, pooled MSE) and ``ssim_person`` (Wang et al. 2004, Gaussian window) of the run's
  output frames against the target renders, in a band around the person: the union of the true source
  and target masks dilated by ``band_px``;
* ``ms_per_frame`` by step and ``fps`` from ``run.json``; with a run from MIR12j on, ``cpu_ms_per_frame`` and the
  frames per second end to end with and without reading and writing, one core (CPU) and wall (``speed_scores``).

The result is strict JSON (no ``NaN``/``Infinity``, which RFC 8259 parsers refuse): the PSNR of output
frames identical to the target renders in the band is infinite, so ``psnr_person`` is then ``null`` and
``psnr_person_identical`` ``true`` (it is ``false`` whenever ``psnr_person`` is a number); any other score
that cannot be computed (e.g. ``joint_err_mm`` without a tracked frame) is ``null``.

Scored frames: the run's frames in which the tracker reported the run's player (the mirror cannot act
before), once the run's edit ramp (``ramp_frames`` tracked frames) is complete. A run folder that is
being written, was interrupted, lists files that are missing or changed, was made from another session,
or with other edits than the session's ground truth, is refused in one line.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from bodystudio.errors import FileFormatError, InputError

RUN_JSON = "run.json"
RUN_FORMAT = "bodystudio-mirror-run"
BAND_PX = 10


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union


def person_band(source_mask: np.ndarray, target_mask: np.ndarray, band_px: int = BAND_PX) -> np.ndarray:
    """The pixels scored by PSNR/SSIM: the union of the source and target masks dilated by ``band_px``."""
    size = 2 * int(band_px) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    return cv2.dilate((np.asarray(source_mask, bool) | np.asarray(target_mask, bool)).astype(np.uint8), kernel) > 0


def ssim_map(a: np.ndarray, b: np.ndarray, sigma: float = 1.5, data_range: float = 255.0) -> np.ndarray:
    """Structural similarity per pixel, Eq. 13 of Wang et al. 2004 (Gaussian 11x11 window, sigma 1.5,
    K1 = 0.01, K2 = 0.03), averaged over the colour channels; (H, W) float64."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise InputError(f"ssim: images differ in shape, {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2

    def blur(x):
        return cv2.GaussianBlur(x, (11, 11), sigma, borderType=cv2.BORDER_REFLECT)

    out = np.zeros(a.shape[:2])
    for ch in range(a.shape[2]):
        x, y = a[..., ch], b[..., ch]
        mx, my = blur(x), blur(y)
        sxx = blur(x * x) - mx * mx
        syy = blur(y * y) - my * my
        sxy = blur(x * y) - mx * my
        out += ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return out / a.shape[2]


def psnr_from_sse(sse: float, count: int, data_range: float = 255.0) -> float:
    """PSNR in dB of a pooled sum of squared errors over ``count`` values (inf when identical)."""
    if count == 0:
        return float("nan")
    mse = sse / count
    return math.inf if mse == 0 else 10.0 * math.log10(data_range**2 / mse)


# ---------------------------------------------------------------------------------------------- inputs

def check_mirror_session(session):
    """The session if it is a synthetic mirror session with ground truth, else a one-line InputError."""
    from bodystudio.capture.session import open_session

    if isinstance(session, (str, Path)):
        session = open_session(session)
    meta = session.metadata if isinstance(session.metadata, dict) else {}
    if meta.get("generator") != "bodystudio synth mirror" or "gt_person" not in session.streams \
            or session.kinect is None:
        raise InputError(f"{session.path}: not a synthetic mirror session (no mirror ground truth); "
                         "`bodystudio eval mirror` scores runs on sessions from `bodystudio synth mirror`")
    return session


def _nonzero(edits) -> dict[str, float]:
    if not isinstance(edits, dict):
        return {}
    out = {}
    for k, v in edits.items():
        try:
            if float(v) != 0.0:
                out[str(k)] = float(v)
        except (TypeError, ValueError):
            out[str(k)] = float("nan")
    return out


def same_session_recording(session, run: dict) -> bool:
    """Whether a run was made from ``session``'s recording wherever the folder now lies: the run's
    ``session_fingerprint`` (:func:`~bodystudio.mirror.frames.recording_fingerprint` of its frames) is the
    session's. A session moved or copied together with its run keeps it; another recording has another; a run
    written before the fingerprint existed has none (and is judged by its path alone)."""
    from bodystudio.mirror.frames import recording_fingerprint

    used = run.get("session_fingerprint")
    ids = [f.get("index") for f in run.get("frames") or [] if isinstance(f, dict)]
    if not isinstance(used, str) or not ids or not all(type(i) is int for i in ids):
        return False
    if not set(ids) <= set(session.frame_ids):
        return False
    return used == recording_fingerprint(session, ids)


def read_mirror_run(session, run_dir: str | Path) -> dict:
    """``run.json`` of a complete run folder made from ``session`` with the session's edits; one-line errors."""
    from bodystudio.fileio import read_json
    from bodystudio.runfolder import OutputLockedError, RunLayout, check_readable, verify_run_files

    run_dir = Path(run_dir)
    layout = RunLayout(run_dir, RUN_JSON, ".", str(run_dir))
    if not run_dir.is_dir():
        raise InputError(f"--run {run_dir}: no such run folder; run `bodystudio mirror run {session.path}` first")
    try:
        check_readable(layout)
    except OutputLockedError as exc:
        raise InputError(str(exc)) from None
    if not layout.manifest_path.is_file():
        raise InputError(f"{layout.manifest_path}: missing, the run folder is incomplete (never committed); "
                         f"re-run `bodystudio mirror run {session.path}`")
    run = read_json(layout.manifest_path, "mirror run manifest")
    if not isinstance(run, dict) or run.get("format") != RUN_FORMAT or not isinstance(run.get("frames"), list):
        raise FileFormatError(f"{layout.manifest_path}: not a mirror run manifest (format != {RUN_FORMAT!r}); "
                              "pass the folder `bodystudio mirror run` wrote")
    ran_on = run.get("session")
    if not isinstance(ran_on, str) or (Path(ran_on).resolve() != Path(session.path).resolve()
                                       and not same_session_recording(session, run)):
        raise InputError(f"{run_dir}: this run was made from session {ran_on!r}, not {session.path}; evaluate it "
                         "against its own session")
    truth, used = _nonzero(session.metadata.get("edits")), _nonzero(run.get("edits"))
    if set(truth) != set(used) or any(not abs(truth[k] - used[k]) <= 1e-9 for k in truth):
        raise InputError(f"{run_dir}: the run's edits {used} differ from the ground truth's {truth} in "
                         f"{session.path}; re-run `bodystudio mirror run` with the session's edits")
    player = run.get("player", 1)
    edited = session.metadata.get("edited_players") or []
    if truth and player not in edited:
        raise InputError(f"{run_dir}: the run reshapes player {player!r} but the ground truth edits players "
                         f"{edited}; re-run with --player {edited[0] if edited else 1}")
    frames = run["frames"]
    ids = [f.get("index") for f in frames if isinstance(f, dict)]
    if len(ids) != len(frames) or not all(type(i) is int for i in ids) or len(set(ids)) != len(ids):
        raise FileFormatError(f"{layout.manifest_path}: malformed frame list; re-run `bodystudio mirror run`")
    missing = sorted(set(ids) - set(session.frame_ids))
    if missing:
        raise InputError(f"{run_dir}: frames {missing[:5]} are not in {session.path}; the run belongs to "
                         "another session")
    if not ids:
        raise InputError(f"{run_dir}: the run holds no frames; re-run `bodystudio mirror run`")
    needed = tuple(f"{d}/{i:05d}.png" for i in ids for d in ("frames", "masks/foreground", "masks/warped"))
    block = run.get("run")
    listed = set((block or {}).get("files", {})) if isinstance(block, dict) else set()
    absent = [k for k in needed if k not in listed]
    if block is not None and absent:
        raise InputError(f"{run_dir}: {absent[0]} is not in {RUN_JSON} ({len(absent)} such); the run folder is "
                         "incomplete, re-run `bodystudio mirror run`")
    verify_run_files(layout, block, only=needed)
    return run


def _read_png(path: Path, color: bool) -> np.ndarray:
    from bodystudio.fileio import read_image

    image = read_image(path, cv2.IMREAD_COLOR if color else cv2.IMREAD_GRAYSCALE)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if color else image


# ---------------------------------------------------------------------------------------------- scores

#: A run of several players (``mirror run --player 1 --player 2``): a player's fg_iou and warp_iou count the run's
#: mask pixels within this many pixels of that player's true or target silhouette and not on another player's
#: (the masks hold all players).
NEAR_PX = 15


def image_scores(session, run_dir: str | Path, run: dict, band_px: int = BAND_PX) -> dict:
    """The image scores (fg_iou, fg_iou_raw, warp_iou, warp_iou_unwarped, psnr_person, ssim_person) of a run's
    ``player`` (a run of several players: its masks near that player, :data:`NEAR_PX`)."""
    from bodystudio.mirror.frames import player_mask_in_color, read_mirror_frame

    run_dir = Path(run_dir)
    player = int(run.get("player", 1))
    several = len(run.get("players") or ()) > 1  # mirror run --player 1 --player 2
    status = {f["index"]: f.get("status") for f in run["frames"]}
    # the Kinect id the player held in each frame (run.json's tracked_as, the run's players in order; rel6a): the
    # SDK's raw mask of a renumbered actor is under that id, not the run's
    order = [int(p) for p in run.get("players") or [player]]
    held = {f["index"]: f["tracked_as"][order.index(player)] for f in run["frames"]
            if player in order and len(f.get("tracked_as") or ()) == len(order)}
    fg, fg_raw, warp, unwarped, ssim = [], [], [], [], []
    sse, count, scored, passed = 0.0, 0, [], 0
    # the run reaches the edit gradually, over its first ``ramp_frames`` tracked ("ok") frames; the ground
    # truth shows the whole edit, so those frames are not scored
    ramp, ok_so_far, ramping = int(run.get("ramp_frames") or 0), 0, 0
    for i in sorted(status):
        ok_so_far += status[i] == "ok"
        if ok_so_far < ramp:
            ramping += 1
            continue
        frame = session.frame(i)
        gt = frame.gt_mirror
        if gt is None or frame.gt_person is None:
            continue
        players = list(gt["players"])
        if player not in players or not bool(gt["reported"][players.index(player)]):
            continue
        truth = frame.gt_person == player
        target_labels = frame.gt_target_person
        target = truth if target_labels is None else target_labels == player
        target_rgb = frame.kinect_rgb if frame.gt_target_rgb is None else frame.gt_target_rgb
        name = f"{i:05d}.png"
        output = _read_png(run_dir / "frames" / name, True)
        refined = _read_png(run_dir / "masks" / "foreground" / name, False) > 127
        warped = _read_png(run_dir / "masks" / "warped" / name, False) > 127
        if output.shape != target_rgb.shape or refined.shape != truth.shape or warped.shape != truth.shape:
            raise FileFormatError(f"{run_dir / 'frames' / name}: image size {output.shape[1]}x{output.shape[0]} is "
                                  f"not the session's colour {truth.shape[1]}x{truth.shape[0]}; re-run the mirror")
        raw = player_mask_in_color(read_mirror_frame(session, i), session.kinect, held.get(i) or player)
        if several:  # the run's masks hold every reshaped player: score this one's, those near it, not another's
            mine = cv2.dilate((truth | target).astype(np.uint8), np.ones((2 * NEAR_PX + 1,) * 2, np.uint8)) > 0
            mine &= (frame.gt_person == 0) | truth
            if target_labels is not None:
                mine &= (target_labels == 0) | target
            refined, warped = refined & mine, warped & mine
        fg.append(mask_iou(refined, truth))
        fg_raw.append(mask_iou(raw, truth))
        warp.append(mask_iou(warped, target))
        unwarped.append(mask_iou(truth, target))
        band = person_band(truth, target, band_px)
        diff = output.astype(np.float64)[band] - target_rgb.astype(np.float64)[band]
        sse += float(np.sum(diff * diff))
        count += diff.size
        ssim.append(float(ssim_map(output, target_rgb)[band].mean()))
        scored.append(i)
        passed += status[i] != "ok"
    if not scored and ramping and ok_so_far < ramp:
        raise InputError(f"{run_dir}: the run never reached the whole edit (--ramp-frames {ramp}, {ok_so_far} "
                         "tracked frames) and the ground truth shows the whole edit; re-run `bodystudio mirror run` "
                         "with --ramp-frames 0")
    if not scored:
        raise InputError(f"{run_dir}: none of the run's frames shows player {player} tracked in {session.path}; "
                         "nothing to score")
    return {"frames_scored": len(scored), "frames_passed_through": int(passed), "frames_ramping": ramping,
            "scored_frames": scored,
            "fg_iou": float(np.mean(fg)), "fg_iou_raw": float(np.mean(fg_raw)), "warp_iou": float(np.mean(warp)),
            "warp_iou_unwarped": float(np.mean(unwarped)), "psnr_person": psnr_from_sse(sse, count),
            "ssim_person": float(np.mean(ssim))}


def actor_truth(session, player: int) -> dict:
    """The true actor record of ``player`` (``gt/phenotype.json`` ``actors``), with ``measured`` attributes."""
    actors = (session.gt_subject or {}).get("actors") or []
    for actor in actors:
        if isinstance(actor, dict) and actor.get("player") == player:
            return actor
    raise InputError(f"{session.path}: no ground truth of player {player} in gt/phenotype.json; regenerate the session")


def init_scores(session, source, player: int = 1) -> dict:
    """|stature| (mm) and |mass| (kg) errors of the source body's rest mesh against the true actor (§4)."""
    from bodystudio.body.measure import measure_attributes

    truth = actor_truth(session, player)["measured"]
    V = np.asarray(source.vertices, np.float64)
    faces = getattr(source, "faces", None)
    if faces is None:
        from bodystudio.body.model import RESOLUTIONS, template_topology

        for resolution in RESOLUTIONS:
            ids, F = template_topology(resolution)
            if (13380 if ids is None else len(ids)) == len(V):
                faces = F
                break
        else:
            raise InputError(f"source body with {len(V)} vertices is in no body template; "
                             "rerun `bodystudio mirror init`")
    measured = measure_attributes(V, faces)
    return {"init_stature_err_mm": abs(measured["stature_m"] - truth["stature_m"]) * 1e3,
            "init_mass_err_kg": abs(measured["mass_kg"] - truth["mass_kg"]),
            "init_stature_m": measured["stature_m"], "true_stature_m": truth["stature_m"],
            "init_mass_kg": measured["mass_kg"], "true_mass_kg": truth["mass_kg"]}


def tracking_scores(session, source, frames: list[int], player: int = 1) -> dict:
    """Mean distance (mm) of the IK-posed source skeleton's Kinect joints from the true joints (§5.2)."""
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.body.skinning import posed_joints
    from bodystudio.mirror.frames import read_mirror_frame
    from bodystudio.mirror.track import ik_pose

    version = session.kinect.version
    errors, previous = [], None
    for i in frames:
        frame = read_mirror_frame(session, i)
        body = frame.body(player)
        gt = session.frame(i).gt_mirror
        players = list(gt["players"])
        if body is None or player not in players:
            previous = None
            continue
        pose = ik_pose(source.skeleton, body.positions, body.tracked, version, previous)
        previous = pose
        heads, tails = posed_joints(source.skeleton, pose)
        model = kinect_joints(source.skeleton, heads, tails, version)
        truth = gt["kinect_joints"][players.index(player)]
        errors.append(np.linalg.norm(model - truth, axis=1).mean())
    return {"joint_err_mm": float(np.mean(errors)) * 1e3 if errors else float("nan")}


def strict_json_scores(scores: dict) -> dict:
    """``scores`` with every non-finite float replaced by ``None`` (recursively), so ``json.dumps(...,
    allow_nan=False)`` succeeds; an infinite ``psnr_person`` (identical images) sets ``psnr_person_identical``."""
    def clean(v):
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, (float, np.floating)):
            return float(v) if math.isfinite(v) else None
        if isinstance(v, np.integer):
            return int(v)
        return v

    out = clean(dict(scores))
    if "psnr_person" in scores:
        p = scores["psnr_person"]
        identical = isinstance(p, (float, np.floating)) and math.isinf(p) and p > 0
        # already strict (psnr null with its flag): the flag stays as it was
        out["psnr_person_identical"] = bool(identical or (p is None and scores.get("psnr_person_identical")))
    return out


def evaluate_mirror(session, run_dir: str | Path | None = None, source=None, band_px: int = BAND_PX) -> dict:
    """The acceptance JSON of issue 12 for a run of ``bodystudio mirror run`` on a synthetic mirror session.

    ``run_dir`` defaults to ``SESSION/mirror/run``; ``source`` (a SourceBody) to the run's player's body,
    ``SESSION/mirror/source_body.npz`` (player N > 1: ``source_body_playerN.npz``, :func:`run.source_body_path`); a
    run of several players is scored for its first player. See the module docstring for the keys; the result is
    strict JSON (:func:`strict_json_scores`: ``psnr_person`` is ``None`` with ``psnr_person_identical`` when the output
    equals the target in the band).
    """
    session = check_mirror_session(session)
    run_dir = Path(session.path) / "mirror" / "run" if run_dir is None else Path(run_dir)
    run = read_mirror_run(session, run_dir)
    player = int(run.get("player", 1))
    if source is None:
        from bodystudio.mirror.run import source_body_path

        path = source_body_path(session.path, player)  # the run's (first) player's body: mirror init --player N
        if not path.is_file():
            again = "" if player == 1 else f" --player {player}"
            raise InputError(f"{path}: missing; run `bodystudio mirror init {session.path}{again}` (the run needs "
                             "it too)")
        from bodystudio.mirror.init import load_source_body

        source = load_source_body(path)
        from bodystudio.mirror.init import source_fingerprint

        used = run.get("source_fingerprint")
        if used is not None and used != source_fingerprint(source):
            raise InputError(f"{run_dir}: the run used another source body than {path} (mirror init re-run "
                             "after it, or mirror run --source); re-run `bodystudio mirror run` with this one")
    images = image_scores(session, run_dir, run, band_px)
    summary = run.get("summary") if isinstance(run.get("summary"), dict) else {}
    ms = summary.get("ms_per_frame") if isinstance(summary.get("ms_per_frame"), dict) else {}
    from bodystudio.mirror.init import source_fingerprint

    block = run.get("run")
    return strict_json_scores({
        "session": str(session.path), "run": str(run_dir), "player": player,
        # which run and source body these scores are of (the report re-scores a saved eval.json of others)
        "run_id": block.get("run_id") if isinstance(block, dict) else None,
        "source_fingerprint": source_fingerprint(source) if hasattr(source, "coeffs") else None,
        "edits": _nonzero(run.get("edits")), **init_scores(session, source, player),
        **tracking_scores(session, source, images["scored_frames"], player),
        **{k: v for k, v in images.items() if k != "scored_frames"},
        "ms_per_frame": {k: float(v) for k, v in ms.items()},
        "ms_per_frame_total": float(sum(ms.values())) if ms else None,
        "fps": summary.get("fps_wall"), **speed_scores(summary)})


def speed_scores(summary: dict) -> dict:
    """A run's speed from its ``run.json`` summary: per-step CPU ms and frames per second end to end with and
    without the reading and writing, on one core (CPU ms, the video encoder's process included) and on the wall
    clock (per-step medians summed). A run from before MIR12j has only wall ms: the CPU entries are None."""
    from bodystudio.mirror.run import end_to_end

    ms = summary.get("ms_per_frame") if isinstance(summary.get("ms_per_frame"), dict) else {}
    cpu = summary.get("cpu_ms_per_frame") if isinstance(summary.get("cpu_ms_per_frame"), dict) else None
    wall = end_to_end({k: float(v) for k, v in ms.items()}) if ms else {}
    one_core = end_to_end({k: float(v) for k, v in cpu.items()}, summary.get("encoder_cpu_ms_per_frame")) \
        if cpu else {}
    return {"cpu_ms_per_frame": None if cpu is None else {k: float(v) for k, v in cpu.items()},
            "encoder_cpu_ms_per_frame": summary.get("encoder_cpu_ms_per_frame"),
            "fps_end_to_end_cpu": one_core.get("fps"), "fps_without_io_cpu": one_core.get("fps_without_io"),
            "fps_end_to_end_wall": wall.get("fps"), "fps_without_io_wall": wall.get("fps_without_io")}
