"""Plant the mutants of run.py's MIR12p untwist line by hand in a scratch copy and run the session_inputs tests."""
# usage (from the repository root): python docs/mutation/mirror-run-untwist-plant.py
import shutil, subprocess, sys, os
src_root = os.getcwd()
work = "/tmp/mirror-run-untwist-plant"
orig_line = "                poses.append(untwisted_pose(a.body.skeleton, pose, UNTWIST_BONES) if UNTWIST_BONES else pose)"
mutants = {
    "append None": "                poses.append(None)",
    "skeleton None": "                poses.append(untwisted_pose(None, pose, UNTWIST_BONES) if UNTWIST_BONES else pose)",
    "pose None": "                poses.append(untwisted_pose(a.body.skeleton, None, UNTWIST_BONES) if UNTWIST_BONES else pose)",
    "bones None": "                poses.append(untwisted_pose(a.body.skeleton, pose, None) if UNTWIST_BONES else pose)",
    "skeleton dropped": "                poses.append(untwisted_pose(pose, UNTWIST_BONES) if UNTWIST_BONES else pose)",
    "pose dropped": "                poses.append(untwisted_pose(a.body.skeleton, UNTWIST_BONES) if UNTWIST_BONES else pose)",
    "bones dropped": "                poses.append(untwisted_pose(a.body.skeleton, pose, ) if UNTWIST_BONES else pose)",
    "not untwisted": "                poses.append(pose)",
    "untwisted, IK pose kept": "                poses.append(untwisted_pose(a.body.skeleton, pose, UNTWIST_BONES) and pose)",
    "condition negated": "                poses.append(untwisted_pose(a.body.skeleton, pose, UNTWIST_BONES) if not UNTWIST_BONES else pose)",
}
tests = ["tests/mirror/test_run_analytic.py::test_session_inputs_warn_per_frame_and_ramp_the_edit",
         "tests/mirror/test_run_mutants.py::test_session_inputs_reshape_several_players_each_on_its_own"]
if os.path.exists(work):
    shutil.rmtree(work)
os.makedirs(work)
for d in ("bodystudio", "tests"):
    shutil.copytree(os.path.join(src_root, d), os.path.join(work, d))
for f in ("pyproject.toml",):
    shutil.copy2(os.path.join(src_root, f), work)
path = os.path.join(work, "bodystudio/mirror/run.py")
clean = open(path).read()
assert clean.count(orig_line + "\n") == 1
for name, line in [("clean", orig_line)] + list(mutants.items()):
    open(path, "w").write(clean.replace(orig_line + "\n", line + "\n"))
    r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests], cwd=work,
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": work})
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    print(f"{name}: {'killed' if r.returncode else 'survived'} {first[:150]}", flush=True)
open(path, "w").write(clean)
