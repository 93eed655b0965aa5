"""Small synthetic cases shared by the reconstruct tests: a posed subject seen by 4 ring cameras, and a sphere
seen by 3 cameras (its silhouettes 5 % larger than the mesh)."""

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


@pytest.fixture(scope="module")
def sphere_scene():
    """An icosphere of radius 0.30 m, 3 cameras around it, and the silhouettes of the sphere scaled by 1.05."""
    import trimesh

    from bodystudio.geometry.camera import Camera
    from bodystudio.reconstruct.silhouette import silhouette_mask

    m = trimesh.creation.icosphere(subdivisions=3, radius=0.30)
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.3, 3 * np.cos(a)), (0, 0, 0), fx=400.0, width=200, height=160)
            for i, a in enumerate([0.0, 2.1, 4.2])]
    masks = {c.name: silhouette_mask(1.05 * V, F, c) for c in cams}
    return V, F, cams, masks
