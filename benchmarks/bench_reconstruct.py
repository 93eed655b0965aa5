"""Rapid Skin benchmark (issue 5's ``benchmarks/rapid_skin.py``; the runner's contract names it bench_*).

1. Accuracy on a synthetic 10-camera 640x480 walk of subject 31 (not used by the tests), 13K template,
   joints from the simulated Kinect tracker: silhouette, depth and both constraint modes, each with the
   default pose refinement and with the paper's initialisation from the tracker joints alone.
2. Solver time per frame (No = 8 outer x Ni = 8 inner, contour matching excluded as in the paper's
   Fig. 9, and reported beside it) for Gauss-Seidel, Jacobi, Cholesky (SuperLU) and CG at the
   2.5K / 6K / 13K templates, one thread, measured in this process, with ratios to Gauss-Seidel.
3. Error vs inner iterations for GS and CG on fixed contour matches (the paper's Fig. 5-6), written
   to docs/reconstruct_convergence.png.
4. The tracker (issue 15): video-rate sessions (30 fps) of hidden subjects (walk 31, turn 3, arm_flex 12),
   tracking from the previous frame vs the per-frame initialisation side by side: whole-frame ms by step
   on one core (numba and BLAS on one thread) and the accuracy tables (median, p90, Hausdorff, per
   body region).
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.timing import markdown_table

SUBJECT_SEED = 31
DOCS = Path(__file__).resolve().parents[1] / "docs"


def _session(tmp: Path, n_frames: int):
    from bodystudio.capture.synth import synth_session

    return synth_session(tmp / "walk", n_cameras=10, n_frames=n_frames, motion="walk", subject_seed=SUBJECT_SEED,
                         template="full")


def _accuracy(session_path: Path, frames: str) -> tuple[str, dict]:
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session

    rows, results = [], {}
    # (constraints, warm start, pose refinement, visual-hull gate, depth reach): each mode with the default refined
    # pose and with the paper's initialisation from the tracker joints alone, side by side; the default gate on
    # silhouette matches (issue 15) beside the paper's ungated matching, and depth's far pairs for the template's
    # own front surface (issue 15, rec15b) beside the previous association
    gate, reach = RapidSkinParams().hull_gate_m, RapidSkinParams().depth_reach_m
    cases = [(("silhouette",), False, True, gate, reach), (("silhouette",), False, True, 0.0, reach),
             (("silhouette",), False, False, gate, reach), (("silhouette",), True, True, gate, reach),
             (("depth",), False, True, gate, reach), (("depth",), False, True, gate, 0.0),
             (("depth",), False, False, gate, reach),
             (("silhouette", "depth"), False, True, gate, reach), (("silhouette", "depth"), False, True, 0.0, reach),
             (("silhouette", "depth"), False, True, gate, 0.0),
             (("silhouette", "depth"), False, False, gate, reach), (("silhouette", "depth"), True, True, gate, reach)]
    for constraints, warm, refine, hull_gate_m, depth_reach_m in cases:
        # per-frame initialisation, as before the tracker: this session samples a whole walk cycle in 6
        # frames, far from video rate (the tracker's table is _tracking's)
        s = reconstruct_session(session_path, solver="gs", template="13k", joints="tracker",
                                constraints=constraints, frames=frames, warm_start=warm, refine_pose=refine,
                                tracking=False, params=RapidSkinParams(constraints=constraints,
                                                                       hull_gate_m=hull_gate_m,
                                                                       depth_reach_m=depth_reach_m))
        name = ",".join(constraints) + (" (warm start)" if warm else "") + ("" if refine else " (tracker init only)")
        name += "" if hull_gate_m else " (no hull gate)"
        name += "" if depth_reach_m else " (no depth reach)"
        results[name] = s
        rows.append([name, s["frames"], s["median_mm"], s["p90_mm"], s["median_all_mm"],
                     s["p90_all_mm"], s["hausdorff_mm"], s["pct_under_10mm"], s["iou_min"],
                     s["init_joint_error_mm"], s["init_ms"], s["solver_ms"], s["matching_ms"]])
    table = markdown_table(["constraints", "frames", "median mm (visible)", "p90 mm (visible)", "median mm (all)",
                            "p90 mm (all)", "Hausdorff mm", "% area < 10 mm", "min IoU", "init joint error mm",
                            "init ms (pose + refinement)", "solver ms", "matching ms"], rows)
    return table, results


def _frame_inputs(session_path: Path, template: str):
    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.reconstruct.pose_init import initialise_pose
    from bodystudio.reconstruct.sequence import TEMPLATES, frame_joints

    session = open_session(session_path)
    frame = session.frame(session.frame_ids[0])
    body = build_body(resolution=TEMPLATES[template])
    init = initialise_pose(body, frame_joints(session, frame, "tracker", None))
    masks = {n: frame.masks[n] for n in frame.masks}
    return body, init.vertices, list(session.cameras), masks, frame


def _timings(session_path: Path, repeats: int) -> tuple[str, dict]:
    import numba
    from threadpoolctl import threadpool_limits

    numba.set_num_threads(1)
    with threadpool_limits(1):  # one core for every solver, BLAS included (the paper's single-core CPU)
        return _timing_table(session_path, repeats)


def _timing_table(session_path: Path, repeats: int) -> tuple[str, dict]:
    from bodystudio.reconstruct.evaluate import surface_error
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations

    rows, ms = [], {}
    for template in ("2k", "6k", "13k"):
        body, V0, cams, masks, frame = _frame_inputs(session_path, template)
        gt = frame.gt_mesh
        for solver in ("gs", "jacobi", "cholesky", "cg"):
            params = RapidSkinParams(solver=solver)
            deform_to_observations(V0, body.faces, cams, masks, params)  # compile / warm caches
            times, match, err = [], [], None
            for _ in range(repeats if solver != "cholesky" else max(2, repeats // 2)):
                r = deform_to_observations(V0, body.faces, cams, masks, params)
                times.append(r.solver_s)
                match.append(r.matching_s)
                err = r
            ms[(template, solver)] = 1000 * statistics.median(times)
            ms[(template, solver, "matching")] = 1000 * statistics.median(match)
            e = surface_error(err.vertices, body.faces, gt.vertices, gt.faces)
            rows.append([f"{template} ({len(V0)} v)", solver, ms[(template, solver)],
                         ms[(template, solver, "matching")], e.median_mm, e.p90_mm])
    for row in rows:
        template = row[0].split()[0]
        row.insert(3, ms[(template, row[1])] / ms[(template, "gs")])
    table = markdown_table(["template", "solver", "solver ms / frame", "x GS time",
                            "matching ms / frame (No x 10 views)", "median mm", "p90 mm"], rows)
    return table, ms


def _convergence(session_path: Path, max_iterations: int) -> tuple[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bodystudio.geometry.laplacian import cotangent_delta_coordinates
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.reconstruct.evaluate import point_to_surface_mm
    from bodystudio.reconstruct.silhouette import silhouette_constraints
    from bodystudio.reconstruct.solver import (
        ConstraintSet,
        DepthConstraints,
        cholesky,
        conjugate_gradient,
        constraint_energy,
        gauss_seidel,
    )

    body, V0, cams, masks, frame = _frame_inputs(session_path, "2k")
    gt = frame.gt_mesh
    delta, delta_rest = cotangent_delta_coordinates(V0, body.faces)
    sil = silhouette_constraints(V0, body.faces, vertex_normals(V0, body.faces), cams, masks)
    cs = ConstraintSet(delta, delta_rest, sil, DepthConstraints.empty())
    e_min = constraint_energy(cholesky(V0, cs), cs)
    e0 = constraint_energy(V0, cs)
    iters = np.arange(0, max_iterations + 1)
    curves = {}
    for name in ("gs", "cg"):
        err, energy = [], []
        for n in iters:
            if n == 0:
                V = V0
            elif name == "gs":
                V = gauss_seidel(V0, cs, int(n))  # k' depends on Ni, so each Ni is its own run
            else:
                V = conjugate_gradient(V0, cs, int(n))
            err.append(float(np.median(point_to_surface_mm(V, gt.vertices, gt.faces))))
            energy.append((constraint_energy(V, cs) - e_min) / (e0 - e_min))
        curves[name] = (err, energy)
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    for name, label in (("gs", "Gauss-Seidel constraints"), ("cg", "conjugate gradients (LME)")):
        ax[0].plot(iters, curves[name][0], marker="o", ms=3, label=label)
        ax[1].semilogy(iters, np.maximum(curves[name][1], 1e-6), marker="o", ms=3, label=label)
    ax[0].set_xlabel("inner iterations Ni (fixed contour matches)")
    ax[0].set_ylabel("median distance to GT (mm)")
    ax[1].set_xlabel("inner iterations Ni")
    ax[1].set_ylabel("(E - E_min) / (E_0 - E_min)")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    ax[1].grid(alpha=0.3)
    fig.suptitle("Rapid Skin 2.5K template, 10 cameras, one outer iteration")
    fig.tight_layout()
    png = DOCS / "reconstruct_convergence.png"
    from bodystudio.fileio import atomic_path

    with atomic_path(png) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    rows = [[int(n), curves["gs"][0][k], curves["cg"][0][k], curves["gs"][1][k], curves["cg"][1][k]]
            for k, n in enumerate(iters) if n in (0, 1, 2, 4, 8, 16, max_iterations)]
    table = markdown_table(["Ni", "GS median mm", "CG median mm", "GS rel. energy", "CG rel. energy"], rows)
    return table, png


#: Video-rate sessions for the tracker: (motion, hidden subject); none is used by the tests.
TRACK_SESSIONS = (("walk", 31), ("turn", 3), ("arm_flex", 12))
TRACK_FPS = 30.0
STEPS = ("read_ms", "init_ms", "fields_ms", "refine_ms", "track_ms", "matching_ms", "solver_ms", "other_ms",
         "frame_ms")
#: ``bodystudio reconstruct --accurate`` (``reconstruct.presets``: the tracker, guarded joint smoothing 2, the shape
#: prior, the whole body's depth in the pose refinement, the torso hold; docs/reconstruct.md, rec15g / rec15h)
ACCURATE_MODE = "accurate (--accurate)"
#: (label, tracking, refinement data, hull gate on the silhouette matches, bone lengths, joint smoothing): the
#: previous defaults (carved hull; distance fields without the gate; each frame's tracked bone lengths), the
#: per-frame init with the gate and one set of bone lengths per run (the default), with the joints smoothed over
#: +-2 frames (--joint-smoothing 2), the tracker.
TRACK_MODES = (("per-frame init, hull, no gate, frame lengths", False, "hull", False, "frame", 0),
               ("per-frame init, fields, no gate, frame lengths", False, "fields", False, "frame", 0),
               ("per-frame init, fields, frame lengths", False, "fields", True, "frame", 0),
               ("per-frame init, fields", False, "fields", True, "sequence", 0),
               ("per-frame init, fields, joint smoothing 2", False, "fields", True, "sequence", 2),
               ("tracker, frame lengths", True, "fields", True, "frame", 0),
               ("tracker, 6 fit it, No = 8 (before issue 15's frame time)", True, "fields", True, "sequence", 0),
               ("tracker", True, "fields", True, "sequence", 0),
               ("tracker, joint smoothing 2", True, "fields", True, "sequence", 2),
               (ACCURATE_MODE, True, "fields", True, "sequence", 2))
#: The tracker as first measured: every tracked frame 6 fit iterations and the run's No (the rows so named).
TRACK_BEFORE = {"iterations": 6, "min_decrease": 0.0, "outer_iterations": 0, "inner_iterations": 0}
REGION_NAMES = ("head", "torso", "crotch", "arms", "hands", "legs", "feet")


def _frame_steps(session_path: Path, repeats: int) -> str:
    """CPU ms (one thread, median of ``repeats``) of each step of frame 1 of a video-rate session, for the
    previous default (carved hull), the new default (distance fields) and the tracker (from frame 0's
    pose): CPU time stays meaningful on a loaded machine where wall time does not."""
    import time
    from dataclasses import replace

    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.geometry.laplacian import cotangent_weights
    from bodystudio.reconstruct.articulated_fit import refine_bone_transforms
    from bodystudio.reconstruct.depth import depth_observation, depth_observation_reference
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations
    from bodystudio.reconstruct.sequence import frame_joints
    from bodystudio.reconstruct.tracking import (
        SilhouetteFields,
        TrackParams,
        outside_fraction,
        silhouette_data_term,
        track_bone_transforms,
    )
    from bodystudio.reconstruct.visual_hull import visual_hull

    def cpu(f, *args, **kwargs):
        t = time.process_time()
        out = f(*args, **kwargs)
        return 1000 * (time.process_time() - t), out

    def read_masks(frame):
        return {n: frame.masks[n] for n in frame.masks}

    def checks(T_prior, T_fit, fields):
        return [outside_fraction(pose_template(fit_body, T).vertices, fields) for T in (T_prior, T_fit)]

    numba.set_num_threads(1)
    session = open_session(session_path)
    cams = list(session.cameras)
    body, fit_body = build_body(resolution="full"), build_body(resolution="2k")
    frame0 = session.frame(session.frame_ids[0])
    T0 = initialise_pose(fit_body, frame_joints(session, frame0, "tracker", None)).bone_transforms
    rest_delta = cotangent_weights(body.vertices, body.faces)
    params = TrackParams(**TRACK_BEFORE)  # the tracker as first measured (6 it, No = 8)
    fast = TrackParams()  # a tracked frame now (issue 15's frame time): fewer fit and outer iterations
    no_fast = fast.outer_iterations or RapidSkinParams().outer_iterations
    ni_fast = fast.inner_iterations or RapidSkinParams().inner_iterations  # its sweeps (rec15n)
    # and (rec15e) the tracked frame's cheaper last matching and chamfer distance fields
    fast_params = RapidSkinParams(outer_iterations=no_fast, inner_iterations=ni_fast, matching=fast.matching)
    fast_fields = f"distance fields ({'exact' if fast.exact_fields else 'chamfer'}), tracked frame now"
    fast_fit = f"tracking fit (<= {fast.iterations} it, stops on the energy's plateau), tracked frame now"
    fast_match, fast_solve = f"matching (No = {no_fast} x 10 views), tracked frame now", \
        f"solver (GS, No = {no_fast} x Ni = {ni_fast}), tracked frame now"
    ms: dict[str, list[float]] = {}
    wall: dict[tuple[str, int], list[float]] = {(m, k): [] for m in ("default", "fast") for k in (1, 2)}
    end_to_end: dict[tuple[str, int], list[float]] = {}

    sensor = session.kinect  # the depth rows (issue 15's accuracy goals are for silhouettes + depth)
    depth_params = replace(fast_params, constraints=("silhouette", "depth"))

    def tracked_frame_now(path, frame_id, with_depth=False):
        """A tracked frame as ``reconstruct_frames`` runs it, from frame 0's pose (the prior); ``with_depth``: with
        the Kinect depth (its PNG, the observation, the depth constraints)."""
        frame = open_session(path).frame(frame_id)
        masks = read_masks(frame)
        depth = depth_observation(frame.kinect_depth_m, sensor.depth) if with_depth else None
        fields = SilhouetteFields(cams, masks, exact=fast.exact_fields)
        outside_fraction(pose_template(fit_body, T0).vertices, fields)
        T = track_bone_transforms(fit_body, T0, fields, fast)
        outside_fraction(pose_template(fit_body, T).vertices, fields)
        P = pose_template(body, T, 1.0)
        return deform_to_observations(P.vertices, body.faces, cams, masks, depth_params if with_depth else fast_params,
                                      depth=depth, delta=rest_delta, fields=fields)
    with threadpool_limits(1):
        for rep in range(repeats + 1):  # the first run compiles
            steps = {}
            frame = open_session(session_path).frame(session.frame_ids[1])
            steps["read masks"], masks = cpu(read_masks, frame)
            if sensor is not None:
                steps["read depth (PNG)"], D = cpu(lambda f: f.kinect_depth_m, frame)
                steps["depth observation (numpy, before rec15f)"], _ = cpu(depth_observation_reference, D,
                                                                           sensor.depth)
                steps["depth observation (compiled), now"], _ = cpu(depth_observation, D, sensor.depth)
            steps["read joints"], J = cpu(frame_joints, session, frame, "tracker", None)
            t_pose, init2 = cpu(initialise_pose, fit_body, J)
            t_pose13, init = cpu(initialise_pose, body, J)
            steps["pose init from joints (2.5K + 13K)"] = t_pose + t_pose13
            steps["visual hull (carved)"], hull = cpu(visual_hull, cams, masks)
            steps["hull fit (10 it)"], _ = cpu(refine_bone_transforms, fit_body, init2.bone_transforms, hull)
            steps["distance fields"], fields = cpu(SilhouetteFields, cams, masks)
            steps[fast_fields], fields_now = cpu(SilhouetteFields, cams, masks, 48, fast.exact_fields)
            steps["fields fit (10 it)"], T = cpu(refine_bone_transforms, fit_body, init2.bone_transforms, None,
                                                 data_term=silhouette_data_term(fields, params))
            steps["tracking fit (6 it)"], Tt = cpu(track_bone_transforms, fit_body, T0, fields, params)
            steps[fast_fit], _ = cpu(track_bone_transforms, fit_body, T0, fields, fast)
            steps["lost-track checks"], _ = cpu(checks, T0, Tt, fields)
            steps["pose 13K (LBS)"], P = cpu(pose_template, body, T, init.global_scale)
            steps["cotangent weights 13K (per frame)"], _ = cpu(cotangent_weights, P.vertices, body.faces)
            for label, gate in (("", RapidSkinParams().hull_gate_m), (", no hull gate", 0.0)):
                t = time.process_time()
                r = deform_to_observations(P.vertices, body.faces, cams, masks, RapidSkinParams(hull_gate_m=gate),
                                           delta=rest_delta, fields=fields)
                deform = 1000 * (time.process_time() - t)
                share = r.matching_s / max(r.matching_s + r.solver_s, 1e-12)
                steps[f"matching (No = 8 x 10 views{label})"] = deform * share
                steps[f"solver (GS, No = 8 x Ni = 8{label})"] = deform * (1 - share)
            t = time.process_time()
            r = deform_to_observations(P.vertices, body.faces, cams, masks, fast_params, delta=rest_delta,
                                       fields=fields_now)
            deform = 1000 * (time.process_time() - t)
            share = r.matching_s / max(r.matching_s + r.solver_s, 1e-12)
            steps[fast_match], steps[fast_solve] = deform * share, deform * (1 - share)
            # the gated deformation's wall time on one and two numba threads (the cameras' matching and the
            # gate's points in prange; everything else in a frame is one thread)
            for mode, run_params in (("default", RapidSkinParams()), ("fast", fast_params)):
                for threads in (1, 2):
                    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
                    t = time.perf_counter()
                    deform_to_observations(P.vertices, body.faces, cams, masks, run_params, delta=rest_delta,
                                           fields=fields if mode == "default" else fields_now)
                    wall[mode, threads].append(1000 * (time.perf_counter() - t))
            # the whole tracked frame end to end (masks read to deformed mesh) on one and two numba threads:
            # process CPU (all threads), the main thread's CPU (with two threads: its share of the parallel
            # kernels plus everything serial, i.e. the frame's wall on an idle two-core machine when the
            # split is even) and wall, back to back
            for threads in (1, 2):
                numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
                for with_depth in (False, True) if sensor is not None else (False,):
                    clocks = (time.process_time(), time.thread_time(), time.perf_counter())
                    tracked_frame_now(session_path, session.frame_ids[1], with_depth)
                    for name, t0, t1 in zip(("cpu", "main", "wall"), clocks,
                                            (time.process_time(), time.thread_time(), time.perf_counter()),
                                            strict=True):
                        end_to_end.setdefault((name, threads, with_depth), []).append(1000 * (t1 - t0))
            numba.set_num_threads(1)
            if rep:
                for k, v in steps.items():
                    ms.setdefault(k, []).append(v)
    med = {k: statistics.median(v) for k, v in ms.items()}
    wall_1, wall_2 = statistics.median(wall["default", 1][1:]), statistics.median(wall["default", 2][1:])
    fast_1, fast_2 = statistics.median(wall["fast", 1][1:]), statistics.median(wall["fast", 2][1:])
    reads = med["read masks"] + med["read joints"] + med["pose 13K (LBS)"]
    common = reads + med["matching (No = 8 x 10 views)"] + med["solver (GS, No = 8 x Ni = 8)"]
    ungated = reads + med["matching (No = 8 x 10 views, no hull gate)"] \
        + med["solver (GS, No = 8 x Ni = 8, no hull gate)"]
    old = ungated + med["pose init from joints (2.5K + 13K)"] + med["visual hull (carved)"] + med["hull fit (10 it)"] \
        + med["cotangent weights 13K (per frame)"]
    fields_init = med["pose init from joints (2.5K + 13K)"] + med["distance fields"] + med["fields fit (10 it)"]
    tracked = common + med["distance fields"] + med["tracking fit (6 it)"] + med["lost-track checks"]
    tracked_now = reads + med[fast_fields] + med[fast_fit] + med["lost-track checks"] + med[fast_match] \
        + med[fast_solve]
    rows = [[k, v] for k, v in med.items()]
    rows += [["**whole frame, first default** (joints + carved hull fit + per-frame cotangents, no gate)", old],
             ["**whole frame, second default** (joints + distance-field fit, rest cotangents, no gate)",
              ungated + fields_init],
             ["**whole frame, default** (the same with the visual-hull gate on the matches)", common + fields_init],
             ["**whole frame, tracked frame** (previous pose + distance-field fit + checks, gate)", tracked],
             ["deformation, gated (matching + solver), wall ms, one numba thread", wall_1],
             ["deformation, gated (matching + solver), wall ms, two numba threads", wall_2],
             ["**whole frame, default, two cores** (the default with the deformation's CPU ms scaled by its "
              "two-thread / one-thread wall)",
              common + fields_init - (1 - wall_2 / wall_1) * (med["matching (No = 8 x 10 views)"]
                                                              + med["solver (GS, No = 8 x Ni = 8)"])],
             ["**whole frame, tracked frame, two cores** (the same scaling)",
              tracked - (1 - wall_2 / wall_1) * (med["matching (No = 8 x 10 views)"]
                                                 + med["solver (GS, No = 8 x Ni = 8)"])],
             [f"**whole frame, tracked frame now** (previous pose + fit to the plateau + checks, No = {no_fast}, "
              "gate)", tracked_now],
             [f"deformation, tracked frame now (No = {no_fast}), wall ms, one numba thread", fast_1],
             [f"deformation, tracked frame now (No = {no_fast}), wall ms, two numba threads", fast_2],
             ["**whole frame, tracked frame now, two cores** (its deformation's CPU ms scaled by its two-thread / "
              "one-thread wall)", tracked_now - (1 - fast_2 / fast_1) * (med[fast_match] + med[fast_solve])]]
    e2e = {k: statistics.median(v[1:]) for k, v in end_to_end.items()}
    rows += [["**whole frame, tracked frame now, end to end, one numba thread**: CPU ms / wall ms",
              f"{e2e['cpu', 1, False]:.1f} / {e2e['wall', 1, False]:.1f}"],
             ["**whole frame, tracked frame now, end to end, two numba threads**: CPU ms (all threads) / main "
              "thread's CPU ms (the idle two-core wall when the split is even) / wall ms",
              f"{e2e['cpu', 2, False]:.1f} / {e2e['main', 2, False]:.1f} / {e2e['wall', 2, False]:.1f}"]]
    if sensor is not None:
        rows += [["**whole frame, tracked frame now, silhouettes + depth, end to end, one numba thread**: CPU ms / "
                  "wall ms", f"{e2e['cpu', 1, True]:.1f} / {e2e['wall', 1, True]:.1f}"],
                 ["**whole frame, tracked frame now, silhouettes + depth, end to end, two numba threads**: CPU ms "
                  "(all threads) / main thread's CPU ms / wall ms",
                  f"{e2e['cpu', 2, True]:.1f} / {e2e['main', 2, True]:.1f} / {e2e['wall', 2, True]:.1f}"]]
    return markdown_table(["step (frame 1, 13K, 10 cameras 640x480, one thread)", "CPU ms (median)"], rows)


def _tracking(tmp: Path, n_frames: int) -> tuple[str, str, dict]:
    import json

    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.capture.synth import synth_session
    from bodystudio.reconstruct.presets import accurate_keywords
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session
    from bodystudio.reconstruct.tracking import TrackParams

    numba.set_num_threads(1)
    time_rows, acc_rows, out = [], [], {}
    for motion, subject in TRACK_SESSIONS:
        path = tmp / f"{motion}{subject}"
        synth_session(path, n_cameras=10, n_frames=n_frames, motion=motion, subject_seed=subject, template="full",
                      fps=TRACK_FPS)
        if motion == "walk":
            out["steps"] = _frame_steps(path, 5)
        for constraints in (("silhouette",), ("silhouette", "depth")):
            for mode, tracking, refine_with, gated, lengths, smoothing in TRACK_MODES:
                params = RapidSkinParams(constraints=constraints, hull_gate_m=RapidSkinParams().hull_gate_m * gated)
                with threadpool_limits(1):
                    track_params = TrackParams(**TRACK_BEFORE) if "(before" in mode else TrackParams()
                    if mode == ACCURATE_MODE:
                        s = reconstruct_session(path, template="13k", constraints=constraints,
                                                **accurate_keywords(params))
                    else:
                        s = reconstruct_session(path, template="13k", constraints=constraints, tracking=tracking,
                                                refine_with=refine_with, params=params, bone_lengths=lengths,
                                                joint_smoothing=smoothing, track_params=track_params)
                frames = json.loads((path / "reconstruct" / "frames.json").read_text())["frames"]
                # frame 0 compiles and initialises in both modes; the steady state is the later frames
                later = frames[1:] or frames
                name = f"{motion} s{subject}, {','.join(constraints)}, {mode}"
                out[(motion, constraints, mode)] = s
                tracks = ", ".join(f"{t} {sum(f['track'] == t for f in frames)}"
                                   for t in dict.fromkeys(f["track"] for f in frames))
                time_rows.append([name, tracks] + [float(np.mean([f[k] for f in later])) for k in STEPS])
                regions = [float(np.mean([f["metrics"]["regions"][r]["p90_mm"] for f in frames
                                          if r in f["metrics"]["regions"]])) for r in REGION_NAMES]
                acc_rows.append([name, s["median_mm"], s["p90_mm"], s["hausdorff_mm"], s["iou_min"]] + regions)
    time_table = markdown_table(["session, constraints, mode", "frames tracked / initialised (why)",
                                 "read ms", "init ms (pose + fields + refine/track)", "fields ms (distance transforms)",
                                 "refine ms (hull or fields fit)",
                                 "track ms (fields + fit + check)", "matching ms", "solver ms", "other ms",
                                 "whole frame ms"], time_rows)
    acc_table = markdown_table(["session, constraints, mode", "median mm (visible)", "p90 mm (visible)",
                                "Hausdorff mm", "min IoU"] + [f"{r} p90 mm" for r in REGION_NAMES], acc_rows)
    return time_table, acc_table, out


def run(quick: bool = False) -> str:
    from bodystudio.reconstruct.tracking import TrackParams

    n_frames = 2 if quick else 6
    with tempfile.TemporaryDirectory(prefix="bench-reconstruct-") as tmp:
        session = _session(Path(tmp), n_frames)
        acc_table, acc = _accuracy(session.path, f"0:{n_frames}")
        time_table, ms = _timings(session.path, 3 if quick else 5)
        conv_table, png = _convergence(session.path, 10 if quick else 20)
        track_time, track_acc, track_extra = _tracking(Path(tmp), 3 if quick else 6)
    sil, sil_plain = acc["silhouette"], acc["silhouette (tracker init only)"]
    both, both_plain = acc["silhouette,depth"], acc["silhouette,depth (tracker init only)"]
    gs13, ch13 = ms[("13k", "gs")], ms[("13k", "cholesky")]
    return "\n\n".join([
        "## reconstruct (Rapid Skin)",
        f"Synthetic walk, subject {SUBJECT_SEED}, 10 cameras 640x480, {n_frames} frames, 13K template, tracker "
        "joints (1 cm noise, 3 % bone-length jitter), No = 8 x Ni = 8, tau = 30 px, alpha = 40 px. Errors are "
        "two-way point-to-surface distances, pooled; 'visible' keeps ground-truth points seen by a camera. "
        "Default: the pose from the tracker joints (Sec. IV.A) is refined by an articulated fit of its bone "
        "transforms (2.5K template) to the implicit visual hull of the silhouettes' distance fields before the "
        "deformation; 'tracker init only' is the paper's initialisation (`--no-refine-pose`). Every frame is "
        "initialised from its joints (these 6 frames span a whole walk cycle, far from video rate; the "
        "tracker's tables are below). 'no depth reach': depth pairs only within 5 cm of a vertex not more than 4 cm "
        "behind its depth pixel (before issue 15's depth reach: now the template's own front surface pairs up to "
        "10 cm). Init ms is wall time on the shared machine.",
        acc_table,
        f"Default, median / p90 on the visible surface (goals <= 4 / <= 10 mm): silhouettes {sil['median_mm']:.2f} / "
        f"{sil['p90_mm']:.2f} mm, silhouettes + depth {both['median_mm']:.2f} / {both['p90_mm']:.2f} mm; "
        f"tracker init only {sil_plain['median_mm']:.2f} / {sil_plain['p90_mm']:.2f} and "
        f"{both_plain['median_mm']:.2f} / {both_plain['p90_mm']:.2f} mm. The refinement costs "
        f"{sil['init_ms'] - sil_plain['init_ms']:.0f} ms per frame (distance fields and 10 Gauss-Newton iterations; "
        "in ms_per_frame, not in the solver time). Statistics are over vertices (the 13K mesh is densest on "
        "head, hands and feet); the area share under 10 mm is area-weighted.",
        "Solver time per frame, one thread (numba and BLAS limited to 1), contour matching excluded (paper "
        "Fig. 9); Jacobi runs 4 x Ni sweeps; Cholesky refactors once per outer iteration (matches change). "
        "Frame 0 from the tracker initialisation alone (the solvers' inputs must not depend on the refinement); "
        "the error columns are that frame's.",
        time_table,
        f"13K: GS {gs13:.1f} ms/frame (goal <= 20 ms), Cholesky / GS = {ch13 / gs13:.1f} (goal >= 20); contour "
        f"matching {ms[('13k', 'gs', 'matching')]:.0f} ms/frame (8 re-matchings x 10 views, one thread).",
        "Error vs inner iterations on fixed matches (2.5K template, frame 0), plot "
        f"`docs/{png.name}`:",
        conv_table,
        f"### Tracker vs per-frame initialisation (issue 15)\n\nVideo-rate sessions ({TRACK_FPS:.0f} fps, "
        f"{3 if quick else 6} frames) of subjects the tests do not use, 10 cameras 640x480, 13K template, tracker "
        "joints. 'per-frame init, hull, no gate': every frame from its joints + the refinement on the carved "
        "visual hull, the paper's matching (the first default); 'per-frame init, fields, no gate': the same on "
        "the distance fields' implicit hull (the second); 'per-frame init, fields': with the visual-hull gate on "
        "the silhouette matches; '..., frame lengths': each frame posed with its own tracked bone lengths "
        "(`--bone-lengths frame`, the previous behaviour), the others with one set per run, the median over its "
        "frames (the default); 'per-frame init, fields' is the default; 'joint smoothing 2': the tracked "
        "joints smoothed over +-2 frames (`--joint-smoothing 2`); 'tracker' (`--tracking`): the previous "
        "frame's pose fitted to the distance fields, re-initialised on a lost track; a tracked frame's fit stops "
        "on the data energy's plateau and its deformation re-matches fewer times (`TrackParams`: "
        f"min_decrease {TrackParams().min_decrease:g}, No = {TrackParams().outer_iterations or 8} x Ni = "
        f"{TrackParams().inner_iterations or 8}); "
        "'tracker, 6 fit it, No = 8 (before ...)': every tracked frame 6 fit iterations and No = 8, the tracker "
        "as first measured; 'accurate (--accurate)': `bodystudio reconstruct --accurate` (the tracker, the "
        "joints smoothed over +-2 frames with a silhouette guard, the body model's shape prior, the whole body's "
        "Kinect depth in the pose refinement with a silhouette guard, the torso held against the outer "
        "iterations' drift; `reconstruct.presets`; tuned on these three sessions, checked on four held-out ones in "
        "docs/reconstruct.md). Whole-frame ms by step are "
        "means over frames 1.. "
        "(frame 0 initialises in both modes), numba and BLAS on one thread, wall time on the shared machine.",
        track_time,
        track_acc,
        "CPU time per step of one frame (walk s31, frame 1; `time.process_time`, one thread, median of 5: "
        "meaningful on the shared machine where the wall times above are not):",
        track_extra["steps"],
    ])
