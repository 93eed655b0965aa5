"""Plant the mutants of MIR12s's TARGET_ROOT lines of mirror/reshape.py by hand in a scratch copy and run the tests
of ``target_skeleton``'s root (the constant and its one use; mutmut's run of the whole function needs the 6k model per
mutant)."""
# usage (from the repository root): python docs/mutation/mirror-reshape-target-root-plant.py [TEST ...]
import os
import shutil
import subprocess
import sys

src_root = os.getcwd()
work = "/work/wt-mutAA-work/reshape-target-root-plant"
F = "bodystudio/mirror/reshape.py"
USE = '        if not (TARGET_ROOT == "source" if keep_root is None else keep_root):\n            return skeleton\n'
mutants = [
    ('TARGET_ROOT = "model"\n', 'TARGET_ROOT = "source"\n', "default source (before MIR12s)"),
    ('TARGET_ROOT = "model"\n', 'TARGET_ROOT = "XXmodelXX"\n', "default renamed (equivalent: any value but source)"),
    (USE, USE.replace('== "source"', '!= "source"'), "== for !="),
    (USE, USE.replace('"source" if', '"XXsourceXX" if'), "source renamed"),
    (USE, USE.replace("is None", "is not None"), "is not None"),
    (USE, USE.replace("if not (", "if ("), "not dropped"),
    (USE, USE.replace("else keep_root", "else not keep_root"), "keep_root negated"),
    (USE, USE.replace("            return skeleton\n", "            pass\n"), "return dropped"),
]
tests = sys.argv[1:] or ["tests/mirror/test_target_root_mutants.py",
         "tests/mirror/test_reshape_analytic.py::test_target_skeleton_from_the_model_moves_the_joints_by_the_regressor",
         "tests/mirror/test_reshape_analytic.py::test_posed_target_of_a_side_on_person_is_the_ground_truths"]
if os.path.exists(work):
    shutil.rmtree(work)
os.makedirs(work)
for d in ("bodystudio", "tests"):
    shutil.copytree(os.path.join(src_root, d), os.path.join(work, d), ignore=shutil.ignore_patterns("__pycache__"))
shutil.copy2(os.path.join(src_root, "pyproject.toml"), work)
clean = open(os.path.join(work, F)).read()
killed = 0
for old, new, name in [(USE, USE, "clean")] + mutants:
    assert clean.count(old) == 1, name
    open(os.path.join(work, F), "w").write(clean.replace(old, new))
    r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests], cwd=work,
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": work})
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    killed += bool(r.returncode) and name != "clean"
    print(f"{name}: {'killed' if r.returncode else 'survived'} {first[:150]}", flush=True)
open(os.path.join(work, F), "w").write(clean)
print(f"{killed} / {len(mutants)} killed")
