"""Plant mutLL's hand-made mutants (code mutmut does not mutate: the numba kernel ``_closest_of_kept``, module
constants and regular expressions, the stale-match bugs the brief names, the changed lines inside the long
``session_inputs`` / ``run_mirror`` / ``initialise_source_body``) in a scratch copy and run the given tests.

usage (from the repository root): python docs/mutation/mirror-init-mutLL-plant.py [WORK]
Each mutant runs first against the tests that existed before mutLL ("killed before"), and when those pass against
the new files too ("killed by the new tests" / "survived")."""
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import scratch_tree  # noqa: E402

work = sys.argv[1] if len(sys.argv) > 1 else "/work/wt-mutLL-work/plant"
INIT, RUN, TRACK = "bodystudio/mirror/init.py", "bodystudio/mirror/run.py", "bodystudio/mirror/track.py"
BATCH, IMP = "bodystudio/batch.py", "bodystudio/capture/importer.py"
NEW_INIT = "tests/mirror/test_init_eq2_reference_mutants.py"
NEW_DEFAULTS = "tests/mirror/test_init_defaults_mutants.py"
OLD_INIT = ["tests/mirror/test_init_match_reuse.py", "tests/mirror/test_init_leg_splay.py",
            "tests/mirror/test_init_pass_settle.py::test_defaults_are_the_papers_passes",
            "tests/mirror/test_init_unpose_posture.py::test_on_by_default",
            "tests/mirror/test_init_analytic.py::test_initialise_source_body_passes_the_depth_camera_and_passes"] + [
    f"tests/mirror/test_init_analytic.py::test_eq2_{t}" for t in (
        "normal_equations_equal_the_dense_least_squares_solve", "recovers_planted_coefficients_and_translation",
        "trims_outliers_after_the_first_match_and_drops_nan_and_unmatched", "matches_only_candidate_vertices",
        "joint_rows_weigh_joint_weight", "symmetric_term_pulls_unsupported_model_parts", "defaults_and_edges")]
OBS_OLD = ["tests/reliability/test_mirror_init_settle_options.py", "tests/reliability/test_mirror_init_leg_splay_options.py",
           "tests/mirror/test_init_pass_settle.py", "tests/mirror/test_init_pool_seed.py"]
RUNT = ["tests/mirror/test_untwist_feet.py", "tests/mirror/test_time_init_untwist_bones.py",
        "tests/mirror/test_run_mutants.py::test_run_mirror_several_players_are_checked_loaded_and_recorded",
        "tests/mirror/test_run_analytic.py::test_session_inputs_warn_per_frame_and_ramp_the_edit"]
NAMES_NEW = "tests/reliability/test_rel6b_names_mutants.py"
NAMES_OLD = ["tests/reliability/test_rel6b_names.py", "tests/reliability/test_batch_inputs.py",
             "tests/capture/test_importer_mutants.py"]

KSQ = "        d[i], m[i] = np.sqrt(best), arg"
KLOOP = "        for j in range(near.shape[1]):"
KIF = "            if e < best:"
KE = "            e = (P[i, 0] - V[v, 0]) ** 2 + (P[i, 1] - V[v, 1]) ** 2 + (P[i, 2] - V[v, 2]) ** 2"
STALE = '        stale = d > cache["reach"] - moved'
MOVED = '        moved = float(np.sqrt(((V - cache["vertices"]) ** 2).sum(axis=1).max()))'
REQ = "                d[stale], m[stale] = cKDTree(V).query(P[stale])"
UPD = '    cache.update(vertices=V.copy(), near=near, reach=dk[:, -1])'
MATCH = "            d, m = closest_vertex_matches(P, V[cand] + t, match_cache)"
SRC = "                                        else POSTURE_BONES if unpose_posture else ())"
UNT = "                poses.append(untwisted_pose(a.body.skeleton, pose, untwist) if untwist else pose)"
ADDR = r'_SCHEDULER_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx|ws|wss)://(\[[0-9A-Fa-f:.]+\]|[^\s/:\x00-\x1f\x7f]+)(:[0-9]+)?/?")'
CAM = '_CAMERA_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")'

mutants = [  # (file, old, new, name, tests before, tests after)
    (INIT, KSQ, "        d[i], m[i] = best, arg", "kernel: squared distance returned", OLD_INIT, [NEW_INIT]),
    (INIT, KLOOP, "        for j in range(1, near.shape[1]):", "kernel: first kept vertex skipped", OLD_INIT, [NEW_INIT]),
    (INIT, KLOOP, "        for j in range(near.shape[1] - 1):", "kernel: last kept vertex skipped", OLD_INIT, [NEW_INIT]),
    (INIT, KIF, "            if e > best:", "kernel: > for <", OLD_INIT, [NEW_INIT]),
    (INIT, KIF, "            if e <= best:", "kernel: <= for < (ties: the last)", OLD_INIT, [NEW_INIT]),
    (INIT, KE, KE.replace("(P[i, 2] - V[v, 2])", "(P[i, 1] - V[v, 2])"), "kernel: z read as y", OLD_INIT, [NEW_INIT]),
    (INIT, KE, KE.replace(" + (P[i, 2] - V[v, 2]) ** 2", ""), "kernel: z dropped", OLD_INIT, [NEW_INIT]),
    (INIT, "                best, arg = e, v", "                best, arg = e, near[i, 0]", "kernel: index not updated",
     OLD_INIT, [NEW_INIT]),
    (INIT, STALE, '        stale = d > cache["reach"]', "stale match: the move ignored", OLD_INIT, [NEW_INIT]),
    (INIT, STALE, '        stale = d > cache["reach"] + moved', "stale match: + moved", OLD_INIT, [NEW_INIT]),
    (INIT, STALE, "        stale = d > np.inf", "stale match: never re-queried", OLD_INIT, [NEW_INIT]),
    (INIT, MOVED, MOVED.replace(".max()", ".mean()"), "stale match: mean move for the largest", OLD_INIT,
     [NEW_INIT]),
    (INIT, REQ, "                pass", "stale match: flagged points not re-queried", OLD_INIT, [NEW_INIT]),
    (INIT, UPD, '    cache.setdefault("near", near)\n    cache.setdefault("reach", dk[:, -1])\n'
     '    cache.setdefault("vertices", V.copy())', "stale match: the first query kept for ever", OLD_INIT, [NEW_INIT]),
    (INIT, UPD, "    cache.update(vertices=V, near=near, reach=dk[:, -1])", "stale match: vertices not copied",
     OLD_INIT, [NEW_INIT]),
    (INIT, MATCH, '            d, m = match_cache.setdefault("first", closest_vertex_matches(P, V[cand] + t, match_cache))',
     "fit_shape: the first match reused at every re-matching", OLD_INIT, [NEW_INIT]),
    (INIT, MATCH, "            d, m = closest_vertex_matches(P, model.vertices(c)[cand] + t, match_cache)",
     "fit_shape: matched without the free columns", OLD_INIT, [NEW_INIT]),
    (INIT, "WEIGHTED_POOL = True", "WEIGHTED_POOL = False", "default: weighted pool off", OLD_INIT, [NEW_DEFAULTS]),
    (INIT, 'UNPOSE_POSTURE_BONES: tuple[str, ...] = ("spine_02", "neck_01", "head")',
     "UNPOSE_POSTURE_BONES: tuple[str, ...] = ()", "default: no posture bones", OLD_INIT, [NEW_DEFAULTS]),
    (INIT, "LEG_SPLAY = False", "LEG_SPLAY = True", "default: leg splay on", OLD_INIT, [NEW_DEFAULTS]),
    (INIT, "KNEE_HINGE_WEIGHT = 0.0", "KNEE_HINGE_WEIGHT = 1.0", "default: knee hinge on", OLD_INIT, [NEW_DEFAULTS]),
    (INIT, "LEG_SPLAY_SIGMA_RAD = 0.1", "LEG_SPLAY_SIGMA_RAD = 0.2", "default: free prior 0.2 rad", OLD_INIT,
     [NEW_DEFAULTS]),
    (INIT, '("calf_r", ("calf_r", "foot_r", "ball_r")))', '("calf_r", ("calf_r", "foot_r")))',
     "LEG_SPLAY_CHAINS: the right ball left out", OLD_INIT, [NEW_INIT, NEW_DEFAULTS]),
    (INIT, SRC, "                                        else POSTURE_BONES)", "initialise_source_body: False as True",
     OLD_INIT, [NEW_DEFAULTS]),
    (INIT, "unpose_posture_bones=UNPOSE_POSTURE_BONES if unpose_posture is None",
     "unpose_posture_bones=() if unpose_posture is None", "initialise_source_body: None as upright", OLD_INIT,
     [NEW_DEFAULTS]),
    (INIT, "or pool_seed < 0:", "or pool_seed < 1:", "pool_seed: 0 refused", OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "    if isinstance(pool_seed, bool) or not", "    if not", "pool_seed: a bool accepted", OBS_OLD,
     [NEW_DEFAULTS]),
    (INIT, "    rng = np.random.default_rng(pool_seed)", "    rng = np.random.default_rng(0)", "pool_seed: not the seed",
     OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "knee_hinge_weight >= 0):", "knee_hinge_weight > 0):", "knee_hinge_weight: 0 refused", OBS_OLD,
     [NEW_DEFAULTS]),
    (INIT, "        if leg_splay:\n", "        if not leg_splay:\n", "leg_splay: negated", OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "free = leg_splay_basis(body.vertices,", "free = leg_splay_basis(model.mean,",
     "leg_splay: the mean body's columns every pass", OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "free_basis=free[0], free_joint_basis=free[1],", "free_basis=free[0], free_joint_basis=None,",
     "leg_splay: the joints' columns dropped", OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "free_joint_basis=free[1], free_sigma=LEG_SPLAY_SIGMA_RAD,", "free_joint_basis=free[1], free_sigma=1.0,",
     "leg_splay: another prior", OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "obs[0][0].version, knee_hinge_weight)", "obs[0][0].version, 1.0)", "knee hinge: the weight not passed",
     OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "knee_hinge_splay_rows(model, body.skeleton, refined_poses,",
     "knee_hinge_splay_rows(model, body.skeleton, refined_poses[:1],", "knee hinge: the first frame's pose only",
     OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "if knee_hinge_weight > 0 and refined_poses else None)", "if knee_hinge_weight > 0 else None)",
     "knee hinge: rows asked without poses (equivalent: no poses give no rows)", OBS_OLD, [NEW_DEFAULTS]),
    (INIT, "if knee_hinge_weight > 0 and refined_poses else None)", "if refined_poses else None)",
     "knee hinge: rows of weight 0 (equivalent: zero rows add nothing)", OBS_OLD, [NEW_DEFAULTS]),
    (RUN, "UNTWIST_FEET = True", "UNTWIST_FEET = False", "run: feet not untwisted", RUNT, []),
    (TRACK, 'UNTWIST_FEET_BONES = ("foot_l", "foot_r")', 'UNTWIST_FEET_BONES = ("foot_l",)', "track: right foot left out",
     RUNT, []),
    (RUN, "                untwist = untwist_bones()", "                untwist = UNTWIST_BONES",
     "session_inputs: the limbs only", RUNT, []),
    (RUN, UNT, "                poses.append(pose)", "session_inputs: not untwisted", RUNT, []),
    (RUN, UNT, UNT.replace("if untwist else pose", "if not untwist else pose"), "session_inputs: condition negated",
     RUNT, []),
    (RUN, "        followed = followed_players(session, players, ids)", "        followed = followed_players(session, "
     "players, ids[:1])", "run_mirror: followed over the first frame only", RUNT, []),
    (RUN, "        tracked = {p: {i: f[k] for i, f in followed.items()} for k, p in enumerate(players)}",
     "        tracked = {p: {i: f[0] for i, f in followed.items()} for k, p in enumerate(players)}",
     "run_mirror: every actor read as the first", RUNT, []),
    (RUN, "                                                     tracked_as=tracked[p]),",
     "                                                     tracked_as=None),", "run_mirror: source check by id", RUNT, []),
    (RUN, '"registration": check_registration(session, p, accept_implausible, tracked_as=tracked[p])}',
     '"registration": check_registration(session, p, accept_implausible, tracked_as=None)}',
     "run_mirror: registration by id", RUNT, []),
    (BATCH, ADDR, ADDR.replace(r"\x00-\x1f\x7f", ""), "address: control characters in the host", NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace(r"\x00-\x1f\x7f", r"\x00"), "address: only NUL refused", NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace("(:[0-9]+)?", r"(:\d+)?"), "address: any digit in the port", NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace("(:[0-9]+)?", "(:[0-9]*)?"), "address: empty port", NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace(r"(\[[0-9A-Fa-f:.]+\]|", "(").replace(r"[^\s/:", r"[^\s/"), "address: ':' in the host",
     NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace(r"\[[0-9A-Fa-f:.]+\]", r"\[[^\]]+\]"), "address: any bracketed host", NAMES_OLD,
     [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace("/?\")", "/*\")"), "address: several slashes", NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace("|ws|wss)", "|ws)"), "address: wss refused", NAMES_OLD, [NAMES_NEW]),
    (BATCH, ADDR, ADDR.replace("(tcp|", "(?i:tcp|"), "address: the protocol case-blind", NAMES_OLD, [NAMES_NEW]),
    (IMP, CAM, CAM.replace("[A-Za-z0-9][A-Za-z0-9_.-]*", "[A-Za-z0-9_.-]+"), "camera name: any first character",
     NAMES_OLD, [NAMES_NEW]),
    (IMP, CAM, CAM.replace("[A-Za-z0-9][A-Za-z0-9_.-]*", "[A-Za-z0-9][A-Za-z0-9_-]*"), "camera name: no '.'",
     NAMES_OLD, [NAMES_NEW]),
]
scratch_tree(work)
files = sorted({m[0] for m in mutants})
clean = {f: open(os.path.join(work, f)).read() for f in files}
env = {**os.environ, "PYTHONPATH": work, "NUMBA_CACHE_DIR": os.path.join(work, ".numba")}


def run(tests):
    return subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m", "not slow",
                           *tests], cwd=work, capture_output=True, text=True, env=env)


r = run(sorted({t for m in mutants for t in m[4] + m[5]}))
print(f"clean: {'FAILED' if r.returncode else 'passed'}", flush=True)
before = after = 0
for f, old, new, name, old_tests, new_tests in mutants:
    assert clean[f].count(old) == 1, name
    open(os.path.join(work, f), "w").write(clean[f].replace(old, new, 1))
    try:
        r = run(old_tests)
        verdict = "killed before"
        if not r.returncode:
            r = run(new_tests) if new_tests else r
            verdict = "killed by the new tests" if r.returncode else "survived"
    finally:
        open(os.path.join(work, f), "w").write(clean[f])
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    before += verdict == "killed before"
    after += verdict != "survived"
    print(f"{name}: {verdict} {first[:150]}", flush=True)
print(f"before {before} / {len(mutants)}, after {after} / {len(mutants)} killed")
