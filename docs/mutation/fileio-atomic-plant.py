"""Plant bugs in fileio.py's atomic writes by hand in a scratch copy and run their tests (``atomic_path`` and
``atomic_write`` are ``@contextlib.contextmanager`` generators: mutmut gives them no mutant)."""
# usage (from the repository root): python docs/mutation/fileio-atomic-plant.py [TEST ...]
import os
import shutil
import subprocess
import sys

src_root = os.getcwd()
work = "/work/wt-mutBB-work/fileio-atomic-plant"
F = "bodystudio/fileio.py"
FULL_1 = ('        if disk_full(exc):\n            raise OutputSpaceError(path, exc.strerror or "no space left on '
          'device") from None\n        raise\n    os.close(fd)\n')
FULL_2 = ('        if disk_full(exc) and not isinstance(exc, OutputSpaceError):  # one line naming the file, not a '
          'traceback\n            raise OutputSpaceError(path, exc.strerror or "no space left on device") from None\n')
mutants = [
    ("    suffix = path.suffix if suffix is None else suffix\n", '    suffix = "" if suffix is None else suffix\n',
     "default suffix empty (np.savez writes tmp.npz beside)"),
    ("    suffix = path.suffix if suffix is None else suffix\n",
     "    suffix = path.suffix if suffix is not None else suffix\n", "is None -> is not None"),
    ("        path.parent.mkdir(parents=True, exist_ok=True)\n", "        path.parent.mkdir(exist_ok=True)\n",
     "parents dropped"),
    ('prefix=f".{path.stem}."', 'prefix=f"{path.stem}."', "temporary file not hidden (no leading dot)"),
    ("dir=path.parent)", "dir=None)", "temporary file in the system's temp folder"),
    ('suffix=f".tmp{suffix}"', 'suffix=".tmp"', "extension dropped from the temporary name"),
    (FULL_1, FULL_1.replace("        if disk_full(exc):\n", "        if False:\n"), "create: full disk not converted"),
    (FULL_1, FULL_1.replace('exc.strerror or "no space left on device"', "exc.strerror"), "create: no default reason"),
    ("            os.fsync(f.fileno())\n", "            f.flush()\n", "no fsync"),
    ("        os.chmod(tmp, _umask_mode())\n", "        pass\n", "no chmod (mkstemp's 0600 kept)"),
    ("            os.unlink(tmp)\n", "            pass\n", "temporary file left after a failure"),
    (FULL_2, FULL_2.replace(" and not isinstance(exc, OutputSpaceError)", ""),
     "write: another file's full disk re-named after this one"),
    (FULL_2, FULL_2.replace("        if disk_full(exc) and not", "        if False and not"),
     "write: full disk not converted"),
    (FULL_2, FULL_2.replace('exc.strerror or "no space left on device"', "exc.strerror"), "write: no default reason"),
    ("open(tmp, mode) as f:", 'open(tmp, "wb") as f:', "atomic_write's mode ignored"),
    ("        os.replace(tmp, path)\n", "        os.rename(tmp, path)\n", "os.rename (equivalent on POSIX)"),
]
tests = sys.argv[1:] or ["tests/reliability/test_fileio_mutants.py", "tests/test_fileio.py"]
if os.path.exists(work):
    shutil.rmtree(work)
os.makedirs(work)
for d in ("bodystudio", "tests"):
    shutil.copytree(os.path.join(src_root, d), os.path.join(work, d), ignore=shutil.ignore_patterns("__pycache__"))
shutil.copy2(os.path.join(src_root, "pyproject.toml"), work)
clean = open(os.path.join(work, F)).read()
killed = 0
for old, new, name in [(FULL_1, FULL_1, "clean")] + mutants:
    assert clean.count(old) == 1, name
    open(os.path.join(work, F), "w").write(clean.replace(old, new))
    r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests], cwd=work,
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": work})
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    killed += bool(r.returncode) and name != "clean"
    print(f"{name}: {'killed' if r.returncode else 'survived'} {first[:150]}", flush=True)
open(os.path.join(work, F), "w").write(clean)
print(f"{killed} / {len(mutants)} killed")
