"""Whole scenes for what ``bodystudio view`` opens: a mesh or scan, a rigged avatar, a capture session.

``open_viewable(path)`` decides what a path is (one-line errors otherwise); ``build_view`` turns it into
a plotter; the ``scene_for_*`` functions are the pieces, usable on any plotter without a window.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bodystudio.errors import FileFormatError, InputError, SessionError
from bodystudio.geometry.mesh import MESH_SUFFIXES, Mesh, load_mesh
from bodystudio.viewer import scene as sc
from bodystudio.viewer.avatar import Avatar, glb_has_skin, load_avatar

log = logging.getLogger(__name__)

SESSION_MANIFEST = "session.json"
IMAGE_LAYERS = ("image", "mask", "none")
MAX_TEXTURE_WIDTH = 320  # camera images are shown small; keeps the HTML export light
FRUSTUM_M = 0.5  # depth at which camera frusta end and their images are drawn
KINECT_COLOR = (0.95, 0.35, 0.85)  # magenta: not in the error colour map


@dataclass(frozen=True)
class Viewable:
    """What a path holds: ``kind`` is ``mesh``, ``avatar`` or ``session``; ``data`` the loaded object."""

    path: Path
    kind: str
    data: Any


def open_viewable(path: str | Path) -> Viewable:
    """Open a session or arm capture folder, a mirror session or run folder (before/after frames and the
    source body, :mod:`bodystudio.viewer.mirror`), a garment fit or render folder (fitted body, garment, lights,
    before/after frames, :mod:`bodystudio.viewer.garment`), a mesh/scan (PLY, OBJ, STL, OFF, GLB) or a skinned
    avatar."""
    path = Path(path)
    if path.is_dir():
        from bodystudio.viewer.arm import is_arm_capture, open_arm_view
        from bodystudio.viewer.garment import is_garment_fit, is_garment_render, open_garment_view
        from bodystudio.viewer.mirror import is_mirror_run, is_mirror_session, open_mirror_view

        if is_arm_capture(path):
            return Viewable(path, "arm", open_arm_view(path))
        if is_garment_fit(path) or is_garment_render(path) or (path / "fit.json").is_file():
            return Viewable(path, "garment", open_garment_view(path))
        if is_mirror_run(path) or is_mirror_session(path):
            return Viewable(path, "mirror", open_mirror_view(path))
        if not (path / SESSION_MANIFEST).is_file():
            inside = sorted(p.parent for p in path.glob(f"*/{SESSION_MANIFEST}"))
            hint = f" (it holds the session {inside[0]})" if inside else ""
            raise SessionError(f"{path}: not a session folder (no {SESSION_MANIFEST}){hint}; give a session "
                               f"folder or a mesh file ({', '.join(MESH_SUFFIXES)})")
        from bodystudio.capture.session import open_session

        return Viewable(path, "session", open_session(path))
    if not path.exists():
        raise InputError(f"{path}: no such file or folder; give a session folder or a mesh file")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise FileFormatError(f"{path}: not a session folder or mesh; give a session folder or a mesh file "
                              f"({', '.join(MESH_SUFFIXES)})")
    if suffix in (".glb", ".gltf") and glb_has_skin(path):
        return Viewable(path, "avatar", load_avatar(path))
    return Viewable(path, "mesh", load_mesh(path))


def scene_for_mesh(mesh: Mesh, plotter=None, reference: Mesh | None = None, title: str | None = None,
                   key_help: bool = True, floor: bool = True):
    """A mesh or scan; with ``reference`` (ground truth) it is coloured by its distance to it in mm."""
    plotter = plotter if plotter is not None else sc.make_plotter()
    if reference is not None:
        sc.add_mesh(plotter, reference, color=sc.GT_COLOR, opacity=0.25, name="reference")
        sc.add_error_map(plotter, mesh, sc.vertex_errors_mm(mesh.vertices, reference))
    else:
        sc.add_mesh(plotter, mesh)
    if floor and mesh.n_vertices:
        sc.add_floor(plotter, mesh.bounds.mean(0), size=max(2.0, 1.5 * float(np.ptp(mesh.vertices[:, 0]))))
    if title:
        sc.add_title(plotter, title)
    if key_help:
        sc.add_key_help(plotter)
    sc.frame_front(plotter, mesh.bounds)
    return plotter


def scene_for_avatar(avatar: Avatar, plotter=None, bone: str | None = None, skeleton: bool = True,
                     title: str | None = None, key_help: bool = True):
    """A rigged avatar: skin (translucent, or the weights of ``bone``) with bones and joints."""
    plotter = plotter if plotter is not None else sc.make_plotter()
    if bone is not None:
        sc.add_skin_weights(plotter, avatar.mesh, avatar.weights, avatar.bone_names, bone)
    else:
        sc.add_mesh(plotter, avatar.mesh, opacity=0.3 if skeleton else 1.0)
    if skeleton:
        sc.add_skeleton(plotter, avatar.heads, avatar.tails)
    sc.add_floor(plotter, avatar.mesh.bounds.mean(0))
    if title:
        sc.add_title(plotter, title)
    if key_help:
        sc.add_key_help(plotter)
    sc.frame_front(plotter, avatar.mesh.bounds)
    return plotter


def _downsample(image: np.ndarray) -> np.ndarray:
    step = max(1, int(np.ceil(image.shape[1] / MAX_TEXTURE_WIDTH)))
    return image[::step, ::step]


def kinect_points(session, frame, stride: int = 7) -> np.ndarray:
    """The frame's Kinect depth back-projected to studio-frame points (every ``stride``-th pixel)."""
    depth = frame.kinect_depth_m
    sensor = session.kinect
    if depth is None or sensor is None:
        return np.zeros((0, 3))
    v, u = np.mgrid[0:depth.shape[0]:stride, 0:depth.shape[1]:stride]
    d = depth[v, u].ravel()
    ok = d > 0
    uv = np.c_[u.ravel(), v.ravel()][ok].astype(np.float64)
    return sensor.depth.unproject(uv, d[ok])


def reconstructed_mesh_path(session_path: Path, frame_id: int) -> Path | None:
    """The reconstruct stage's mesh of a frame.

    A folder with ``run.json`` is read as one run (checked by
    :func:`bodystudio.reconstruct.sequence.read_reconstruction`: no writer, no interrupted commit, that
    frame's checksum matches); without one, ``reconstruct/**/<name ending in the frame number>.ply``
    outside hidden (staging) folders.
    """
    folder = Path(session_path) / "reconstruct"
    if not folder.is_dir():
        return None
    from bodystudio.reconstruct.sequence import read_reconstruction, reconstruction_layout
    from bodystudio.runfolder import check_readable

    check_readable(reconstruction_layout(session_path))
    if (folder / "run.json").is_file():
        return read_reconstruction(session_path, frame_id)[1].get(frame_id)
    for p in sorted(folder.rglob("*")):
        m = re.search(r"(\d+)$", p.stem)
        if any(part.startswith(".") for part in p.relative_to(folder).parts):
            continue
        if p.suffix.lower() in (".ply", ".obj") and m and int(m.group(1)) == frame_id:
            return p
    return None


def _session_bounds(session, gt: Mesh | None) -> np.ndarray:
    if gt is not None:
        return gt.bounds
    return np.array([[-0.5, 0.0, -0.5], [0.5, 1.9, 0.5]])


FRAME_LAYERS = ("gt", "recon", "kinect", "gt-skeleton-bones", "gt-skeleton-joints")


def _clear_frame_layers(plotter, rig) -> None:
    """Remove the previous frame's layers, so a frame lacking one (no reconstruction) shows none."""
    names = set(plotter.renderer.actors)
    for name in [*FRAME_LAYERS, *(f"camera-{c.name}-image" for c in rig)]:
        if name in names:
            plotter.remove_actor(name)
    if "error (mm)" in plotter.scalar_bars:
        plotter.remove_scalar_bar("error (mm)")


def scene_for_frame(session, frame_id: int, plotter, images: str = "image", cloud: bool = True,
                    skeleton: bool = True):
    """The per-frame layers of a session (replaced when the time slider moves)."""
    if images not in IMAGE_LAYERS:
        raise InputError(f"unknown image layer {images!r}; valid: {', '.join(IMAGE_LAYERS)}")
    frame = session.frame(frame_id)
    rig = session.cameras
    _clear_frame_layers(plotter, rig)
    for cam in rig:
        picture = None
        if images == "image" and cam.name in frame.images:
            picture = _downsample(frame.images[cam.name])
        elif images == "mask" and cam.name in frame.masks:
            picture = _downsample(frame.masks[cam.name])
        if picture is not None:
            sc.add_camera(plotter, cam, picture, far=FRUSTUM_M)
    gt = frame.gt_mesh
    recon_path = reconstructed_mesh_path(session.path, frame_id)
    recon = load_mesh(recon_path) if recon_path is not None else None
    if recon is not None and gt is not None:
        sc.add_mesh(plotter, gt, color=sc.GT_COLOR, opacity=0.25, name="gt")
        sc.add_error_map(plotter, recon, sc.vertex_errors_mm(recon.vertices, gt), name="recon")
    elif recon is not None:
        sc.add_mesh(plotter, recon, name="recon")
    elif gt is not None:
        sc.add_mesh(plotter, gt, color=sc.GT_COLOR, name="gt")
    if cloud:
        sc.add_point_cloud(plotter, kinect_points(session, frame), point_size=2.0, name="kinect", color=KINECT_COLOR)
    joints = frame.gt_joints
    if skeleton and joints is not None:
        sc.add_skeleton(plotter, joints["heads"], joints["tails"], radius=0.005, name="gt-skeleton")
    return plotter


def scene_for_session(session, frame_id: int | None = None, plotter=None, images: str = "image",
                      cloud: bool = True, skeleton: bool = True, title: str | None = None, key_help: bool = True):
    """A capture session at one frame: camera frusta with their images (or silhouettes), the Kinect point
    cloud, the ground-truth mesh and skeleton, and the reconstruction coloured by its error in mm."""
    if not session.frame_ids:
        raise SessionError(f"{session.path}: the session has no frames; regenerate or re-import it")
    frame_id = session.frame_ids[0] if frame_id is None else int(frame_id)
    plotter = plotter if plotter is not None else sc.make_plotter()
    for cam in session.cameras:  # frusta stay when frames change
        sc.add_camera(plotter, cam, None, far=FRUSTUM_M)
    if session.kinect is not None:
        sc.add_camera(plotter, session.kinect.depth, None, far=FRUSTUM_M, color=KINECT_COLOR, name="frustum-kinect")
    scene_for_frame(session, frame_id, plotter, images, cloud, skeleton)
    gt = session.frame(frame_id).gt_mesh
    sc.add_floor(plotter, _session_bounds(session, gt).mean(0), size=4.0)
    sc.add_title(plotter, title or f"{session.path.name}  frame {frame_id}")
    if key_help:
        sc.add_key_help(plotter, sc.KEY_HELP + ("\nslider or n / p: next / previous frame"
                                                if len(session.frame_ids) > 1 else ""))
    centers = np.array([c.center for c in session.cameras]) if len(session.cameras) else np.zeros((0, 3))
    b = _session_bounds(session, gt)
    if len(centers):
        b = np.array([np.minimum(b[0], centers.min(0)), np.maximum(b[1], centers.max(0))])
    sc.frame_front(plotter, b, direction=(0.3, 0.6, 1.0), margin=0.75, fit="sphere")
    return plotter


def add_time_slider(plotter, session, images: str = "image", cloud: bool = True, skeleton: bool = True,
                    frame_id: int | None = None):
    """A slider over the session's frames that swaps the per-frame layers, and keys n / p for the next and
    previous frame (interactive windows)."""
    ids = session.frame_ids
    if len(ids) < 2:
        return plotter

    def show(k: int) -> None:
        scene_for_frame(session, ids[k], plotter, images, cloud, skeleton)
        sc.add_title(plotter, f"{session.path.name}  frame {ids[k]}")

    return sc.add_frame_slider(plotter, ids, ids.index(frame_id) if frame_id in ids else 0, show)


MAX_HTML_FRAMES = 12  # frames exported to HTML (evenly spaced); each carries its meshes and images


def frame_layer_names(plotter, rig) -> set[str]:
    """Names of the actors :func:`scene_for_frame` replaces on every frame."""
    return {*FRAME_LAYERS, *(f"camera-{c.name}-image" for c in rig)}


def session_payload(session, plotter, frame_ids=None, images: str = "image", cloud: bool = True,
                    skeleton: bool = True, max_frames: int = MAX_HTML_FRAMES, start: int | None = None) -> dict:
    """The WebGL payload of a session view with its frames: static actors once, per-frame layers per frame.

    ``plotter`` holds a :func:`scene_for_session` view; it is left showing the exported frame nearest
    ``start`` (the page opens there too).
    """
    from bodystudio.viewer.webgl import scene_payload

    ids = list(session.frame_ids if frame_ids is None else frame_ids)
    if len(ids) > max_frames:
        ids = [ids[int(round(k))] for k in np.linspace(0, len(ids) - 1, max_frames)]
    names = frame_layer_names(plotter, session.cameras)
    frames = []
    for fid in ids:
        scene_for_frame(session, fid, plotter, images, cloud, skeleton)
        layer = scene_payload(plotter, include=names, allow_empty=True)
        frames.append({"id": int(fid), "objects": layer["objects"], "colorBars": layer["colorBars"]})
    k0 = int(np.argmin(np.abs(np.asarray(ids) - (ids[0] if start is None else start))))
    scene_for_frame(session, ids[k0], plotter, images, cloud, skeleton)
    payload = scene_payload(plotter, exclude=names, allow_empty=True)
    payload["colorBars"] = frames[k0]["colorBars"] or next((f["colorBars"] for f in frames if f["colorBars"]), [])
    payload["frames"] = frames
    payload["start"] = k0
    if not payload["objects"] and not any(f["objects"] for f in frames):
        raise sc.EmptySceneError(f"{session.path}: nothing to export; the session has no cameras or meshes")
    return payload


def build_view(path: str | Path | Viewable, bone: str | None = None, frame: int | None = None, images: str = "image",
               off_screen: bool = True, window_size: tuple[int, int] = sc.WINDOW_SIZE,
               reference: str | Path | None = None, cloud: bool = True):
    """The plotter ``bodystudio view`` shows for a path (session, mesh, scan or avatar) or an opened one."""
    item = path if isinstance(path, Viewable) else open_viewable(path)
    if bone is not None and item.kind != "avatar":
        raise InputError(f"{item.path}: --bone needs an avatar (a skinned .glb), this is a {item.kind}")
    if reference is not None and item.kind != "mesh":
        raise InputError(f"{item.path}: --reference colours a mesh or scan by its error; this is a {item.kind}")
    if frame is not None and item.kind not in ("session", "arm", "mirror", "garment"):
        raise InputError(f"{item.path}: --frame picks a session frame; this is a {item.kind}")
    ref = load_mesh(reference) if reference is not None else None
    plotter = sc.make_plotter(off_screen=off_screen, window_size=window_size)
    if item.kind == "session":
        scene_for_session(item.data, frame, plotter, images=images, cloud=cloud)
        if not off_screen:
            add_time_slider(plotter, item.data, images=images, cloud=cloud, frame_id=frame)
    elif item.kind == "arm":
        from bodystudio.viewer.arm import add_arm_time_slider, scene_for_arm_sequence

        scene_for_arm_sequence(item.data, frame, plotter, cloud=cloud)
        if not off_screen:
            add_arm_time_slider(plotter, item.data, cloud=cloud, frame_id=frame)
    elif item.kind == "mirror":
        from bodystudio.viewer.mirror import scene_for_mirror

        scene_for_mirror(item.data, frame, plotter)
    elif item.kind == "garment":
        from bodystudio.viewer.garment import add_garment_time_slider, dress_fitted_body, scene_for_garment

        dressed = dress_fitted_body(item.data)
        scene_for_garment(item.data, frame, plotter, dressed=dressed)
        if not off_screen:
            add_garment_time_slider(plotter, item.data, frame, dressed)
    elif item.kind == "avatar":
        scene_for_avatar(item.data, plotter, bone=bone, title=item.path.name)
    else:
        scene_for_mesh(item.data, plotter, reference=ref, title=item.path.name)
    return plotter
