"""Run the test suite as N pytest processes side by side, one shard of the test files each (`make test`).

pytest runs one test at a time on one core; the CI machine has two. Each shard is a plain
``python -m pytest ARGS`` with ``BODYSTUDIO_TEST_CLAIMS`` naming a shared folder: every shard collects the
same tests, and tests/conftest.py's run loop then takes the next test file no other shard has claimed,
longest first by its measured seconds (tests/shard_weights.json), until none is left. So every test runs
once, unchanged, with its module's fixtures in one process; only session fixtures may be built once per
shard. Shard 0 prints as it runs; the others print their whole log when they end. The exit status is the
first failing shard's (5, "no tests collected", only when no shard ran a test); the last line says it and names
the failed tests.

    python scripts/test_shards.py --jobs 2 -- -q --durations=25
    python scripts/test_shards.py --jobs 2 --write-weights tests/shard_weights.json -- -q   # refresh the table

--jobs 1 runs pytest directly, as before.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

NO_TESTS = 5  # pytest.ExitCode.NO_TESTS_COLLECTED


def shard_exit_code(codes: list[int]) -> int:
    """One exit status for the shards: the first failure, 0 when every shard passed or had nothing to run."""
    failed = [c for c in codes if c not in (0, NO_TESTS)]
    if failed:
        return failed[0]
    return NO_TESTS if all(c == NO_TESTS for c in codes) else 0


def file_seconds(junit_paths: list[Path]) -> dict[str, float]:
    """Seconds per test file (setup + call + teardown of its tests) from pytest's JUnit XML reports."""
    seconds: dict[str, float] = {}
    for path in junit_paths:
        if not path.is_file():
            continue
        for case in ET.parse(path).getroot().iter("testcase"):
            module = case.get("classname", "").split(".")
            # classname is the module path (tests.garment.test_fit), plus the class for tests in a class
            while module and not module[-1].startswith("test_"):
                module.pop()
            if module:
                name = "/".join(module) + ".py"
                seconds[name] = seconds.get(name, 0.0) + float(case.get("time", 0.0))
    return seconds


def failed_tests(junit_paths: list[Path]) -> list[str]:
    """Test ids (``tests/x/test_y.py::[Class::]test_z``) with a failure or an error in pytest's JUnit XML reports."""
    out = []
    for path in junit_paths:
        if not path.is_file():
            continue
        for case in ET.parse(path).getroot().iter("testcase"):
            if case.find("failure") is None and case.find("error") is None:
                continue
            if not case.get("classname"):  # a collection error: the name is the module's dotted path
                name = case.get("name", "?").replace(".", "/") + ".py (collection error)"
            else:
                parts = case.get("classname").split(".")
                i = max((k for k, part in enumerate(parts) if part.startswith("test_")), default=len(parts) - 1)
                name = "/".join(parts[:i + 1]) + ".py::" + "::".join([*parts[i + 1:], case.get("name", "?")])
            if name not in out:  # every shard collects, so each reports the same collection error
                out.append(name)
    return out


def closing_line(codes: list[int], failed: list[str]) -> str:
    """The last line of a sharded run: shard 0 prints first and the others' logs after it, so a failure in an
    early shard was followed by another shard's "N passed" as the run's last words (exit status non-zero)."""
    code = shard_exit_code(codes)
    head = f"=== test shards: exit {code}"
    if code in (0, NO_TESTS):
        return head + (", every shard passed" if code == 0 else ", no tests ran")
    bad = ", ".join(f"shard {i} exit {c}" for i, c in enumerate(codes) if c not in (0, NO_TESTS))
    names = "; ".join(failed[:10]) + (f" and {len(failed) - 10} more" if len(failed) > 10 else "")
    return f"{head} ({bad}): FAILED {names or 'see the shard logs above'}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--jobs", type=int, default=2, help="pytest processes side by side (1: plain pytest)")
    parser.add_argument("--write-weights", type=Path, help="after the run, write the seconds per test file here")
    parser.add_argument("pytest_args", nargs="*", help="arguments for pytest (after --)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")
    command = [sys.executable, "-m", "pytest", *args.pytest_args]
    with tempfile.TemporaryDirectory(prefix="bodystudio-shards-") as tmp:
        junit = [Path(tmp) / f"shard-{i}.xml" for i in range(args.jobs)]
        (Path(tmp) / "claims").mkdir()
        # the reports give the weights and, with several shards, the failed tests of the closing line
        own_junit = any(a.startswith(("--junitxml", "--junit-xml")) for a in args.pytest_args)
        wanted = args.write_weights or (args.jobs > 1 and not own_junit)
        extra = (lambda i: [f"--junitxml={junit[i]}"]) if wanted else (lambda i: [])
        if args.jobs == 1:
            code = subprocess.call([*command, *extra(0)])
        else:
            codes = _run_shards(command, args.jobs, Path(tmp), extra)
            code = shard_exit_code(codes)
            print(closing_line(codes, failed_tests(junit) if wanted else []), flush=True)
        if args.write_weights and code == 0:
            seconds = file_seconds(junit)
            args.write_weights.write_text(json.dumps({k: round(v, 1) for k, v in sorted(seconds.items())},
                                                     indent=1) + "\n")
            print(f"wrote {args.write_weights} ({len(seconds)} test files)")
    return code


def _run_shards(command: list[str], jobs: int, tmp: Path, extra) -> list[int]:
    procs, logs, started = [], [], time.monotonic()
    try:
        for i in range(jobs):
            env = dict(os.environ, BODYSTUDIO_TEST_CLAIMS=str(tmp / "claims"))
            if i == 0:
                log = None
                procs.append(subprocess.Popen([*command, *extra(i)], env=env))
            else:
                log = open(tmp / f"shard-{i}.log", "w+b")  # noqa: SIM115 - closed below
                procs.append(subprocess.Popen([*command, *extra(i)], env=env, stdout=log, stderr=subprocess.STDOUT))
            logs.append(log)
        codes = []
        for i, (proc, log) in enumerate(zip(procs, logs, strict=True)):
            codes.append(proc.wait())
            print(f"=== test shard {i}/{jobs}: exit {codes[-1]}, {time.monotonic() - started:.0f} s since start",
                  flush=True)
            if log is not None:
                log.seek(0)
                sys.stdout.buffer.write(log.read())
                sys.stdout.flush()
                log.close()
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return codes


if __name__ == "__main__":
    sys.exit(main())
