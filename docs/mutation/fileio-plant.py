"""Plant bugs in fileio.py's atomic writes and its decoder's stderr capture by hand in a scratch copy and run their
tests (``atomic_path``, ``atomic_write`` and ``_native_stderr_captured`` are ``@contextlib.contextmanager``
generators: mutmut gives them no mutant)."""
# usage (from the repository root): python docs/mutation/fileio-plant.py [TEST ...]
import os
import shutil
import subprocess
import sys

src_root = os.getcwd()
work = "/work/wt-mutBB-work/fileio-plant"
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
    # _native_stderr_captured
    ("            os.ftruncate(fd, 0)\n", "            pass\n", "capture: file not emptied"),
    ("            os.lseek(fd, 0, os.SEEK_SET)\n            os.dup2(fd, 2)\n", "            os.dup2(fd, 2)\n",
     "capture: not rewound before (a hole of NULs before the lines)"),
    ("            os.dup2(fd, 2)\n", "            pass\n", "capture: fd 2 never redirected"),
    ("                os.dup2(saved, 2)\n", "                pass\n", "capture: fd 2 never restored"),
    ("                os.lseek(fd, 0, os.SEEK_SET)\n                chunks = []\n", "                chunks = []\n",
     "capture: not rewound before reading"),
    ("                    chunk = os.read(fd, size)\n", "                    chunk = os.read(fd, 1)\n",
     "capture: read a byte at a time (equivalent: perf)"),
    ('.decode("utf-8", "replace")', '.decode("utf-8")', "capture: strict UTF-8"),
    ('                out.append(b"".join(chunks).decode("utf-8", "replace"))\n', "                pass\n",
     "capture: nothing handed back"),
    ("            os.close(saved)\n", "            pass\n", "capture: the saved fd leaks"),
    ("    with _stderr_lock:\n", "    with contextlib.nullcontext():\n", "capture: no lock between threads"),
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
