"""Small synthetic capture shared by the reconstruct tests: a posed subject seen by 4 ring cameras."""

import numpy as np
import pytest


@pytest.fixture(scope="session")
def synthetic_capture():
    from bodystudio.body import Pose, build_body
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.body.population import sample_subject
    from bodystudio.body.skinning import posed_joints
    from bodystudio.capture.render import render
    from bodystudio.geometry.camera import ring_rig

    phenotype, local = sample_subject(23)
    subject = build_body(phenotype, local, resolution="6k")
    rot = np.zeros((subject.skeleton.n_bones, 3))
    for name, v in [("upperarm_l", (0, 0, -0.5)), ("upperarm_r", (0, 0, 0.5)), ("lowerarm_r", (0.4, 0, 0)),
                    ("thigh_l", (0.25, 0, 0)), ("calf_l", (-0.35, 0, 0)), ("spine_02", (0.05, 0.15, 0))]:
        rot[subject.skeleton.index(name)] = v
    pose = Pose(rot, np.array([0.05, 0.0, -0.03]))
    V_gt, _ = subject.pose(pose)
    heads, tails = posed_joints(subject.skeleton, pose)
    joints = kinect_joints(subject.skeleton, heads, tails)
    rig = ring_rig(4)
    masks = {cam.name: render(V_gt, subject.faces, cam).mask for cam in rig}
    return {"V": V_gt, "F": subject.faces, "joints": joints, "rig": rig, "masks": masks}
