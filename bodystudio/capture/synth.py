"""The synthetic studio: a known subject, moving through a known motion, seen by known cameras.

``synth_session`` writes a complete session (``docs/session-format.md``): per camera RGB renders over
the studio background plates (with Gaussian sensor noise unless ``noise=False``), ground-truth masks,
empty-studio background frames for background subtraction (Rapid Skin Sec. V.A), an optional Kinect
(depth, colour, body-tracker joints) and the ground truth (phenotype, posed meshes, joints, poses).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from bodystudio.capture.session import Session, SessionWriter, open_session, progress_bar
from bodystudio.errors import InputError

log = logging.getLogger(__name__)

#: Gaussian sensor noise of the studio cameras, in 0..255 grey levels (a machine-vision CMOS at ISO base).
SENSOR_NOISE_STD = 2.0
#: Number of empty-studio frames written per camera for the background model (mean and per-pixel std).
N_BACKGROUND_FRAMES = 5


def parse_resolution(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480); anything else raises a one-line InputError."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
        if w < 16 or h < 16:
            raise ValueError
    except ValueError:
        raise InputError(f"--resolution {text!r} must be WIDTHxHEIGHT in pixels, e.g. 640x480") from None
    return w, h


def kinect_sensor(version: str):
    """The simulated RGB-D sensor (``v1`` or ``v2``) placed in front of the subject."""
    from bodystudio.geometry.camera import kinect_v1, kinect_v2

    if version == "v2":
        return kinect_v2()
    if version == "v1":
        return kinect_v1()
    raise InputError(f"--kinect {version!r} is not a Kinect version; valid: v1, v2")


def synth_session(out: str | os.PathLike, n_cameras: int = 10, n_frames: int = 30, motion: str = "walk",
                  subject_seed: int = 7, kinect: str | None = "v2", resolution: tuple[int, int] = (640, 480),
                  noise: bool = True, seed: int = 0, template: str = "full",
                  n_background: int = N_BACKGROUND_FRAMES, progress: bool = False,
                  fps: float | None = None) -> Session:
    """Render a synthetic studio session of subject ``subject_seed`` into the new folder ``out``.

    ``seed`` drives the motion variation, sensor noise and background texture; the same arguments
    always give the same session (byte-identical files). ``fps``: the motion plays at its natural
    speed sampled at that frame rate (a video-rate sequence, as a tracker sees it) instead of
    ``n_frames`` samples spread over the whole motion.
    """
    from bodystudio.body import build_body, posed_joints
    from bodystudio.body.population import sample_subject
    from bodystudio.capture.motion import MOTIONS, motion_sequence
    from bodystudio.capture.render import background_plate, render, render_rgb
    from bodystudio.geometry.camera import ring_rig

    out = Path(out)
    if n_cameras < 1 or n_frames < 1:
        raise InputError(f"need at least one camera and one frame, got --cameras {n_cameras} --frames {n_frames}")
    if motion not in MOTIONS:
        raise InputError(f"unknown motion {motion!r}; valid: {', '.join(MOTIONS)}")
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out}: output folder exists and is not empty; choose a new folder")
    width, height = resolution
    noise_std = SENSOR_NOISE_STD if noise else 0.0
    rng = np.random.default_rng([seed, subject_seed])

    phenotype, local = sample_subject(subject_seed)
    body = build_body(phenotype, local, resolution=template)
    skeleton, F = body.skeleton, body.faces
    poses = motion_sequence(motion, n_frames, skeleton, seed, fps=fps)
    rig = ring_rig(n_cameras, width=width, height=height)
    plates = {cam.name: background_plate(cam, seed) for cam in rig}
    sensor = kinect_sensor(kinect) if kinect else None

    metadata = {"generator": "bodystudio synth session", "subject_seed": subject_seed, "motion": motion,
                "seed": seed, "noise_std": noise_std, "template": template, "kinect": kinect,
                "resolution": [width, height]}
    if fps is not None:
        metadata["fps"] = float(fps)
    with progress_bar(progress) as bar:
        task = bar.add_task("synth session", total=n_frames + 1)
        with SessionWriter(out, rig, source="synthetic", metadata=metadata,
                           command="bodystudio synth session") as writer:
            writer.write_gt_subject(phenotype.to_dict(), local, template=template, rig=body.rig,
                                    n_vertices=body.n_vertices, bone_names=list(skeleton.bone_names))
            for cam in rig:
                for k in range(n_background):
                    writer.write_background(cam.name, k, _with_noise(plates[cam.name], noise_std, rng))
            if sensor is not None:
                writer.write_kinect_calibration(sensor)
                kinect_plate = background_plate(sensor.color, seed)
            bar.advance(task)
            for i, pose in enumerate(poses):
                V, _ = body.pose(pose)
                heads, tails = posed_joints(skeleton, pose)
                for cam in rig:
                    result = render(V, F, cam)
                    rgb = render_rgb(V, F, cam, background=plates[cam.name], result=result,
                                     noise_std=noise_std, rng=rng)
                    writer.write_image(cam.name, i, rgb)
                    writer.write_mask(cam.name, i, result.mask)
                    writer.write_mask(cam.name, i, result.mask, ground_truth=True)
                if sensor is not None:
                    _write_kinect_frame(writer, i, V, F, heads, tails, skeleton, sensor, kinect, kinect_plate,
                                        noise, noise_std, rng)
                writer.write_gt_mesh(i, V, F)
                writer.write_gt_joints(i, skeleton.bone_names, heads, tails)
                writer.write_gt_pose(i, pose, skeleton.bone_names)
                bar.advance(task)
    session = open_session(out)
    log.info("wrote %s: %d cameras x %d frames", out, n_cameras, n_frames)
    return session


def _write_kinect_frame(writer, i, V, F, heads, tails, skeleton, sensor, version, plate, noise, noise_std, rng):
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.capture.kinect import simulate_kinect_depth, simulate_tracker_joints
    from bodystudio.capture.render import render_rgb

    depth_m = simulate_kinect_depth(V, F, sensor, rng, noise=noise)
    writer.write_kinect_depth(i, depth_m)
    writer.write_kinect_rgb(i, render_rgb(V, F, sensor.color, background=plate, noise_std=noise_std, rng=rng))
    if noise:
        joints, tracked = simulate_tracker_joints(heads, tails, skeleton, version, rng)
    else:
        joints, tracked = simulate_tracker_joints(heads, tails, skeleton, version, rng, noise_m=0.0,
                                                  bone_length_jitter=0.0)
    writer.write_kinect_joints(i, kinect_joint_names(version), joints, tracked, joint_set=version)


def _with_noise(image: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    if noise_std <= 0:
        return image.copy()
    noisy = image.astype(np.float32) + rng.normal(0.0, noise_std, image.shape).astype(np.float32)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)
