"""pymeshlab, imported by the process's main thread only (its Qt plugins corrupt the heap otherwise).

``import pymeshlab`` loads MeshLab's filter plugins through Qt (``PluginManager::loadPlugins``), and Qt files
every object it creates under the importing thread's ``QThreadData``. When that thread ends before the
process, the plugin objects are the data's last references; at process exit MeshLab's static
``PluginManager`` destructor unloads them, one ``~QObject`` frees the data while the others still point to
it, and the next one dereferences it again (valgrind: "Invalid read of size 4 at QThreadData::deref() ... by
~QPluginLoader() ... by PluginManager::~PluginManager() ... by __run_exit_handlers; block free'd by
~QObjectPrivate ... by PluginManager::~PluginManager()"). The decrement writes into freed memory: glibc
then aborts the exiting process with ``malloc_consolidate(): unaligned fastbin chunk detected`` or
``corrupted double-linked list``, or, worse, the memory has been reused and something else is silently
overwritten.

A dask worker runs its tasks in a thread pool thread that ends when the worker closes, so the first import
must happen in the worker's main thread: :mod:`bodystudio.batch` does it in a worker plugin at start-up.
:func:`import_pymeshlab` refuses a first import from any other thread, so the hazard cannot come back
unnoticed.
"""

from __future__ import annotations

import sys
import threading


def import_pymeshlab():
    """The ``pymeshlab`` module; its first import must come from the main thread (see the module docstring)."""
    module = sys.modules.get("pymeshlab")
    if module is not None:
        return module
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError(f"pymeshlab imported first by thread {threading.current_thread().name!r}, not the main "
                           "thread: its Qt plugins would corrupt the heap at exit (bodystudio.geometry.meshlab); "
                           "import it in the main thread first (a dask worker: bodystudio.batch's worker plugin)")
    import pymeshlab

    return pymeshlab
