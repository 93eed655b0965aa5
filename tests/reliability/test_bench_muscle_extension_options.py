"""``benchmarks.bench_muscle --step extension``: ``--extension-per-group`` and ``--extension-centre`` (fifth pass),
``--extension-subject-rows`` (tenth)."""

import pytest

from benchmarks.bench_muscle import EXTENSION_GROUP_SEEDS, OUT_OF_RANGE, extension_seeds, main


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


@pytest.mark.parametrize("argv", [["--extension-per-group", "0"], ["--extension-per-group", "5"],
                                  ["--extension-per-group", "two"], ["--extension-centre", "elbow"],
                                  ["--extension-captured-rest", "skin"], ["--extension-subject-rows", "each"]])
def test_bad_extension_options_exit_2_before_any_work(argv, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--step", "extension", "--work", str(tmp_path / "w"), *argv])
    assert exc.value.code == 2
    assert "--extension-" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
