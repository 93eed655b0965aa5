"""The planted-bug catalogue of issue 17 (scripts/planted_bugs.py) stays replayable: every bug's anchor is in
its module exactly once and its test selection exists, so a refactor that moves the code fails here instead
of silently dropping the bug from the next replay."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _catalogue():
    spec = importlib.util.spec_from_file_location("planted_bugs", ROOT / "scripts" / "planted_bugs.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


planted = _catalogue()


@pytest.mark.parametrize("bug", planted.BUGS, ids=lambda b: b.id)
def test_each_planted_bug_has_one_anchor_and_tests(bug):
    text = (ROOT / bug.module).read_text()
    assert text.count(bug.old) == 1, f"{bug.id}: anchor found {text.count(bug.old)} times in {bug.module}"
    assert bug.new != bug.old
    files = bug.test_files(ROOT)
    assert files and all((ROOT / f).is_file() for f in files)
    planted_text = text.replace(bug.old, bug.new)
    compile(planted_text, bug.module, "exec")  # the planted module still parses: a failure is the bug's, not syntax


def test_ids_are_unique_and_the_issue_bugs_are_all_there():
    ids = [b.id for b in planted.BUGS]
    assert len(ids) == len(set(ids))
    named = {"sil-k-one", "sil-alpha-tau", "cot-squared", "cot-uniform", "dqs-no-normalise", "dqs-no-antipodal",
             "lbs-dominant-translation", "harmonic-no-fill", "harmonic-compat-flipped", "harmonic-graph-laplacian",
             "ba-no-robust-loss", "kinect-no-grazing", "kinect-no-holes", "bgsub-no-dark-rule", "bgsub-no-hole-fill",
             "bgsub-all-components", "alg1-one-outer-fewer", "alg1-no-solve-cli"}
    assert named <= set(ids)
