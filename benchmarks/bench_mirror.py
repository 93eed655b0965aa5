"""Mirror stage (issue 12): per-frame cost of each step at 640x480, one and two actors, on one core.

The image steps (§5.3-§5.5) run on rendered frames with the true source/target vertices
(:mod:`bodystudio.mirror.image_case`), so the figures do not depend on the body fit. Times are the median
process CPU time of repeated calls with every thread pool held to one thread (numba, OpenCV, BLAS): the
figure one idle core would give on this shared machine; wall medians are listed beside them. The
session-side steps (IK, posing) come from MIR-BODY's timing function when it is present.
"""

from __future__ import annotations

import contextlib
import os
import time

import numpy as np

from benchmarks.timing import markdown_table
from bodystudio.mirror.run import CORRESPONDENCE, MLS_ALPHA, MLS_RADIUS_PX, untwist_bones


def _median_ms(fn, repeats: int) -> tuple[float, float]:
    """(median CPU ms, median wall ms) of ``fn()`` after one warm-up call."""
    fn()
    cpu, wall = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return float(np.median(cpu)) * 1e3, float(np.median(wall)) * 1e3


@contextlib.contextmanager
def one_core():
    """Hold numba, OpenCV and the BLAS pools to one thread (restored afterwards)."""
    import cv2
    import numba
    from threadpoolctl import threadpool_limits

    cv_threads, nb_threads = cv2.getNumThreads(), numba.get_num_threads()
    cv2.setNumThreads(1)
    numba.set_num_threads(1)
    try:
        with threadpool_limits(1):
            yield
    finally:
        cv2.setNumThreads(cv_threads)
        numba.set_num_threads(nb_threads)


def image_step_times(case, repeats: int = 7) -> tuple[dict, dict]:
    """Per-step (CPU ms, wall ms) of the image steps on one :class:`ImageCase`, and of the alternatives."""
    from bodystudio.mirror.compose import compose, update_background
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.run import REGISTER_OUTLINE_ONE_PLAYER, frame_pairs, registered_pairs
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground

    dense = CORRESPONDENCE == "dense"
    background = update_background(None, case.background, np.zeros(case.true_mask.shape, bool))
    n_actors = case.actors
    sources, targets = np.split(case.source_vertices, n_actors), np.split(case.target_vertices, n_actors)
    F1 = case.faces[: len(case.faces) // n_actors]
    # several actors: the player of each mask pixel, as the run passes the graph cut (each actor's side of the
    # frame: the bench's actors stand apart, at the same depth)
    labels = None
    if n_actors > 1:
        centres = sorted(case.camera.project(V.mean(0, keepdims=True))[0, 0] for V in sources)
        cols = np.arange(case.player_mask.shape[1])
        labels = np.where(case.player_mask, 1 + np.searchsorted(np.add(centres[1:], centres[:-1]) / 2, cols)[None],
                          0).astype(np.uint8)
    fg = refine_foreground(case.rgb, case.player_mask, background=background, labels=labels)

    register = n_actors == 1 and dense and REGISTER_OUTLINE_ONE_PLAYER
    if register:  # the run's registration of one player's bodies to the refined outline (MIR12p), in the step
        from bodystudio.body.statistical import load_statistical_model

        model = load_statistical_model("2k", progress=False)

    def pairs(dense=dense, register=register):
        # the run's call (run.frame_pairs): one actor's pairs, or all actors' in one call (one z-buffer per body);
        # one player's registered to the graph cut's outline and paired again (run.registered_pairs)
        p = frame_pairs(sources, targets, F1, case.camera, "dense" if dense else "mls")
        if register:
            p = registered_pairs(p, sources[0], targets[0], F1, model.weights, model.parents, case.camera, fg)
        return p

    def field_of(kind, radius_px=MLS_RADIUS_PX, dense=dense):
        # the run's call: with the refined foreground, whose extras beyond the fitted body the dense warp carries
        return lambda: mls_warp_field(case.src_uv, case.dst_uv, kind=kind, alpha=MLS_ALPHA, groups=case.pair_groups,
                                      radius_px=radius_px, dense=case.dense if dense else None, foreground=fg)

    field = field_of("similarity")()
    warped, alpha = warp_foreground(case.rgb, fg, field)
    name = "dense correspondence, 1 px outline band" if dense else "MLS similarity (handles within 32 px)"
    other = "MLS similarity (handles within 32 px)" if dense else "dense correspondence, 1 px outline band"
    out = {
        f"pairs (visibility + projection, rim{', dense' if dense else ''}; one player's registered to the outline "
        "and paired again)": _median_ms(pairs, repeats),
        "foreground: graph cut (PyMaxflow)": _median_ms(
            lambda: refine_foreground(case.rgb, case.player_mask, background=background, labels=labels), repeats),
        f"warp field: {name}": _median_ms(field_of("similarity"), repeats),
        "warp (remap)": _median_ms(lambda: warp_foreground(case.rgb, fg, field), repeats),
        "compose": _median_ms(lambda: compose(warped, alpha, background, case.rgb, fg), repeats),
        "background update": _median_ms(lambda: update_background(background, case.rgb, fg), repeats),
    }
    side = {
        f"pairs{'' if dense else ', dense'}, not used": _median_ms(lambda: pairs(not dense, False), repeats),
        "pairs without the outline registration (`run.REGISTER_OUTLINE_ONE_PLAYER = False`), not used": _median_ms(
            lambda: pairs(dense, False), repeats),
        f"warp field: {other}, not used": _median_ms(field_of("similarity", dense=not dense), repeats),
        "foreground: GrabCut (OpenCV), not used": _median_ms(
            lambda: refine_foreground(case.rgb, case.player_mask, method="grabcut"), max(3, repeats // 2)),
        "warp field: MLS affine, not used": _median_ms(field_of("affine", dense=False), repeats),
        "warp field: MLS rigid, not used": _median_ms(field_of("rigid", dense=False), repeats),
        "warp field: MLS similarity over all handles, not used": _median_ms(field_of("similarity", None, False),
                                                                             repeats),
    }
    return out, side


def _outline_registration_ms(result: tuple[dict, dict]) -> float:
    """CPU ms the outline registration adds to one actor's pairs step (:func:`image_step_times`' pairs row minus its
    side row without it; 0 where the run does not register)."""
    out, side = result
    pairs = next(v[0] for k, v in out.items() if k.startswith("pairs ("))
    plain = next((v[0] for k, v in side.items() if k.startswith("pairs without the outline registration")), pairs)
    return max(pairs - plain, 0.0)


def _accuracy(case) -> dict[str, float]:
    from bodystudio.mirror.foreground import refine_foreground
    from bodystudio.mirror.image_case import iou
    from bodystudio.mirror.warp import mls_warp_field, warp_foreground

    out = {"player mask IoU (raw)": iou(case.player_mask, case.true_mask),
           "graph cut IoU": iou(refine_foreground(case.rgb, case.player_mask), case.true_mask),
           "GrabCut IoU": iou(refine_foreground(case.rgb, case.player_mask, method="grabcut"), case.true_mask)}
    for kind in ("affine", "similarity", "rigid"):
        field = mls_warp_field(case.src_uv, case.dst_uv, kind=kind, alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX)
        _, alpha = warp_foreground(case.rgb, case.true_mask, field)
        out[f"warp_iou MLS {kind}"] = iou(alpha > 0.5, case.target_mask)
    field = mls_warp_field(case.src_uv, case.dst_uv, kind="similarity", alpha=MLS_ALPHA, radius_px=MLS_RADIUS_PX,
                           dense=case.dense)
    out["warp_iou dense"] = iou(warp_foreground(case.rgb, case.true_mask, field)[1] > 0.5, case.target_mask)
    return out


def _refine_weights(n_players: int) -> dict:
    """``{"weights": the run's RefineWeights}`` for ``n_players`` reshaped (MIR12n: 2000 depth points for one), or
    ``{}`` in a checkout before it."""
    try:
        from bodystudio.mirror.run import refine_weights
    except ImportError:
        return {}
    return {"weights": refine_weights(n_players)}


def _refine_steps(n_players: int) -> int:
    """The run's Gauss-Newton steps per player when it reshapes ``n_players`` (MIR12k; 1 before it)."""
    try:
        from bodystudio.mirror.run import refine_steps
    except ImportError:
        return 1
    return refine_steps(n_players)


def _session_side(quick: bool) -> tuple[list[str], float | None, float | None, dict | None]:
    """Markdown lines: the session side per frame, from MIR-SYNTH's and MIR-BODY's timing functions; its CPU ms
    per frame split into what the actors share (the depth-to-colour registration) and what each actor costs (IK,
    skinning its source and target body), and the pose refinement's per actor (``--refine-pose``; None without):
    ``{players reshaped: CPU ms}``, the run's steps for one player and for two (:func:`_refine_steps`).

    A synthetic mirror session is written (as ``synthetic.time_synth_mirror`` does), its observations fitted and
    tracked (``init.time_init_and_track``: the §4 fit, IK and skinning per frame), and the depth-to-colour
    registration and the vertex pairs of a tracked frame timed here.
    """
    import importlib
    import tempfile

    try:
        synthetic = importlib.import_module("bodystudio.mirror.synthetic")
        init = importlib.import_module("bodystudio.mirror.init")
        frames = importlib.import_module("bodystudio.mirror.frames")
    except ImportError:
        return ["Session side (synthesis, init, IK, posing, depth registration): their modules are not in this "
                "checkout."], None, None, None
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session

    n_frames = 24 if quick else 40
    lines = []
    with tempfile.TemporaryDirectory() as tmp, one_core():
        synth: dict = {}  # time_synth_mirror's call, with the actor standing from frame 10 (no walk-in)
        synthetic.synth_mirror_session(f"{tmp}/s", subject_seed=3, n_frames=n_frames, actors=1,
                                       edits={"taller": 0.1}, version="v1", timings=synth, walk_in=False)
        session = open_session(f"{tmp}/s")
        model = load_statistical_model("6k", progress=False)
        observations, _ = init.collect_observations(session)
        # the IK's numba kernel (MIR12f) compiled before the timing: its first compile (~10 s CPU, once per install
        # and per edit of mirror/track.py, then loaded from numba's cache in ~0.15 s) is not per-frame work, and the
        # §4 initialisation's figure would otherwise say whether the cache was warm
        if observations:
            from bodystudio.mirror.track import ik_pose

            o = observations[0]
            ik_pose(model.skeleton(np.zeros(len(model.stddev))), o.joints, o.tracked, o.version)
            # and the init's own kernels (MIR12i's refined unposing calls the refinement's ``_project_body``): one
            # untimed initialisation first, so that the figure below is the warm init's whatever the cache held
            init.time_init_and_track(observations, model, view_point=session.kinect.depth.center, track_frames=1,
                                     depth_camera=session.kinect.depth)
        track = init.time_init_and_track(observations, model, view_point=session.kinect.depth.center,
                                         track_frames=30, depth_camera=session.kinect.depth,
                                         untwist_bones=untwist_bones())  # the run's (mir12aa: the feet too)
        last = frames.read_mirror_frame(session, session.frame_ids[-1])
        register = _median_ms(lambda: frames.register_depth_to_color(last.depth_m, last.player, session.kinect),
                              5)
        lines.append(f"Session side (one core; a {n_frames}-frame v1 synthetic session): depth-to-colour "
                     f"registration {register[0]:.1f} ms CPU ({register[1]:.1f} wall), IK "
                     f"{track['ik_cpu_ms']:.1f} ms, the 6k source and target bodies posed in one pass "
                     f"{track['bodies_cpu_ms']:.1f} ms per frame (skinning the source alone "
                     f"{track['skin_cpu_ms']:.1f}); the §4 initialisation "
                     f"{track['init_cpu_s']:.2f} s CPU over {track['init_frames']} frames. Synthesis: "
                     + ", ".join(f"{k} {v:.2f}" for k, v in synth.items() if isinstance(v, (int, float))) + ".")
        refine_ms = {}
        for players in (1, 2):
            steps = _refine_steps(players)
            ms = _refine_pose_ms(session, model, last, frames, steps, **_refine_weights(players))
            if ms is None:
                break
            refine_ms[players] = ms[0]
            lines.append(f"`--refine-pose`, {players} player{'s' if players > 1 else ''} reshaped: the pose "
                         f"refinement {ms[0]:.1f} ms CPU ({ms[1]:.1f} wall) per frame and player, {steps} "
                         f"Gauss-Newton step{'s' if steps > 1 else ''} (the mean shape posed by the IK against the "
                         "player mask, depth and joints of the last frame; with the run's pelvis-lean prior and its "
                         "running posture, updated after the frame).")
    return (lines, register[0], track["ik_cpu_ms"] + track["bodies_cpu_ms"], refine_ms or None)


def _refine_pose_ms(session, model, frame, frames, iterations: int = 1, weights=None) -> tuple[float, float] | None:
    """CPU and wall ms of :func:`bodystudio.mirror.refine.refine_pose` (``iterations`` Gauss-Newton steps, the run's
    ``weights`` where given, E_trunk centred on the run's running posture and that posture updated after it, as
    ``run_mirror`` does) on ``frame`` (None without the module)."""
    import importlib

    try:
        refine = importlib.import_module("bodystudio.mirror.refine")
    except ImportError:
        return None
    from bodystudio.mirror.init import SourceBody
    from bodystudio.mirror.track import ik_pose

    c = np.zeros(len(model.stddev))
    body = SourceBody(c, model.vertices(c), model.skeleton(c), (), 0.0, model.weights, model.faces)
    tracked = frame.body(1)
    if tracked is None:
        return None
    sensor = session.kinect
    pose = ik_pose(body.skeleton, tracked.positions, tracked.tracked, sensor.version)
    _, players = frames.register_depth_to_color(frame.depth_m, frame.player, sensor)
    points = frames.point_cloud(frame, sensor, 1)
    plan = refine.refine_plan(body.vertices, body.faces, body.weights, body.skeleton, sensor.version,
                              twist_bones=refine.TWIST_BONES)  # the run's plan (MIR12h)
    from bodystudio.mirror import run as run_mod

    # the run's running posture (mir12ae: E_trunk centred on it, updated after every refined frame)
    bones, window = run_mod.POSTURE_BONES, run_mod.POSTURE_WINDOW
    posture = refine.updated_posture(None, body.skeleton, pose, 1, window, bones) if bones else None

    def refined():
        refined_pose = refine.refine_pose(plan, body.skeleton, pose, sensor.color, players == 1, tracked.positions,
                                          tracked.tracked, points[points[:, 1] > 0.02],
                                          (players > 0) & (players != 1), sensor.version, iterations=iterations,
                                          posture=posture, **({} if weights is None else {"weights": weights}))
        if bones:
            refine.updated_posture(posture, body.skeleton, refined_pose, 2, window, bones)

    return _median_ms(refined, 7)


def run(quick: bool = False) -> str:
    from bodystudio.mirror.image_case import cached_image_case

    repeats = 5 if quick else 9
    edits = {"+10 % stature, +15 kg": None, "-10 % stature, -15 kg": (("stature_m", -0.16), ("mass_kg", -15.0))}
    lines = ["## mirror", "",
             "Per-frame cost of the mirror's image steps at 640x480 (Kinect v1 colour camera), rendered frames with "
             "the true source/target vertices. Median process CPU ms with numba, OpenCV and BLAS held to one thread "
             "(wall ms beside: the machine is shared). `python -m benchmarks.run --only mirror`.", ""]
    with one_core():
        cases = {"1 actor": cached_image_case(None, 0, 1), "2 actors": cached_image_case(None, 0, 2)}
        rows, totals, side_rows = [], {}, []
        results = {name: image_step_times(case, repeats) for name, case in cases.items()}
        steps = list(next(iter(results.values()))[0])
        for step in steps:
            rows.append([step] + [f"{results[n][0][step][0]:.2f} ({results[n][0][step][1]:.1f})" for n in cases])
        for n in cases:
            totals[n] = sum(v[0] for v in results[n][0].values())
        rows.append(["**total (CPU ms)**"] + [f"**{totals[n]:.1f}**" for n in cases])
        rows.append(["**frames per second, one core**"] + [f"**{1e3 / totals[n]:.1f}**" for n in cases])
        for step in next(iter(results.values()))[1]:
            side_rows.append([step] + [f"{results[n][1][step][0]:.2f} ({results[n][1][step][1]:.1f})" for n in cases])
        lines += [markdown_table(["step", *[f"{n}: CPU ms (wall)" for n in cases]], rows), "",
                  "Alternatives measured side by side (not in the total):", "",
                  markdown_table(["step", *[f"{n}: CPU ms (wall)" for n in cases]], side_rows), ""]
        acc_rows = []
        for label, ed in edits.items():
            acc = _accuracy(cached_image_case(ed, 0, 1))
            acc_rows.append([label, *[round(v, 4) for v in acc.values()]])
        lines += ["Accuracy on the same frame (1 actor, seed 0):", "",
                  markdown_table(["edit", *acc], acc_rows), ""]
    try:
        session_lines, register_ms, actor_ms, refine_ms = _session_side(quick)
        lines += session_lines + [""]
        if register_ms is not None:
            session_ms = register_ms + actor_ms
            # the outline registration waits for the graph cut's foreground, as the pose refinement does: a run
            # without the refinement pairs the bodies once (run.session_inputs)
            outline = _outline_registration_ms(results["1 actor"])
            end_to_end = totals["1 actor"] + session_ms - outline
            lines += [f"**End to end, one actor, one core: {end_to_end:.1f} ms CPU per frame = "
                      f"{1e3 / end_to_end:.1f} fps** without the pose refinement (`--no-refine-pose`; image steps "
                      f"{totals['1 actor'] - outline:.1f} without the outline registration, which needs the refined "
                      f"foreground + registration, IK and the bodies {session_ms:.1f}; reading PNG frames "
                      "from disk and writing the outputs not included: a live mirror gets frames from the SDK and "
                      "shows them).", ""]
            one, each = (None, None) if refine_ms is None else (refine_ms[1], refine_ms[2])
            if one is not None:
                lines += [f"**With the pose refinement (`--refine-pose`, the default): {end_to_end + outline + one:.1f}"
                          f" ms CPU per frame = {1e3 / (end_to_end + outline + one):.1f} fps** (the same run's "
                          f"figures plus the refinement {one:.1f} and the outline registration {outline:.1f}).", ""]
            # two actors: one registration, each actor its own IK, refinement and two skinned bodies
            two = totals["2 actors"] + register_ms + 2 * (actor_ms + (each or 0.0))
            lines += [f"**End to end, two actors, one core: {two:.1f} ms CPU per frame = {1e3 / two:.1f} fps** "
                      f"{'with' if each is not None else 'without'} the pose refinement (image steps "
                      f"{totals['2 actors']:.1f} + registration {register_ms:.1f} + 2 x (IK and the bodies "
                      f"{actor_ms:.1f}{f' + refinement {each:.1f}' if each is not None else ''}); the "
                      "per-actor figures are the one-actor session's).", ""]
    except Exception as exc:  # another module's timing helper must not hide these figures
        lines += [f"Session side: its timing helpers failed ({type(exc).__name__}: {exc}).", ""]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines.append(f"Load average at the end: {load:.1f}.")
    return "\n".join(lines)


if __name__ == "__main__":
    print(run(quick=os.environ.get("BENCH_QUICK") == "1"))
