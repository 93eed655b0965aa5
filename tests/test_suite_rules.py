"""Rules the test suite keeps about itself (issue 17): our own modules are imported, never skipped."""

import re
from pathlib import Path

TESTS = Path(__file__).parent


def test_no_importorskip_of_bodystudio_modules():
    """``pytest.importorskip("bodystudio...")`` turns an import error in our code into a silent skip; only
    outside tools may be skipped when missing."""
    pattern = re.compile(r"importorskip\(\s*[\"']bodystudio")
    offenders = [f"{p.relative_to(TESTS)}:{i}" for p in TESTS.rglob("*.py") if p != Path(__file__)
                 for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not offenders, f"import our modules directly instead: {offenders}"


def test_every_bench_module_has_the_runner_interface():
    """`make bench` (benchmarks/run.py) imports every benchmarks/bench_*.py and calls run(quick=...); a script
    without it would put a FAILED section into docs/BENCHMARKS.md and fail `make bench`. One-off scripts take
    another name (e.g. benchmarks/mirror_pose_oracle.py)."""
    import ast
    from pathlib import Path

    missing = []
    for path in sorted((Path(__file__).parents[1] / "benchmarks").glob("bench_*.py")):
        tree = ast.parse(path.read_text())
        runs = [f for f in tree.body if isinstance(f, ast.FunctionDef) and f.name == "run"]
        if not runs or "quick" not in [a.arg for a in runs[0].args.args + runs[0].args.kwonlyargs]:
            missing.append(path.name)
    assert missing == [], f"bench modules without run(quick=...): {missing}"


def test_test_files_outside_packages_have_unique_names():
    """pytest imports a test file in a folder without ``__init__.py`` under its bare name, so two such files of
    one name (tests/garment/test_x.py and tests/mirror/test_x.py) stop the whole run at collection ("import
    file mismatch"); a file in a package folder (tests/muscle/) is named after its package and may repeat."""
    seen: dict[str, list[str]] = {}
    for path in TESTS.rglob("test_*.py"):
        if not (path.parent / "__init__.py").exists():
            seen.setdefault(path.name, []).append(str(path.relative_to(TESTS)))
    clashes = {name: paths for name, paths in seen.items() if len(paths) > 1}
    assert not clashes, f"rename one of each (e.g. test_<stage>_...): {clashes}"

def _test_shards_module():
    import importlib.util

    path = Path(__file__).parents[1] / "scripts" / "test_shards.py"
    spec = importlib.util.spec_from_file_location("test_shards", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_sharded_run_exit_status():
    """`make test`'s status: the first failing shard's; a shard with nothing to run (5) is not a failure
    unless no shard ran anything."""
    code = _test_shards_module().shard_exit_code
    assert code([0, 0]) == 0 and code([0, 5]) == 0 and code([5, 5]) == 5
    assert code([0, 1]) == 1 and code([2, 1]) == 2 and code([5, 1]) == 1


def test_sharded_run_ends_naming_the_failed_tests(tmp_path):
    """A failing test in an early shard was followed by the later shards' logs, so `make test` ended on another
    shard's "N passed" line (exit status 1). The last line now gives the status and names the failed tests
    (once, though every shard collects them); a passing run says so."""
    import subprocess
    import sys

    root = Path(__file__).parents[1]
    (tmp_path / "test_planted.py").write_text("def test_fine():\n    pass\n\n\ndef test_planted():\n"
                                              "    assert 1 == 2\n")
    proc = subprocess.run([sys.executable, "scripts/test_shards.py", "--jobs", "2", "--", "-q", "-p",
                           "no:cacheprovider", "--rootdir", str(tmp_path), str(tmp_path / "test_planted.py")],
                          cwd=root, capture_output=True, text=True, timeout=600)
    last = proc.stdout.strip().splitlines()[-1]
    assert proc.returncode == 1, proc.stdout[-2000:]
    assert last.startswith("=== test shards: exit 1 (shard 0 exit 1") and last.endswith("::test_planted"), last
    assert last.count("test_planted") == 2 and "test_fine" not in last, last  # the file and the test, once
    line = _test_shards_module().closing_line
    assert line([0, 5], []) == "=== test shards: exit 0, every shard passed"
    assert line([5, 1], []).endswith("(shard 1 exit 1): FAILED see the shard logs above")


def test_sharded_run_runs_every_test_once_each_file_in_one_process():
    """scripts/test_shards.py --jobs 2 (`make test`): the two pytest processes share the test files; every
    test runs exactly once and all tests of a file run in the same process (its module fixtures are built
    once)."""
    import subprocess
    import sys

    root = Path(__file__).parents[1]
    files = ["tests/body/test_skinning.py", "tests/capture/test_session_bodies.py", "tests/geometry/test_laplacian.py"]
    proc = subprocess.run([sys.executable, "scripts/test_shards.py", "--jobs", "2", "--", "-q", "-rA",
                           "-p", "no:cacheprovider", *files], cwd=root, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    shard0, shard1 = proc.stdout.split("=== test shard 0/2")
    ran = [line.split()[1] for out in (shard0, shard1) for line in out.splitlines() if line.startswith("PASSED ")]
    collected = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                                *files], cwd=root, capture_output=True, text=True, timeout=600).stdout.split()
    assert sorted(ran) == sorted(n for n in collected if "::" in n), proc.stdout[-3000:]
    for name in files:
        where = {i for i, out in enumerate((shard0, shard1)) if f"PASSED {name}::" in out}
        assert len(where) == 1, (name, where)
