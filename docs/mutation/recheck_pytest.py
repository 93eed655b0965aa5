"""Re-run named mutants of a kept mutmut scratch tree with plain pytest, one process per mutant (mutKK).

usage (from the repository root): python docs/mutation/recheck_pytest.py WORK TEST.py < names.txt > LOG
For tests that need pytest's function-scoped fixtures (monkeypatch spies, tmp_path per test), which
recheck_direct.py builds once. TEST.py is copied from this tree into WORK/mutants first. Prints
``<mutant> killed|survived`` per line, the format of recheck_setmeta.py.
"""
import os
import shutil
import subprocess
import sys

work, test_rel = sys.argv[1], sys.argv[2]
mutants = os.path.join(work, "mutants")
shutil.copy2(test_rel, os.path.join(mutants, test_rel))
env = dict(os.environ, PYTHONPATH=mutants)
clean = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", test_rel],
                       cwd=mutants, env=dict(env, MUTANT_UNDER_TEST=""), capture_output=True, text=True)
if clean.returncode != 0:
    sys.exit(f"clean run fails:\n{clean.stdout[-2000:]}")
for name in (ln.strip() for ln in sys.stdin if ln.strip()):
    r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", test_rel], cwd=mutants,
                       env=dict(env, MUTANT_UNDER_TEST=name), capture_output=True, text=True)
    first = next((ln for ln in r.stdout.splitlines() if ln.startswith("FAILED")), "")
    print(name, "killed" if r.returncode != 0 else "survived", first, flush=True)
