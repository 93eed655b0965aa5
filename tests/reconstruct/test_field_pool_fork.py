"""SilhouetteFields' transform pool across a fork (mutN): a child forked after the parent built fields on two
threads builds its own, the same arrays, instead of waiting on the parent's pool, whose threads it has not."""

import os
import signal

import numba
import numpy as np
import pytest

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct import tracking
from bodystudio.reconstruct.tracking import SilhouetteFields


@pytest.mark.skipif(not hasattr(os, "fork") or numba.config.NUMBA_NUM_THREADS < 2, reason="needs fork, 2 threads")
def test_fields_built_in_a_forked_child_do_not_wait_on_the_parents_pool():
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=300.0, width=80, height=60)
            for i, a in enumerate((0.0, 1.5, 3.0))]
    masks = {c.name: np.zeros((60, 80), bool) for c in cams}
    for k, c in enumerate(cams):
        masks[c.name][20:40, 30 + k:50] = True
    before = numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        parent = SilhouetteFields(cams, masks, exact=False)
        assert tracking._FIELD_POOLS  # the parent's pool exists, with its threads
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                signal.alarm(20)
                child = SilhouetteFields(cams, masks, exact=False)
                code = 0 if np.array_equal(child._packed_sdf, parent._packed_sdf) else 2
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
    finally:
        numba.set_num_threads(before)
    assert os.waitstatus_to_exitcode(status) == 0  # -14 (SIGALRM): the child waited on a pool with no thread
