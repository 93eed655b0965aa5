"""mus11y's choice lines in capture_arm_frames and load_arm_capture's sex_fit line, planted by hand (branch mutGG);
run from the repository root: python docs/mutation/muscle-capture-sex-from-depth-plant.py"""
import sys

sys.path.insert(0, "docs/mutation")
from plant import replay  # noqa: E402

M = [
    ('            sexes = (sex_fit["sex"],)\n', '            sexes = sexes\n', "the first run (a man) kept"),
    ("        if len(runs) > 1:  # the subject's", "        if len(runs) > 2:  # the subject's", "never scored"),
    ("sex_fit = sex_from_depth_energies(energies, o.sex_margin_mm)", "sex_fit = sex_from_depth_energies(energies, 0.0)",
     "the margin not passed"),
    ("regressed_joints=regressed, sex_fit=sex_fit)", "regressed_joints=regressed)", "the record not read back"),
]
n = replay("bodystudio/muscle/capture.py", M, ["tests/muscle/test_sex_from_depth_mutants.py",
                                              "tests/muscle/test_sex_choice_capture_mutants.py"],
           "/work/wt-mutGG-work/plant", pytest_args=("-m", "slow or not slow"))
print(f"{n} / {len(M)} killed")
