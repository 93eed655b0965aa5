"""scripts/mutate.py's resume logic and its refusal to write a run that measured nothing (issue 17's tooling).

The bug of the last round: ``--resume TREE --functions F`` on a kept tree whose mutmut run ended before it wrote the
module's ``.meta`` (the box ended while mutants were generated) asked mutmut for no mutant, scored nothing and
crashed in the report (``None`` formatted as a percentage) after results.json had been overwritten with the empty
entry. No mutmut run here: the functions are called on a hand-made tree.
"""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
import mutate  # noqa: E402

MODULE = "bodystudio/muscle/normal_equations.py"
GLOBS = ["bodystudio.muscle.normal_equations.x_spd_solve__mutmut_*"]


def _tree(tmp_path, codes=None):
    (tmp_path / "mutants" / "bodystudio" / "muscle").mkdir(parents=True)
    if codes is not None:
        (tmp_path / "mutants" / (MODULE + ".meta")).write_text(json.dumps({"exit_code_by_key": codes}))
    return tmp_path


def test_resume_without_the_modules_meta_runs_the_functions_globs(tmp_path):
    """No ``.meta`` of the module yet: mutmut is handed the functions' globs (it generates and runs them), not an empty
    list (which ran nothing); another module's ``.meta`` in the tree does not count."""
    work = _tree(tmp_path)
    (work / "mutants" / "bodystudio" / "other.py.meta").write_text(
        json.dumps({"exit_code_by_key": {"bodystudio.other.x_f__mutmut_1": None}}))
    assert mutate._to_run(work, MODULE, ["spd_solve"], resuming=True) == GLOBS
    assert mutate._to_run(work, MODULE, ["spd_solve"], resuming=False) == GLOBS
    assert mutate._to_run(work, MODULE, None, resuming=True) == []


def test_resume_with_the_meta_runs_only_the_functions_mutants_without_a_result(tmp_path):
    name = "bodystudio.muscle.normal_equations.x_spd_solve__mutmut_{}".format
    codes = {name(1): None, name(2): 1, name(3): 0, name(10): None,
             "bodystudio.muscle.normal_equations.x_normal_matrix__mutmut_1": None}
    work = _tree(tmp_path, codes)
    assert mutate._to_run(work, MODULE, ["spd_solve"], resuming=True) == [name(1), name(10)]
    done = _tree(tmp_path / "done", {name(1): 1})
    assert mutate._to_run(done, MODULE, ["spd_solve"], resuming=True) == []


@pytest.fixture
def report(tmp_path, monkeypatch):
    """results.json with one measured entry and a MUTATION.md, both in tmp_path."""
    results = tmp_path / "results.json"
    entry = {"module": MODULE, "commit": "abc", "tests": ["t.py"], "counts": {"killed": 3, "survived": 1},
             "killed": 3, "total": 4, "score": 0.75, "wall_s": 5.0, "timed_out": False, "survivors": [],
             "functions": ["spd_solve"], "history": [{"date": "2026-11-27", "commit": "abc", "score": 0.75}]}
    results.write_text(json.dumps({f"{MODULE} (functions)": entry}))
    (tmp_path / "MUTATION.md").write_text(f"# M\n\n{mutate.BEGIN}\n{mutate.END}\n")
    monkeypatch.setattr(mutate, "RESULTS", results)
    monkeypatch.setattr(mutate, "REPORT", tmp_path / "MUTATION.md")
    return results, entry


def test_a_run_that_measured_nothing_exits_non_zero_and_keeps_the_entry(report, tmp_path, monkeypatch, capsys):
    results, entry = report
    work = _tree(tmp_path / "kept")
    monkeypatch.setattr(mutate, "run_module", lambda *a, **k: {
        "module": MODULE, "tests": ["t.py"], "wall_s": 1.0, "error": f"no mutant of {MODULE} has a result"})
    rc = mutate.main(["--modules", MODULE, "--functions", "spd_solve", "--resume", str(work), "--score-only"])
    assert rc == 1
    assert "no mutant of" in capsys.readouterr().err
    assert json.loads(results.read_text()) == {f"{MODULE} (functions)": entry}


def test_an_error_entry_renders_and_a_measured_run_appends_its_history(report, tmp_path, monkeypatch):
    results, entry = report
    work = _tree(tmp_path / "kept")
    measured = dict(entry, killed=4, score=1.0, counts={"killed": 4}, commit="def")
    measured.pop("history")
    monkeypatch.setattr(mutate, "run_module", lambda *a, **k: dict(measured))
    assert mutate.main(["--modules", MODULE, "--functions", "spd_solve", "--resume", str(work), "--score-only"]) == 0
    got = json.loads(results.read_text())[f"{MODULE} (functions)"]
    assert [h["score"] for h in got["history"]] == [0.75, 1.0]
    assert got["wall_s"] == 10.0  # both boxes
    text = mutate.render({"a.py": {"module": "a.py", "error": "no tests found"}, f"{MODULE} (functions)": got})
    assert "| `a.py` | no tests found |" in text and "**100.0%** (4 / 4)" in text


def test_a_key_of_its_own_leaves_the_shared_functions_entry_alone(report, tmp_path, monkeypatch):
    results, entry = report
    work = _tree(tmp_path / "kept")
    monkeypatch.setattr(mutate, "run_module", lambda *a, **k: dict(entry, history=None, score=0.5, killed=2))
    key = f"{MODULE} (mutR lines)"
    assert mutate.main(["--modules", MODULE, "--functions", "spd_solve", "--resume", str(work), "--score-only",
                        "--key", key]) == 0
    got = json.loads(results.read_text())
    assert got[f"{MODULE} (functions)"] == entry and got[key]["score"] == 0.5
    assert mutate.main(["--modules", MODULE, "bodystudio/muscle/model.py", "--key", key]) == 2


def test_the_test_files_of_a_top_level_module_are_found():
    """``tests_for`` of a module at the package's top (``bodystudio/fileio.py``) looks in tests/ itself (it looked
    for tests/fileio/, which does not exist, and handed mutmut nothing but EXTRA_TESTS); runfolder's six files."""
    root = Path(__file__).resolve().parent.parent
    fileio = mutate.tests_for("bodystudio/fileio.py", root)
    assert "tests/test_fileio.py" in fileio and "tests/reliability/test_fileio_mutants.py" in fileio
    runfolder = mutate.tests_for("bodystudio/runfolder.py", root)
    assert len(runfolder) == 6 and "tests/reliability/test_process_alive_mutants.py" in runfolder
    assert mutate.tests_for("bodystudio/mirror/refine.py", root)[0].startswith("tests/mirror/test_")
