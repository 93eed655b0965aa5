"""Plant bugs by hand in a scratch copy of runfolder.py and run its tests: in ``command_read_locks`` (a
``@contextlib.contextmanager`` generator: mutmut gives it no mutant) and in the commit's order of steps (mutmut does
not move statements)."""
# usage (from the repository root): python docs/mutation/runfolder-plant.py [TEST ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

work = "/work/wt-mutBB-work/runfolder-plant"
F = "bodystudio/runfolder.py"
BODY = ("    previous = _HOLDING[0]\n    _HOLDING[0] = True\n    try:\n        yield\n    finally:\n"
        "        _HOLDING[0] = previous\n        if not previous:\n            release_read_locks()\n")
SRC = open(os.path.join(os.getcwd(), F)).read()
END = SRC.index("    remove_staging(layout)\n\n")
MANIFEST = SRC[SRC.index('    if plan.get("manifest") is not None:\n        data'):END]
RECORD = SRC[SRC.index("        with atomic_write(self.layout.commit_record"):
             SRC.index("        apply_commit(self.layout, plan)\n")]
LOOP = '    for move in plan["moves"]:\n        staged_rel'
BODY_COMMIT = SRC[SRC.index(LOOP):END]  # moves, deletes, manifest
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
    (MANIFEST + "    remove_staging(layout)\n", "    remove_staging(layout)\n" + MANIFEST,
     "order: the staging removed before the manifest is written"),
    (BODY_COMMIT, MANIFEST + BODY_COMMIT.replace(MANIFEST, ""), "order: the manifest written before the moves"),
    ("    for key in plan.get(\"deletes\", []):\n        resolve(layout, key).unlink(missing_ok=True)\n" + MANIFEST,
     MANIFEST + "    for key in plan.get(\"deletes\", []):\n        resolve(layout, key).unlink(missing_ok=True)\n",
     "order: the deletes after the manifest"),
    (RECORD + "        apply_commit(self.layout, plan)\n", "        apply_commit(self.layout, plan)\n" + RECORD,
     "order: the commit record written after the commit"),
    ("        apply_commit(self.layout, plan)\n        self.committed = True\n        release_lock(self.layout)\n",
     "        release_lock(self.layout)\n        apply_commit(self.layout, plan)\n        self.committed = True\n",
     "order: the lock released before the commit is carried out"),
]
tests = sys.argv[1:] or ["tests/reliability/test_runfolder_mutants.py",
                         "tests/reliability/test_runfolder_staging_mutants.py"]
replay(F, mutants, tests, work)
