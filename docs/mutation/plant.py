"""Replay mutants planted by hand: the code mutmut does not mutate (decorated functions, the order of statements),
each mutant written into a scratch copy of the tree and the given tests run against it (``pytest -x``); killed or
survived is printed per mutant, then the count. The ``*-plant.py`` scripts beside this file list their mutants and
call :func:`replay` (run them from the repository root)."""

import os
import shutil
import subprocess
import sys


def scratch_tree(work: str, src_root: str | None = None) -> None:
    """``work`` made afresh with a copy of ``bodystudio/``, ``tests/`` and ``pyproject.toml`` of ``src_root``."""
    src_root = os.getcwd() if src_root is None else src_root
    if os.path.exists(work):
        shutil.rmtree(work)
    os.makedirs(work)
    for d in ("bodystudio", "tests"):
        shutil.copytree(os.path.join(src_root, d), os.path.join(work, d), ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(os.path.join(src_root, "pyproject.toml"), work)


def replay(path: str, mutants: list[tuple[str, str, str]], tests: list[str], work: str, *,
           unique: bool = True, pytest_args: tuple[str, ...] = ()) -> int:
    """Each ``(old, new, name)`` of ``mutants`` planted in ``path`` (relative to the tree) of a fresh scratch tree
    ``work`` and ``tests`` run; a clean run first (it must pass). ``unique``: each ``old`` must occur once (else its
    first occurrence is replaced). Returns the number killed; the file is restored at the end."""
    scratch_tree(work)
    target = os.path.join(work, path)
    clean = open(target).read()
    env = {**os.environ, "PYTHONPATH": work, "NUMBA_CACHE_DIR": os.path.join(work, ".numba")}
    killed = 0
    for old, new, name in [("", "", "clean")] + list(mutants):
        if name != "clean":
            assert clean.count(old) == 1 if unique else clean.count(old) >= 1, name
        try:
            with open(target, "w") as f:
                f.write(clean.replace(old, new, 1) if old else clean)
            r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *pytest_args,
                                *tests], cwd=work, capture_output=True, text=True, env=env)
        finally:
            with open(target, "w") as f:
                f.write(clean)
        first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
        killed += bool(r.returncode) and name != "clean"
        print(f"{name}: {'killed' if r.returncode else 'survived'} {first[:150]}", flush=True)
    print(f"{killed} / {len(mutants)} killed")
    return killed
