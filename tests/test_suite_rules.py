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
