"""Re-run mutants of a kept mutmut scratch tree by calling the test functions directly, one fork per mutant.

usage (from the repository root): python docs/mutation/recheck_direct.py WORK TESTMODULE MAP.json < names.txt
WORK is a scratch tree kept by ``scripts/mutate.py --keep``; names are full mutant names (mutmut's meta keys).
The test module (tests/mirror/test_X.py, copied from this tree) is imported once with the clean code; fixtures
``model``, ``mean_body``, ``scene``, ``session`` (the module's ``_session()``), ``monkeypatch``, ``tmp_path``,
``caplog`` are provided, and any other ``@pytest.fixture`` of the test module or its folder's conftest.py
(built once); parametrized tests run every parameter set. Per mutant: fork, MUTANT_UNDER_TEST=<mutant>, the
tests of KMAP[function] (all when absent) in the order of their clean-run time, the first exception (or 120 s
alarm, RECHECK_ALARM_S to change it) = killed, none = survived.
"""
import importlib
import inspect
import itertools
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

work, test_rel, kmap_path = sys.argv[1], sys.argv[2], sys.argv[3]
kmap = json.load(open(kmap_path))
names = [ln.strip() for ln in sys.stdin if ln.strip()]
tree = os.environ.get("BODYSTUDIO_TREE", os.getcwd())
shutil.copy2(os.path.join(tree, test_rel), os.path.join(work, "mutants", test_rel))
os.chdir(os.path.join(work, "mutants"))
sys.path.insert(0, os.getcwd())
sys.path.insert(0, os.path.join(os.getcwd(), "tests", "mirror"))
os.environ["NUMBA_CACHE_DIR"] = os.path.join(work, ".numba-cache")
os.environ["NUMBA_THREADING_LAYER"] = "workqueue"
os.environ["MUTANT_UNDER_TEST"] = ""
import numpy as np  # noqa: E402
from _pytest.logging import LogCaptureFixture  # noqa: E402,F401
from _pytest.monkeypatch import MonkeyPatch  # noqa: E402

mod = importlib.import_module(test_rel[:-3].replace("/", "."))
fixture_values = {}
if hasattr(mod, "_model_2k"):
    fixture_values["model"] = mod._model_2k()
    fixture_values["mean_body"] = fixture_values["model"].body(np.zeros(fixture_values["model"].n_components))
if hasattr(mod, "_scene"):
    fixture_values["scene"] = mod._scene()
if hasattr(mod, "_session"):  # tests/mirror/test_evaluate_mutants.py: the small synthetic mirror session
    fixture_values["session"] = mod._session()


class _Caplog:
    """Enough of pytest's caplog for ``at_level``, ``set_level``, ``records`` and ``text``."""

    def __init__(self):
        import logging

        self.records = []
        outer = self

        class H(logging.Handler):
            def emit(self, record):
                outer.records.append(record)

        self.handler = H()
        logging.getLogger().addHandler(self.handler)

    @property
    def text(self):
        return "\n".join(r.getMessage() for r in self.records)

    def set_level(self, level, logger=None):
        import logging

        logging.getLogger(logger).setLevel(level)  # not undone: each mutant runs in a fork that is thrown away

    def at_level(self, level, logger=None):
        import contextlib
        import logging

        @contextlib.contextmanager
        def cm():
            lg = logging.getLogger(logger)
            old = lg.level
            lg.setLevel(level)
            try:
                yield
            finally:
                lg.setLevel(old)
        return cm()


def cases(fn):
    marks = [m for m in getattr(fn, "pytestmark", []) if m.name == "parametrize"]
    if not marks:
        return [{}]
    out = []
    for combo in itertools.product(*[[(m.args[0], v) for v in m.args[1]] for m in marks]):
        params = {}
        for argnames, value in combo:
            keys = list(argnames) if isinstance(argnames, (tuple, list)) else [a.strip() for a in argnames.split(",")]
            vals = value if len(keys) > 1 else (value,)
            params.update(dict(zip(keys, vals, strict=True)))
        out.append(params)
    return out


def fixture(name):
    """A fixture's value, built once: the ones above, else a ``@pytest.fixture`` of the test module (e.g. ``case``
    of test_pose_refine_analytic.py) or of its folder's conftest.py or tests/conftest.py (called with its own
    fixtures; yield fixtures are not supported)."""
    if name == "tmp_path_factory" and name not in fixture_values:  # e.g. tests/conftest.py's tiny_arm_model_path
        from types import SimpleNamespace

        fixture_values[name] = SimpleNamespace(mktemp=lambda base, numbered=True: Path(tempfile.mkdtemp(prefix=base)))
    if name not in fixture_values:
        defn = getattr(mod, name, None)
        if defn is None:
            conftest = importlib.import_module(test_rel.rsplit("/", 1)[0].replace("/", ".") + ".conftest")
            defn = getattr(conftest, name, None)
            if defn is None:  # a session fixture of tests/conftest.py (e.g. body_2k)
                defn = getattr(importlib.import_module("tests.conftest"), name)
        fn = defn._get_wrapped_function() if hasattr(defn, "_get_wrapped_function") else defn
        fixture_values[name] = fn(**{a: fixture(a) for a in inspect.signature(fn).parameters})
    return fixture_values[name]


def run(fn, params):
    mp = MonkeyPatch()
    try:
        kw = {}
        for p in inspect.signature(fn).parameters:
            if p in params:
                kw[p] = params[p]
            elif p == "monkeypatch":
                kw[p] = mp
            elif p == "tmp_path":
                kw[p] = Path(tempfile.mkdtemp(prefix="direct-"))
            elif p == "caplog":
                kw[p] = _Caplog()
            else:
                kw[p] = fixture(p)
        fn(**kw)
    finally:
        mp.undo()


tests = [(n, f) for n, f in vars(mod).items() if n.startswith("test_") and callable(f)
         and not any(m.name == "slow" for m in getattr(f, "pytestmark", []))]
durations = {}
for n, f in tests:
    t = time.perf_counter()
    for params in cases(f):
        run(f, params)
    durations[n] = time.perf_counter() - t
print("clean run: ok", {k: round(v, 2) for k, v in sorted(durations.items(), key=lambda kv: kv[1])}, flush=True)
tests.sort(key=lambda nf: durations[nf[0]])


def func_of(name):
    if ".x_" in name:
        return name.split(".x_", 1)[1].rsplit("__mutmut", 1)[0]
    return name.split("x\u01c1", 1)[-1].rsplit("__mutmut", 1)[0].replace("\u01c1", ".")


counts = {}
for name in names:
    words = kmap.get(func_of(name))
    chosen = [(n, f) for n, f in tests if words is None or any(w in n for w in words.split(" or "))]
    pid = os.fork()
    if pid == 0:
        os.environ["MUTANT_UNDER_TEST"] = name
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        signal.alarm(int(os.environ.get("RECHECK_ALARM_S", "120")))  # a shorter box for loops on a real clock
        code = 0
        try:
            for _n, f in chosen:
                for params in cases(f):
                    run(f, params)
        except BaseException:
            code = 1
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    code = os.waitstatus_to_exitcode(status)
    res = "survived" if code == 0 else "killed"
    counts[res] = counts.get(res, 0) + 1
    print(name, res, code, len(chosen), flush=True)
print(json.dumps(counts))
