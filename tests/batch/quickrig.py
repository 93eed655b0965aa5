"""Worker-side setup for the batch rig tests: the scan fit replaced by the 2k body model's own rig.

The fit is not what these tests test (the batch is); with it a unit takes a fraction of a second. ``slow_unit``
also writes the worker's pid and sleeps, so a test can kill the worker while it holds a unit.
"""

import os
import time
import types
from pathlib import Path


def quick_rig(mesh, model, weights="harmonic", stage=None):
    import numpy as np

    from bodystudio.body import build_body
    from bodystudio.rig.avatar import Avatar
    from bodystudio.rig.weights import limit_influences

    body = build_body(resolution="2k")
    sk = body.skeleton
    colors = (np.abs(np.sin(body.vertices * 20.0)) * 255).astype(np.uint8)
    avatar = Avatar(body.vertices, body.faces, colors, sk.bone_names, sk.parents, None, sk.rest_rotations,
                    sk.rest_rotations, sk.lengths, limit_influences(body.weights), np.zeros(3),
                    loaded_heads=sk.heads.copy())
    avatar.metadata["fit_err_mm_median"] = 0.0
    for name in ("fit", "skeleton", "weights"):
        if stage is not None:
            stage(name)
    return types.SimpleNamespace(avatar=avatar, fit=None, seconds={})


def install_quick_rig():
    import bodystudio.rig.pipeline as pipeline

    pipeline.rig_scan = quick_rig


class SlowUnit:
    """Setup: the quick rig, which inside the unit's lock (staging begun) writes ``pid_dir/PID`` and sleeps
    ``seconds``, so that a test can kill the worker while it holds a unit."""

    def __init__(self, pid_dir: str, seconds: float):
        self.pid_dir, self.seconds = pid_dir, seconds

    def __call__(self):
        import bodystudio.rig.pipeline as pipeline

        pid_dir, seconds = self.pid_dir, self.seconds

        def slow_rig(*args, **kwargs):
            Path(pid_dir, str(os.getpid())).write_text("")
            time.sleep(seconds)
            return quick_rig(*args, **kwargs)

        pipeline.rig_scan = slow_rig


class SlowCaptureWrite:
    """Setup of an arm-capture unit: writing the unit's files (inside its lock, staging begun) first writes
    ``pid_dir/PID`` and sleeps ``seconds``, so that a test can kill the worker while it holds the unit."""

    def __init__(self, pid_dir: str, seconds: float):
        self.pid_dir, self.seconds = pid_dir, seconds

    def __call__(self):
        import bodystudio.muscle.capture as capture

        original = getattr(capture, "_original_write_arm_capture_files", capture.write_arm_capture_files)
        capture._original_write_arm_capture_files = original
        pid_dir, seconds = self.pid_dir, self.seconds

        def slow_write(path_for, *args, **kwargs):
            original(path_for, *args, **kwargs)
            Path(pid_dir, str(os.getpid())).write_text("")
            time.sleep(seconds)

        capture.write_arm_capture_files = slow_write
