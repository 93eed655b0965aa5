"""``pose_init.neck_at_joint`` (rec15l) where test_neck_at_joint.py does not reach it (issue 17, mutation testing):
float32 transforms (a renderer's or a loaded file's) come back as float64 geometry, the neck placed to float64
precision, the input left as it was. One 2k template, built once; < 2 s."""
import functools

import numpy as np

from bodystudio.body import build_body
from bodystudio.body.kinect import kinect_joint_names, kinect_joints
from bodystudio.reconstruct.pose_init import initialise_pose, neck_at_joint

NECK = kinect_joint_names("v2").index("Neck")


@functools.cache
def _template():
    return build_body(resolution="2k")


def test_float32_transforms_give_float64_ones_with_the_neck_on_the_joint():
    body = _template()
    sk = body.skeleton
    J = kinect_joints(sk, sk.heads, sk.tails, "v2")
    T32 = initialise_pose(body, J).bone_transforms.astype(np.float32)
    kept = T32.copy()
    target = J[NECK] + np.array([0.0123456789, 0.0234567891, -0.0345678912])
    out = neck_at_joint(body, T32, target)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(T32, kept)
    b = sk.index("neck_01")
    np.testing.assert_allclose(out[b, :3, :3] @ sk.heads[b] + out[b, :3, 3], target, atol=1e-12)
    other = np.arange(len(out)) != b
    np.testing.assert_array_equal(out[other], T32[other].astype(np.float64))
