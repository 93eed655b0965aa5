"""``benchmarks.bench_muscle --step extension``: ``--extension-per-group`` and ``--extension-centre`` (fifth pass),
``--extension-subject-rows`` (tenth)."""

import pytest

from benchmarks.bench_muscle import (
    CHECK_SETS,
    EXTENSION_GROUP_SEEDS,
    HELD_OUT_SETS,
    IN_RANGE_SEED,
    OUT_OF_RANGE,
    extension_seeds,
    held_out_group,
    main,
)


def test_per_group_takes_the_first_seeds_of_every_group():
    one = extension_seeds(1)
    assert [s for s, _ in one] == [601, 602, 603, 604]
    two = extension_seeds(2)
    assert len(two) == 8 and [lab for _, lab in two] == [lab for lab in OUT_OF_RANGE for _ in range(2)]
    assert {s for s, _ in extension_seeds(4)} == {s for g in EXTENSION_GROUP_SEEDS for s in g}
    held = {611, 612, 613, 614, 631, 632, 633, 634, 620}
    assert not held & {s for g in EXTENSION_GROUP_SEEDS for s in g}  # captured and held-out subjects disjoint
    with pytest.raises(ValueError, match="per_group"):
        extension_seeds(5)


def test_set_d_is_five_new_subjects_per_group_that_no_other_set_uses():
    d = CHECK_SETS[0][1]
    assert len(d) == 20 and [held_out_group(s) for s in d] == list(OUT_OF_RANGE) * 5
    # A, B, the captured groups (C's out-of-range subjects among them), the eleventh pass's second added set, C's men
    others = {IN_RANGE_SEED, *(s for _, seeds in HELD_OUT_SETS for s in seeds),
              *(s for g in EXTENSION_GROUP_SEEDS for s in g), *range(671, 675), *range(621, 626)}
    assert not others & set(d)
    assert [held_out_group(s) for _, seeds in HELD_OUT_SETS for s in seeds] == list(OUT_OF_RANGE) * 2
    for bad in (620, 715):
        with pytest.raises(ValueError, match=f"held-out seed {bad}: its last digit must be 1-4"):
            held_out_group(bad)


@pytest.mark.parametrize("argv", [["--extension-per-group", "0"], ["--extension-per-group", "5"],
                                  ["--extension-per-group", "two"], ["--extension-centre", "elbow"],
                                  ["--extension-captured-rest", "skin"], ["--extension-subject-rows", "each"]])
def test_bad_extension_options_exit_2_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--step", "extension", "--work", str(tmp_path / "w"), *argv])
    assert exc.value.code == 2
    assert "--extension-" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
