"""``OMP_WAIT_POLICY`` set by the user (adversarial pass 3). bodystudio defaults it to PASSIVE (its numba OpenMP
threads sleep between regions, docs/reconstruct.md) but kept any value already set: an empty one (``export
OMP_WAIT_POLICY=``) or a misspelt one made libgomp print "Invalid value for environment variable" on stderr of
every command that ran a parallel kernel, around the one error line, and the default was lost. Now those are
replaced by PASSIVE; a valid ACTIVE or passive stays the user's."""

from __future__ import annotations

import subprocess
import sys

import pytest

from .conftest import cli_env

PROBE = """
import os
import bodystudio
import numba
import numpy as np

@numba.njit(parallel=True)
def total(a):
    s = 0.0
    for i in numba.prange(a.size):
        s += a[i]
    return s

print(os.environ["OMP_WAIT_POLICY"], total(np.ones(1000)), numba.threading_layer())
"""


@pytest.mark.parametrize("value, kept", [("", "PASSIVE"), ("fast", "PASSIVE"), ("ACTIVE", "ACTIVE"),
                                         ("passive", "passive")])
def test_user_wait_policy(value, kept):
    proc = subprocess.run([sys.executable, "-c", PROBE], env=cli_env({"OMP_WAIT_POLICY": value,
                                                                      "NUMBA_NUM_THREADS": "2"}),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-1000:]
    policy, total, layer = proc.stdout.split()
    assert policy == kept and float(total) == 1000.0
    assert "Invalid value" not in proc.stderr and "libgomp" not in proc.stderr, proc.stderr
