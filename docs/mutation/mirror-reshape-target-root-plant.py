"""Plant the mutants of MIR12s's TARGET_ROOT lines of mirror/reshape.py by hand in a scratch copy and run the tests
of ``target_skeleton``'s root (the constant and its one use; mutmut's run of the whole function needs the 6k model per
mutant)."""
# usage (from the repository root): python docs/mutation/mirror-reshape-target-root-plant.py [TEST ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

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
replay(F, mutants, tests, work)
