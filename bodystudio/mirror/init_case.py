"""Small synthetic Kinect observations of a posed subject (no session needed): the mirror init/track tests'
and ``benchmarks/mirror_init_accuracy.py``'s walk set.

A population subject is posed by a motion, rendered into a Kinect depth camera with the Kinect noise
model (flying pixels at the silhouette, holes, quantisation), back-projected to studio-frame points,
and seen by the simulated SDK tracker (joint noise, bone-length jitter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bodystudio.body import build_body
from bodystudio.body.kinect import kinect_joints
from bodystudio.body.measure import measure_body
from bodystudio.body.population import sample_population
from bodystudio.body.skinning import posed_joints
from bodystudio.capture.kinect import simulate_kinect_depth, simulate_tracker_joints
from bodystudio.capture.motion import motion_sequence
from bodystudio.geometry.camera import kinect_v1, kinect_v2
from bodystudio.mirror.init import InitObservation


@dataclass
class Scene:
    body: object  # the true BodyModel
    truth: dict  # measured attributes of the true rest body
    sensor: object
    observations: list  # InitObservation per frame
    poses: list
    true_joints: list  # (J, 3) per frame


def drop_flying_pixels(depth_m: np.ndarray, step_m: float = 0.03) -> np.ndarray:
    """Depth (H, W) without the pixels lying *between* surfaces: the part of the SDK's player segmentation
    this scene (no room, no player mask) stands in for.

    At a depth discontinuity the Kinect reports mixtures of the near and the far depth; the SDK does not
    label those behind the silhouette as the player (``mirror.synthetic``'s player mask: the true person's
    pixels). A pixel whose 3x3 neighbourhood holds a depth more than ``step_m`` nearer *and* one more
    than ``step_m`` farther (no measurement counts as far) is such a mixture.
    """
    from scipy import ndimage

    depth = np.asarray(depth_m, dtype=np.float64)
    valid = depth > 0
    near = ndimage.minimum_filter(np.where(valid, depth, np.inf), size=3, mode="nearest")
    far = ndimage.maximum_filter(np.where(valid, depth, np.inf), size=3, mode="nearest")
    return np.where(valid & (depth - near > step_m) & (far - depth > step_m), 0.0, depth)


def back_project(depth_m: np.ndarray, camera, player_mask: bool = True) -> np.ndarray:
    """Studio-frame points of the depth pixels; with ``player_mask`` the flying pixels behind the body's
    silhouette are left out as the SDK's player mask leaves them out (:func:`drop_flying_pixels`)."""
    if player_mask:
        depth_m = drop_flying_pixels(depth_m)
    rows, cols = np.nonzero(depth_m > 0)
    uv = np.stack([cols, rows], 1).astype(np.float64)
    return camera.unproject(uv, depth_m[rows, cols].astype(np.float64))


def synthetic_scene(subject_seed: int, n_frames: int = 6, motion: str = "walk", version: str = "v2",
                    resolution: str = "6k", seed: int = 0, offset=(0.1, 0.0, 0.2), frame_stride: int = 1,
                    noise: bool = True, joint_noise_m: float = 0.01, yaw_deg: float = 0.0) -> Scene:
    """``subject_seed``'s population body doing ``motion`` (``seed``: its draw, the posture's too, and the noise),
    every ``frame_stride``-th of ``n_frames * frame_stride`` frames, moved by ``offset`` and, with ``yaw_deg``,
    turned about the vertical (90: its left side to the sensor, as a walk-in shows it)."""
    phenotype, local = sample_population(1, seed=subject_seed)[0]
    body = build_body(phenotype, local, resolution=resolution)
    sensor = kinect_v2() if version == "v2" else kinect_v1("320x240")
    rng = np.random.default_rng(seed)
    poses = motion_sequence(motion, n_frames * frame_stride, body.skeleton, seed=seed)[::frame_stride]
    if yaw_deg:
        from bodystudio.mirror.synthetic import _yaw

        poses = [_yaw(body.skeleton, p, float(np.radians(yaw_deg)), p.translation) for p in poses]
    obs, truths, out_poses = [], [], []
    for i, pose in enumerate(poses):
        pose = type(pose)(pose.rotations, pose.translation + np.asarray(offset))
        V, _ = body.pose(pose)
        depth = simulate_kinect_depth(V, body.faces, sensor, rng, noise=noise)
        heads, tails = posed_joints(body.skeleton, pose)
        K, tracked = simulate_tracker_joints(heads, tails, body.skeleton, version, rng, noise_m=joint_noise_m,
                                             bone_length_jitter=3 * joint_noise_m)
        person = drop_flying_pixels(depth) > 0  # the SDK's player mask: this scene has no room behind the actor
        obs.append(InitObservation(i, back_project(depth, sensor.depth), K, tracked, version, player_mask=person))
        truths.append(kinect_joints(body.skeleton, heads, tails, version))
        out_poses.append(pose)
    return Scene(body, measure_body(body), sensor, obs, out_poses, truths)
