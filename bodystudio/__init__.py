"""bodystudio: multi-camera studio capture with a scan-and-rig pipeline.

Pipeline stages are subpackages, in order: ``capture`` (synthetic studio, sessions), ``calib``
(camera calibration), ``reconstruct`` (Rapid Skin template deformation), ``register`` (scan fitting),
``rig`` (skeleton and skin weights transfer, reshaping, export), ``muscle`` (arm-muscle capture) and
``viewer``. ``body`` holds the MakeHuman body model, ``geometry`` the shared mesh and camera maths.
"""

from bodystudio.errors import BodyStudioError

__version__ = "0.1.0"
__all__ = ["BodyStudioError", "__version__"]
