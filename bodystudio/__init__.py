"""bodystudio: multi-camera studio capture with a scan-and-rig pipeline.

Pipeline stages are subpackages, in order: ``capture`` (synthetic studio, sessions), ``calib``
(camera calibration), ``reconstruct`` (Rapid Skin template deformation), ``register`` (scan fitting),
``rig`` (skeleton and skin weights transfer, reshaping, export), ``muscle`` (arm-muscle capture) and
``viewer``. ``body`` holds the MakeHuman body model, ``geometry`` the shared mesh and camera maths.
"""

import os

# numba's OpenMP threads sleep between parallel regions instead of spinning: the compiled Rapid Skin matching
# runs ~24 short regions a frame, and spinning workers on a busy machine took the CPU from the thread doing
# the work (two threads: 570-1000 ms CPU a deformation instead of 150; passive: 152 ms, docs/reconstruct.md).
# Set before numba loads its threading layer. A valid OMP_WAIT_POLICY the user set (ACTIVE / PASSIVE) is kept;
# an empty or invalid one (libgomp ignores it, printing "Invalid value for environment variable" on stderr
# in every command, around the one error line) is replaced by the default.
if os.environ.get("OMP_WAIT_POLICY", "").strip().upper() not in ("ACTIVE", "PASSIVE"):
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"

from bodystudio.errors import BodyStudioError  # noqa: E402

__version__ = "0.1.0"
__all__ = ["BodyStudioError", "__version__"]
