"""Plant bugs in runfolder.py's ``command_read_locks`` (a ``@contextlib.contextmanager`` generator: mutmut gives it no
mutant) by hand in a scratch copy and run the read-lock tests."""
# usage (from the repository root): python docs/mutation/runfolder-plant.py [TEST ...]
import os
import shutil
import subprocess
import sys

src_root = os.getcwd()
work = "/work/wt-mutBB-work/runfolder-plant"
F = "bodystudio/runfolder.py"
BODY = ("    previous = _HOLDING[0]\n    _HOLDING[0] = True\n    try:\n        yield\n    finally:\n"
        "        _HOLDING[0] = previous\n        if not previous:\n            release_read_locks()\n")
mutants = [
    (BODY, BODY.replace("    _HOLDING[0] = True\n", "    _HOLDING[0] = False\n"), "readers never register"),
    (BODY, BODY.replace("    previous = _HOLDING[0]\n", "    previous = False\n"),
     "nested command forgets the outer one"),
    (BODY, BODY.replace("        _HOLDING[0] = previous\n", "        pass\n"), "holding never switched off"),
    (BODY, BODY.replace("        if not previous:\n", "        if True:\n"),
     "a nested command releases the outer locks"),
    (BODY, BODY.replace("        if not previous:\n            release_read_locks()\n", "        pass\n"),
     "locks never released at the end"),
    (BODY, BODY.replace("    try:\n        yield\n    finally:\n", "    yield\n    if True:\n"),
     "not released when the command fails"),
]
tests = sys.argv[1:] or ["tests/reliability/test_runfolder_mutants.py",
                         "tests/reliability/test_runfolder_staging_mutants.py"]
if os.path.exists(work):
    shutil.rmtree(work)
os.makedirs(work)
for d in ("bodystudio", "tests"):
    shutil.copytree(os.path.join(src_root, d), os.path.join(work, d), ignore=shutil.ignore_patterns("__pycache__"))
shutil.copy2(os.path.join(src_root, "pyproject.toml"), work)
clean = open(os.path.join(work, F)).read()
killed = 0
for old, new, name in [(BODY, BODY, "clean")] + mutants:
    assert clean.count(old) == 1, name
    open(os.path.join(work, F), "w").write(clean.replace(old, new))
    r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests], cwd=work,
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": work})
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    killed += bool(r.returncode) and name != "clean"
    print(f"{name}: {'killed' if r.returncode else 'survived'} {first[:150]}", flush=True)
open(os.path.join(work, F), "w").write(clean)
print(f"{killed} / {len(mutants)} killed")
