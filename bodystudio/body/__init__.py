"""The MakeHuman body model: shape (phenotype + local targets), skeleton, skin weights and posing.

>>> from bodystudio.body import Phenotype, build_body, Pose
>>> body = build_body(Phenotype(gender=1.0), resolution="6k")
>>> vertices, joints = body.pose(Pose.rest(body.skeleton.n_bones))
"""

from bodystudio.body.model import RESOLUTIONS, BodyModel, build_body, rig_definition, shaped_vertices, template_topology
from bodystudio.body.phenotype import Phenotype
from bodystudio.body.pose import Pose, load_pose, pose_from_dict
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.skinning import (
    dual_quaternion_skinning,
    forward_kinematics,
    linear_blend_skinning,
    posed_joints,
    skinning_transforms,
)

__all__ = [
    "RESOLUTIONS", "BodyModel", "Phenotype", "Pose", "Skeleton", "build_body", "dual_quaternion_skinning",
    "forward_kinematics", "linear_blend_skinning", "load_pose", "pose_from_dict", "posed_joints", "rig_definition",
    "shaped_vertices", "skinning_transforms", "template_topology",
]
