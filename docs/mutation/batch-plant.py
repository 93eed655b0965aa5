"""Plant bugs by hand in a scratch copy of batch.py and run its tests: in ``batch_client`` (a
``@contextlib.contextmanager`` generator: mutmut gives it no mutant) and the module constants the client uses."""
# usage (from the repository root): python docs/mutation/batch-plant.py [TEST ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

work = "/work/wt-mutFF-work/batch-plant"
F = "bodystudio/batch.py"
mutants = [
    ("        if units is not None:\n            n = max(1, min(n, int(units)))\n", "",
     "no cap at the batch's units"),
    ("n = max(1, min(n, int(units)))", "n = max(1, max(n, int(units)))", "cap: min -> max"),
    ("n = max(1, min(n, int(units)))", "n = min(n, int(units))", "no floor of one worker"),
    ("n = workers or os.cpu_count() or 1", "n = os.cpu_count() or 1", "--workers ignored"),
    ("threads_per_worker=1, processes=True", "threads_per_worker=2, processes=True", "two threads per worker"),
    ("threads_per_worker=1, processes=True", "threads_per_worker=1, processes=False", "threads, not processes"),
    ("env=dict(WORKER_ENV)", "env=None", "thread pools not pinned"),
    ('dashboard_address=":0"', 'dashboard_address=":8787"', "a fixed dashboard port"),
    ("        client.register_plugin(_exit_with_client_plugin())\n", "", "workers outlive a killed client"),
    ("        check_worker_versions(client.run(_worker_version))\n", "", "worker versions not checked"),
    ("        client.register_plugin(_main_thread_imports_plugin())\n", "", "no main-thread imports"),
    ("        client.close()\n        if cluster is not None:", "        if cluster is not None:",
     "client not closed"),
    ("        if cluster is not None:\n            cluster.close()\n", "", "cluster not closed"),
    ("    try:\n        check_worker_versions(client.run(_worker_version))\n        client.register_plugin("
     "_main_thread_imports_plugin())\n        yield client\n    finally:\n",
     "    if True:\n        check_worker_versions(client.run(_worker_version))\n        client.register_plugin("
     "_main_thread_imports_plugin())\n        yield client\n    if True:\n", "not closed on an error"),
    ('timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False', 'timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=True',
     "the client made the default"),
    ("CONNECT_TIMEOUT_S = 5.0", "CONNECT_TIMEOUT_S = 60.0", "a minute to fail on an unreachable scheduler"),
    ("reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__", "reason = str(exc)",
     "the whole multi-line error in the one line"),
    ("    for name in (\"distributed\", \"distributed.http.proxy\"):\n        logging.getLogger(name)"
     ".setLevel(logging.WARNING)\n", "", "distributed's INFO lines in the output"),
    ('"OMP_NUM_THREADS": "1"', '"OMP_NUM_THREADS": "2"', "OpenMP not pinned"),
]
tests = sys.argv[1:] or ["tests/batch/test_batch_units_mutants.py"]
replay(F, mutants, tests, work, unique=False)
