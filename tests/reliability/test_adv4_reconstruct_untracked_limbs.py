"""``reconstruct`` on a frame whose tracker lost the limbs (adversarial pass 4).

Untracked joints are NaN to the pose initialisation, whose limb segments then keep the template's rest pose. On a
4-camera 160x120 session (subject 7, Kinect v1, silhouettes + depth) a frame with all eight limb joints untracked
fitted p90 70.7 mm, Hausdorff 289 mm (its neighbours 15.4 / 15.7 mm), every IoU >= 0.9: the self-check passed it
with no word, exit 0. Each frame now records how many limb joints were untracked (frames.json, where any was), and
the run warns naming kinect/joints when a frame missed half of them or more (a warning: one such frame should not
refuse a session)."""

from __future__ import annotations

import json
import shutil

from bodystudio.capture.faults import restamp
from bodystudio.reconstruct.plausibility import LIMB_JOINTS, run_plausibility, untracked_limb_joints


def test_a_frame_with_its_limbs_untracked_is_warned_about(small_synth_session, tmp_path, caplog):
    from bodystudio.reconstruct.sequence import reconstruct_session

    S = shutil.copytree(small_synth_session, tmp_path / "S")
    rel = "kinect/joints/00001.json"
    data = json.loads((S / rel).read_text())
    data["tracked"] = [n not in LIMB_JOINTS and t for n, t in zip(data["names"], data["tracked"], strict=True)]
    (S / rel).write_text(json.dumps(data))
    restamp(S, rel)
    reconstruct_session(S, template="2k", frames="1:2", score=False)
    frames = json.loads((S / "reconstruct" / "frames.json").read_text())["frames"]
    assert frames[0]["plausibility"]["untracked_limb_joints"] == 8
    verdict = json.loads((S / "reconstruct" / "run.json").read_text())["plausibility"]
    assert verdict["ok"] and verdict["frames_limbs_untracked"] == 1  # the other checks pass it
    assert any("1 of 1 frames had 4 or more of the 8 limb joints untracked by" in w and "kinect/joints" in w
               for w in verdict["warnings"]), verdict["warnings"]
    assert "limb joints untracked" in caplog.text


def test_the_count_and_the_threshold():
    import numpy as np

    from bodystudio.body.kinect import kinect_joint_names

    names = kinect_joint_names("v2")
    J = np.zeros((25, 3))
    assert untracked_limb_joints(J) == 0 and untracked_limb_joints(None) is None
    for k, n in enumerate(LIMB_JOINTS[:3]):
        J[names.index(n)] = np.nan
        assert untracked_limb_joints(J) == k + 1
    J[names.index("Head")] = np.nan  # not a limb joint
    assert untracked_limb_joints(J) == 3
    assert not run_plausibility([{"untracked_limb_joints": 3}, {"untracked_limb_joints": 0}])["warnings"]
    report = run_plausibility([{"untracked_limb_joints": 4}, {"untracked_limb_joints": 1}, {}])
    assert report["frames_limbs_untracked"] == 1 and report["ok"]
    assert report["warnings"][0].startswith("1 of 3 frames had 4 or more of the 8 limb joints untracked")
