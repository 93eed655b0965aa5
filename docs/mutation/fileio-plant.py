"""Plant bugs in fileio.py's atomic writes and its decoder's stderr capture by hand in a scratch copy and run their
tests (``atomic_path``, ``atomic_write`` and ``_native_stderr_captured`` are ``@contextlib.contextmanager``
generators: mutmut gives them no mutant)."""
# usage (from the repository root): python docs/mutation/fileio-plant.py [TEST ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

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
replay(F, mutants, tests, work)
