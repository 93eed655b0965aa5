"""The arm-muscle capture's mid-stream faults (rel6b; docs/muscle.md "Bad input").

Audited on a symlink copy of a real-size arm session (``benchmarks/muscle_bad_input.py``: /work/musw seq_501, 20
frames, the fault in frame 10): a truncated, half-size, 8-bit or deleted depth PNG, a null elbow or a deleted joints
file are refused in one line naming the file, nothing written; every joint flagged untracked (the SDK's "inferred")
captures as the clean copy (0.0 mm: positions used as designed). The arm leaving the depth window for three frames
was refused naming "depth frame 10" and telling the user to "move the subject to about 1 m" (it was at 1 m): now the
depth file, that the arm left the view after the frames before had it, and ``--frames 10``. A depth map of another
size named "depth frame 10", now the file. Milliseconds beyond the 2k template.
"""

from __future__ import annotations

import numpy as np
import pytest

from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def scene():
    from bodystudio.body import build_body
    from bodystudio.geometry.camera import kinect_v2
    from bodystudio.muscle.arm import arm_template

    camera = kinect_v2().depth
    plate = np.zeros((camera.height, camera.width))
    plate[150:270, 200:320] = 1.0  # something at 1 m, enough pixels for the clean-up
    return camera, arm_template(build_body(resolution="2k"), "left"), plate


def test_the_arm_leaving_the_view_is_told_as_such(scene):
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames

    camera, template, plate = scene
    depths = [plate, plate, np.zeros_like(plate)]
    with pytest.raises(InputError, match=r"^S/kinect/depth/00012.png: no arm in the 0.5-1.3 m depth window in frame "
                       r"12, though the 2 frame\(s\) before had it: the arm left the view; capture the first 2 frames "
                       r"\(--frames 2\) or record the arm in view throughout$"):
        capture_arm_frames(depths, camera, template, None, CaptureOptions(mode="nicp"), frame_ids=[10, 11, 12],
                           depth_sources=[f"S/kinect/depth/{i:05d}.png" for i in (10, 11, 12)])
    # no arm from the first frame: the distance advice, as before
    with pytest.raises(InputError, match="^depth frame 0: only 0 depth pixels within 0.5-1.3 m; no arm in range: "
                       "move "):
        capture_arm_frames([np.zeros_like(plate)], camera, template, None, CaptureOptions(mode="nicp"))


def test_a_depth_map_of_another_size_names_its_file(scene):
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames

    camera, template, plate = scene
    half = plate[::2, ::2]
    with pytest.raises(InputError, match=r"^S/kinect/depth/00011.png: depth map is 256x212 but the depth camera "):
        capture_arm_frames([plate, half], camera, template, None, CaptureOptions(mode="nicp"), frame_ids=[10, 11],
                           depth_sources=["S/kinect/depth/00010.png", "S/kinect/depth/00011.png"])


def test_a_killed_captures_staging_folder_is_removed_by_the_next_capture(tmp_path):
    """SIGKILL during the write left ``.OUT.staging-PID`` beside the output for ever (audit: the kill left no output,
    the rerun captured); the next write into that place removes it, and leaves a running writer's alone."""
    import os
    import subprocess
    import sys

    from bodystudio.muscle.export import staged_output_folder

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    killed = tmp_path / f".capture.staging-{int(dead.stdout)}"
    running = tmp_path / f".capture.staging-{os.getppid()}"
    for folder in (killed, running):
        folder.mkdir()
        (folder / "meshes").mkdir()
    with staged_output_folder(tmp_path / "capture") as stage:
        (stage / "params.json").write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["capture", running.name])
