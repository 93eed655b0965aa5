"""The shape term's form against the extension's ceiling (issue 11 §4, eighth pass): linear Eq. 6-7 or the body form.

For each form (``model.SHAPE_FORMS``) the benchmark's original model (``bench_muscle --step prepare``'s, its training
rows refitted in the form) is extended with the *ground-truth* base-pose and posed meshes of the added out-of-range
subjects 601-604 (the step's "truth meshes": what a perfect capture would give, the form's ceiling), and the model-only
error (median mm over the arm, own rest joints, as ``bench_muscle``) of held-out subjects is measured before and after:
sets A (611-614, the goal's) and B (631-634) as the step's, set C (641-644, 651-654, 661-664: the same groups, other
seeds; the set the body form's choices were made on) and the in-range men 620 and 621-625 (set C in range).

    python -m benchmarks.muscle_extension_form --work W   # W/model.npz from bench_muscle --step prepare
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from benchmarks.bench_muscle import (
    EXTENSION_GROUP_SEEDS,
    EXTENSION_SEEDS,
    HELD_OUT_SETS,
    IN_RANGE_SEED,
    OUT_OF_RANGE,
    RESOLUTION,
    _template,
    out_of_range_subject,
)
from benchmarks.timing import markdown_table

#: set C's in-range men (its out-of-range subjects: the groups' other seeds, not added at 1 per group)
SET_C_IN_RANGE = (621, 622, 623, 624, 625)


def held_out_cases() -> list[tuple[str, int, str]]:
    """(set, seed, group label) of every held-out subject: A, B, C out of range; "in" (620), "C in" (621-625)."""
    labels = list(OUT_OF_RANGE)
    cases = [(name, seed, label) for name, seeds in HELD_OUT_SETS for seed, label in zip(seeds, labels, strict=True)]
    cases += [("C", seed, label) for seeds, label in zip(EXTENSION_GROUP_SEEDS, labels, strict=True)
              for seed in seeds[1:]]
    cases += [("in", IN_RANGE_SEED, "in range")] + [("C in", seed, "in range") for seed in SET_C_IN_RANGE]
    return cases


def form_ceiling(work: Path, forms=("linear", "body")) -> dict:
    """``{form: {"original": {seed: mm}, "extended": {seed: mm}}}`` and the cases, for :func:`table`."""
    from bodystudio.muscle.model import extend_arm_model, load_arm_model, model_error_mm, with_shape_form
    from bodystudio.muscle.synthetic import sample_arm_subject, subject_arm_samples

    prepared = load_arm_model(work / "model.npz", _template())
    added = [s for seed, label in zip(EXTENSION_SEEDS, OUT_OF_RANGE, strict=True)
             for s in subject_arm_samples(out_of_range_subject(seed, label), RESOLUTION, n_shapes=1, n_poses=8,
                                          seed=3, name=f"truth_{seed}")]
    cases = held_out_cases()
    tests = {}
    for _, seed, label in cases:
        subj = (sample_arm_subject(seed, gender="male", bmi_range=(22.0, 26.0)) if label == "in range"
                else out_of_range_subject(seed, label))
        tests[seed] = subject_arm_samples(subj, RESOLUTION, n_shapes=1, n_poses=12, seed=2)
    out = {"cases": cases}
    for form in forms:
        original = with_shape_form(prepared, form)
        extended = extend_arm_model(original, added)
        out[form] = {key: {seed: model_error_mm(m, tests[seed], use_sample_joints=True)["median_mm"]
                           for seed in tests} for key, m in (("original", original), ("extended", extended))}
    return out


def table(data: dict) -> str:
    """Mean change (and mean mm, original -> extended) per set and form; the change against the linear original."""
    sets = list(dict.fromkeys(name for name, _, _ in data["cases"]))
    forms = [f for f in ("linear", "body") if f in data]
    rows = []
    for form in forms:
        d = data[form]
        cells = [form]
        for name in sets:
            seeds = [seed for n, seed, _ in data["cases"] if n == name]
            change = np.mean([100 * (d["extended"][s] / d["original"][s] - 1) for s in seeds])
            vs_linear = np.mean([100 * (d["extended"][s] / data["linear"]["original"][s] - 1) for s in seeds]) \
                if "linear" in data else float("nan")
            cells.append(f"{change:+.1f} % ({np.mean([d['original'][s] for s in seeds]):.2f} -> "
                         f"{np.mean([d['extended'][s] for s in seeds]):.2f} mm; {vs_linear:+.1f} %)")
        rows.append(cells)
    return markdown_table(["shape term", *(f"set {n}" for n in sets)], rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder with the benchmark's model.npz")
    args = parser.parse_args(argv)
    print("Mean change of the held-out subjects' model-only error, ground-truth meshes of 601-604 added (mean median "
          "mm original -> extended; change against the linear original model):\n")
    print(table(form_ceiling(args.work)))


if __name__ == "__main__":
    main()
