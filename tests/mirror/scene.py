"""The init/track tests' synthetic scene (kept importable as ``scene``; the code lives in the package)."""

from bodystudio.mirror.init_case import Scene, back_project, synthetic_scene

__all__ = ["Scene", "back_project", "synthetic_scene"]
