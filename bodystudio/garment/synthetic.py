"""Synthetic ground truth for garment replacement (§2 of issue 13).

One camera films a textured subject wearing a known garment of its own under a known directional +
ambient light, moving at 30 fps in front of the studio background. The session (``docs/session-format.md``)
holds the video (``cam_00/rgb``), the person's silhouette (``cam_00/mask`` and ``gt/masks``), per-pixel
layers (``gt/layers``: 0 background, 1 body, 2 garment), the true lights (``gt/lighting.json``), the
worn and target garments (``gt/garment.json``), shape (``gt/phenotype.json`` with the stature), the skin
albedo per body vertex (``gt/albedo.json``), pose, posed body meshes and joints per frame, and the true
render of the actor wearing the TARGET garment (``gt/garment_target``, noise-free; its layers in
``gt/garment_target_layers``).

The camera is written to ``calibration/cameras.json`` because every session has one; it is ground
truth only (``metadata.calibration_is_ground_truth``): the garment pipeline works uncalibrated, as §4.1.
Images are linear (no sRGB curve): pixel = 255 * albedo * (ambient + sum of visible lights' n.l).
"""

from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from bodystudio.capture.session import GT_ALBEDO, GT_GARMENT, GT_LIGHTING, LAYER_BACKGROUND, LAYER_BODY, LAYER_GARMENT
from bodystudio.errors import InputError
from bodystudio.garment.garments import GARMENTS, PATTERNS
from bodystudio.garment.lighting import Lighting

log = logging.getLogger(__name__)

FPS = 30.0
#: Seconds per cycle of each motion at natural speed (walk on the spot: one stride per ~1.1 s).
MOTION_CYCLE_S = {"walk": 1.1, "arm_flex": 2.0, "turn": 4.0, "arms_raise": 2.0, "a_pose": 1.0}
SENSOR_NOISE_STD = 2.0
MAX_FRAMES = 2000


def garment_camera(width: int = 480, height: int = 640, distance_m: float = 3.2):
    """The single front camera: 1.0 m high, ``distance_m`` in front (+z), framing a 2.1 m tall view, no distortion."""
    from bodystudio.geometry.camera import Camera

    target = np.array([0.0, 0.9, 0.0])
    eye = np.array([0.0, 1.0, distance_m])
    fx = height * np.linalg.norm(eye - target) / 2.1
    return Camera.look_at("cam_00", eye, target, fx=fx, width=width, height=height)


def sample_lighting(rng: np.random.Generator) -> Lighting:
    """One directional light in the camera's hemisphere (azimuth within 50 deg of the camera, 15-55 deg up)
    with a slight warm/cool tint, plus ambient 0.15-0.3."""
    az = np.radians(rng.uniform(-50, 50))
    el = np.radians(rng.uniform(15, 55))
    direction = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    intensity = rng.uniform(0.6, 0.85)
    tint = 1.0 + rng.uniform(-0.06, 0.06) * np.array([1.0, 0.0, -1.0])
    return Lighting(direction[None], (intensity * tint)[None], np.full(3, rng.uniform(0.15, 0.3)))


def subject_albedo(body, rng: np.random.Generator) -> np.ndarray:
    """Per-vertex skin albedo (n, 3) in [0, 1]: a skin tone with smooth blotches, darker hair on the scalp."""
    tones = np.array([[0.87, 0.68, 0.57], [0.76, 0.57, 0.45], [0.58, 0.42, 0.32], [0.42, 0.29, 0.21]])
    tone = tones[rng.integers(len(tones))] * rng.uniform(0.95, 1.05)
    V = body.vertices
    k = rng.normal(size=(3, 3)) * 6.0
    phase = rng.uniform(0, 2 * np.pi, 3)
    blotch = np.sin(V @ k.T + phase).mean(1)
    albedo = tone[None] * (1.0 + 0.06 * blotch)[:, None]
    head = body.skeleton.heads[body.skeleton.index("head")]
    top = V[:, 1].max()
    scalp = (V[:, 1] > head[1] + 0.55 * (top - head[1])) & (V[:, 2] < head[2] + 0.06)
    albedo[scalp] = np.array([0.18, 0.13, 0.1]) * rng.uniform(0.7, 1.3)
    return np.clip(albedo, 0.0, 1.0)


def motion_poses(motion: str, n_frames: int, skeleton, seed: int):
    """``n_frames`` poses of ``motion`` sampled at 30 fps at the motion's natural speed."""
    from bodystudio.capture.motion import CYCLIC_MOTIONS, keyframes_to_poses, motion_keyframes

    cycle_frames = MOTION_CYCLE_S[motion] * FPS
    cycles = max(1, math.ceil(n_frames / cycle_frames))
    keys = motion_keyframes(motion, skeleton, seed, cycles)
    if motion in ("walk", "arm_flex"):
        total = max(n_frames, round(cycles * cycle_frames))
    else:
        total = max(n_frames, round(cycle_frames))
    return keyframes_to_poses(skeleton, keys, total, cyclic=motion in CYCLIC_MOTIONS)[:n_frames]


def synth_garment_session(out: str | os.PathLike, subject_seed: int = 7, n_frames: int = 60, garment: str = "tshirt",
                          pattern: str = "stripes", motion: str = "walk", resolution: tuple[int, int] = (480, 640),
                          seed: int = 0, noise: bool = True, template: str = "6k", texture_size: int = 512,
                          shadows: bool = True, progress: bool = False):
    """Render the single-camera garment session of subject ``subject_seed`` into the new folder ``out``.

    The actor wears a plain-coloured ``garment``-cut garment; the target is ``garment`` with ``pattern``.
    Same arguments, same bytes.
    """
    from bodystudio.body import build_body, posed_joints
    from bodystudio.body.population import sample_subject
    from bodystudio.capture.render import background_plate
    from bodystudio.capture.session import SessionWriter, open_session, progress_bar
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment
    from bodystudio.geometry.camera import CameraRig

    out = Path(out)
    if garment not in GARMENTS:
        raise InputError(f"--garment {garment!r}: valid: {', '.join(GARMENTS)}")
    if pattern not in PATTERNS:
        raise InputError(f"--pattern {pattern!r}: valid: {', '.join(PATTERNS)}")
    if motion not in MOTION_CYCLE_S:
        raise InputError(f"--motion {motion!r}: valid: {', '.join(MOTION_CYCLE_S)}")
    if not 1 <= n_frames <= MAX_FRAMES:
        raise InputError(f"--frames {n_frames}: must be in [1, {MAX_FRAMES}]")
    if subject_seed < 0:
        raise InputError(f"--subject-seed {subject_seed}: must be >= 0")
    width, height = resolution
    if not (64 <= width <= 4096 and 64 <= height <= 4096):
        raise InputError(f"--resolution {width}x{height}: width and height must be in [64, 4096] pixels")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"{out}: output folder exists and is not empty; choose a new folder")

    rng = np.random.default_rng([seed, subject_seed, 13])
    phenotype, local = sample_subject(subject_seed)
    body = build_body(phenotype, local, resolution=template)
    skeleton, F = body.skeleton, body.faces
    poses = motion_poses(motion, n_frames, skeleton, seed)
    camera = garment_camera(width, height)
    lighting = sample_lighting(rng)
    skin = subject_albedo(body, rng)
    worn_name = garment  # the actor wears the target's cut in a plain colour, so the target covers it
    worn_seed, target_seed = int(rng.integers(1 << 16)), int(rng.integers(1 << 16))
    worn = dress(body, worn_name, "plain", texture_size, worn_seed)
    target = dress(body, garment, pattern, texture_size, target_seed)
    plate = background_plate(camera, seed)
    noise_std = SENSOR_NOISE_STD if noise else 0.0
    stature = float(body.vertices[:, 1].max() - body.vertices[:, 1].min())

    metadata = {"generator": "bodystudio synth garment", "subject_seed": subject_seed, "garment": garment,
                "pattern": pattern, "worn": worn_name, "motion": motion, "fps": FPS, "seed": seed,
                "noise_std": noise_std, "template": template, "resolution": [width, height],
                "shadows": shadows, "calibration_is_ground_truth": True, "color_space": "linear"}
    with progress_bar(progress) as bar:
        task = bar.add_task("synth garment", total=n_frames)
        with SessionWriter(out, CameraRig({camera.name: camera}), source="synthetic", metadata=metadata,
                           command="bodystudio synth garment") as writer:
            writer.write_gt_subject(phenotype.to_dict(), local, template=template, rig=body.rig,
                                    n_vertices=body.n_vertices, bone_names=list(skeleton.bone_names),
                                    stature_m=stature)
            writer.write_gt_json(GT_LIGHTING, {**lighting.to_dict(), "space": "world", "model":
                                               "albedo * (ambient + sum visible max(0, n.d) color), linear"})
            writer.write_gt_json(GT_GARMENT, {
                "worn": {"name": worn_name, "pattern": "plain", "seed": worn_seed},
                "target": {"name": garment, "pattern": pattern, "seed": target_seed},
                "texture_size": texture_size})
            writer.write_gt_json(GT_ALBEDO, {"albedo": np.round(skin, 6), "template": template,
                                             "appearance": np.round(appearance_albedo(body, worn, skin), 6),
                                             "space": "linear RGB in [0, 1], one row per body vertex"})
            writer.write_background(camera.name, 0, _with_noise(plate, noise_std, rng))
            for i, pose in enumerate(poses):
                Vb, _ = body.pose(pose)
                heads, tails = posed_joints(skeleton, pose)
                seen = render_garment(Vb, F, worn, pose_garment(worn, body, pose), camera, lighting, plate, skin,
                                      shadows)
                true = render_garment(Vb, F, target, pose_garment(target, body, pose), camera, lighting, plate, skin,
                                      shadows)
                writer.write_image(camera.name, i, _with_noise(seen.image, noise_std, rng))
                person = seen.garment_mask | seen.body_mask
                writer.write_mask(camera.name, i, person)
                writer.write_mask(camera.name, i, person, ground_truth=True)
                writer.write_layers(camera.name, i, layer_labels(seen))
                writer.write_target(camera.name, i, true.image)
                writer.write_layers(camera.name, i, layer_labels(true), target=True)
                writer.write_gt_mesh(i, Vb, F)
                writer.write_gt_joints(i, skeleton.bone_names, heads, tails)
                writer.write_gt_pose(i, pose, skeleton.bone_names)
                bar.advance(task)
    log.info("wrote %s: %d frames of subject %d wearing %s (target %s)", out, n_frames, subject_seed, worn_name,
             garment)
    return open_session(out)


def appearance_albedo(body, worn, skin: np.ndarray, reach_m: float = 0.15) -> np.ndarray:
    """The albedo a video shows at each body vertex: the worn garment's colour where it covers the skin.

    A vertex is covered when the ray along its normal meets the garment within ``reach_m``; it takes the
    garment texture's colour at the hit (what §5.1's mean colour should find there).
    """
    import open3d as o3d

    from bodystudio.garment.garments import sample_texture
    from bodystudio.geometry.mesh import vertex_normals

    N = vertex_normals(body.vertices, body.faces)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(worn.vertices.astype(np.float32)),
                        o3d.core.Tensor(worn.faces.astype(np.uint32)))
    rays = np.hstack([body.vertices - 1e-3 * N, N]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))
    t = hit["t_hit"].numpy()
    covered = t < reach_m
    tri = hit["primitive_ids"].numpy()[covered].astype(np.int64)
    uvw = hit["primitive_uvs"].numpy()[covered].astype(np.float64)
    bary = np.column_stack([1.0 - uvw.sum(1), uvw])
    uv = np.einsum("kj,kjd->kd", bary, worn.uv[worn.faces[tri]])
    out = skin.copy()
    out[covered] = sample_texture(worn.texture, uv)
    return out


def layer_labels(result) -> np.ndarray:
    """uint8 (H, W) labels of a :class:`~bodystudio.garment.render.GarmentRender`: 0 background, 1 body, 2 garment."""
    labels = np.full(result.garment_mask.shape, LAYER_BACKGROUND, dtype=np.uint8)
    labels[result.body_mask] = LAYER_BODY
    labels[result.garment_mask] = LAYER_GARMENT
    return labels


def _with_noise(image: np.ndarray, noise_std: float, rng: np.random.Generator) -> np.ndarray:
    if noise_std <= 0:
        return image.copy()
    noisy = image.astype(np.float32) + rng.normal(0.0, noise_std, image.shape).astype(np.float32)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)
