"""Arm-muscle sequences in the viewer: the captured arm coloured by its per-vertex error, with the depth points.

An :class:`ArmSequenceView` holds what a captured arm sequence shows: per-frame vertices in one
topology, the ground truth in the same topology when the session has it (synthetic sequences), and
the session whose Kinect depth frames are drawn as points. ``scene_for_arm_sequence`` draws one frame,
``add_arm_time_slider`` steps through them in a window and ``arm_payload`` exports every frame (evenly
spaced, at most ``MAX_HTML_FRAMES``) to the HTML page, with the same frame slider as sessions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.viewer import scene as sc

ARM_LAYERS = ("arm", "truth-arm", "depth")
DEPTH_COLOR = (0.95, 0.35, 0.85)  # magenta, as the session view's Kinect cloud: not in the error colour map
DEPTH_MARGIN_M = 0.08  # depth points kept within this distance of the arm's bounding box
ERROR_CLIM_MM = (0.0, 10.0)  # one colour scale for every frame, so frames compare


@dataclass(frozen=True)
class ArmSequenceView:
    """What an arm capture shows: ``vertices`` (T, n, 3), ``faces``, optional ``truth`` (T, n, 3)."""

    path: Path
    frame_ids: tuple[int, ...]
    vertices: np.ndarray
    faces: np.ndarray
    truth: np.ndarray | None = None
    session: Any = None  # bodystudio.capture.session.Session for the depth points, or None
    arm_mask: np.ndarray | None = None  # (n,) the tracked arm vertices (the evaluation's), for the title

    def index(self, frame_id: int | None) -> int:
        if frame_id is None:
            return 0
        if int(frame_id) not in self.frame_ids:
            raise InputError(f"{self.path}: no frame {frame_id}; frames are {self.frame_ids[0]}..{self.frame_ids[-1]}")
        return self.frame_ids.index(int(frame_id))

    def errors_mm(self, k: int) -> np.ndarray | None:
        """Per-vertex distance (mm) of frame ``k`` to the truth's same vertex (one topology)."""
        if self.truth is None:
            return None
        return 1000.0 * np.linalg.norm(self.vertices[k] - self.truth[k], axis=1)


def arm_depth_points(view: ArmSequenceView, k: int, stride: int = 2) -> np.ndarray:
    """Frame ``k``'s depth image back-projected (every ``stride``-th pixel), kept near the arm."""
    if view.session is None:
        return np.zeros((0, 3))
    from bodystudio.viewer.views import kinect_points

    points = kinect_points(view.session, view.session.frame(view.frame_ids[k]), stride=stride)
    lo = view.vertices[k].min(0) - DEPTH_MARGIN_M
    hi = view.vertices[k].max(0) + DEPTH_MARGIN_M
    return points[np.all((points >= lo) & (points <= hi), axis=1)]


def _clear_arm_layers(plotter) -> None:
    names = set(plotter.renderer.actors)
    for name in ARM_LAYERS:
        if name in names:
            plotter.remove_actor(name)
    if "error (mm)" in plotter.scalar_bars:
        plotter.remove_scalar_bar("error (mm)")


def scene_for_arm_frame(view: ArmSequenceView, k: int, plotter, cloud: bool = True):
    """Frame ``k``'s layers: the arm (error colours when the truth is known), the truth, the depth points."""
    _clear_arm_layers(plotter)
    mesh = Mesh(view.vertices[k], view.faces)
    err = view.errors_mm(k)
    if err is not None:
        sc.add_mesh(plotter, Mesh(view.truth[k], view.faces), color=sc.GT_COLOR, opacity=0.2, name="truth-arm")
        sc.add_error_map(plotter, mesh, err, clim=ERROR_CLIM_MM, name="arm")
    else:
        sc.add_mesh(plotter, mesh, name="arm")
    if cloud:
        sc.add_point_cloud(plotter, arm_depth_points(view, k), point_size=3.0, name="depth", color=DEPTH_COLOR)
    return plotter


def _title(view: ArmSequenceView, k: int) -> str:
    err = view.errors_mm(k)
    tail = ""
    if err is not None and view.arm_mask is not None and view.arm_mask.shape == err.shape:
        tail = f"  arm median error {np.median(err[view.arm_mask]):.1f} mm"
    elif err is not None:
        tail = f"  median error (all vertices) {np.median(err):.1f} mm"
    return f"{view.path.name}  frame {view.frame_ids[k]}{tail}"


def scene_for_arm_sequence(view: ArmSequenceView, frame_id: int | None = None, plotter=None, cloud: bool = True,
                           title: str | None = None, key_help: bool = True):
    """An arm capture at one frame, framed from the depth sensor's side (the front of the body, +z)."""
    k = view.index(frame_id)
    plotter = plotter if plotter is not None else sc.make_plotter()
    scene_for_arm_frame(view, k, plotter, cloud)
    sc.add_title(plotter, title or _title(view, k))
    if key_help:
        sc.add_key_help(plotter, sc.KEY_HELP + ("\nslider or n / p: next / previous frame"
                                                if len(view.frame_ids) > 1 else ""))
    V = view.vertices.reshape(-1, 3)
    sc.frame_front(plotter, np.stack([V.min(0), V.max(0)]), direction=(0.2, 0.1, 1.0), margin=1.2)
    return plotter


def add_arm_time_slider(plotter, view: ArmSequenceView, cloud: bool = True, frame_id: int | None = None):
    """A frame slider and keys n / p over an arm sequence (interactive windows)."""
    ids = view.frame_ids
    if len(ids) < 2:
        return plotter

    def show(k: int) -> None:
        scene_for_arm_frame(view, k, plotter, cloud)
        sc.add_title(plotter, _title(view, k))

    return sc.add_frame_slider(plotter, ids, view.index(frame_id), show)


def arm_payload(view: ArmSequenceView, plotter, cloud: bool = True, max_frames: int | None = None,
                start: int | None = None) -> dict:
    """The WebGL payload of an arm sequence with its frames (static actors once, per-frame layers per frame)."""
    from bodystudio.viewer.views import MAX_HTML_FRAMES
    from bodystudio.viewer.webgl import scene_payload

    max_frames = MAX_HTML_FRAMES if max_frames is None else max_frames
    ks = list(range(len(view.frame_ids)))
    if len(ks) > max_frames:
        ks = sorted({int(round(k)) for k in np.linspace(0, len(ks) - 1, max_frames)})
    names = set(ARM_LAYERS)
    frames = []
    for k in ks:
        scene_for_arm_frame(view, k, plotter, cloud)
        layer = scene_payload(plotter, include=names, allow_empty=True)
        frames.append({"id": int(view.frame_ids[k]), "objects": layer["objects"], "colorBars": layer["colorBars"]})
    k_start = view.index(start)
    k0 = int(np.argmin(np.abs(np.asarray(ks) - k_start)))
    scene_for_arm_frame(view, ks[k0], plotter, cloud)
    payload = scene_payload(plotter, exclude=names, allow_empty=True)
    payload["colorBars"] = frames[k0]["colorBars"]
    payload["frames"] = frames
    payload["start"] = k0
    return payload


ARM_CAPTURE_FORMAT = "bodystudio-arm-capture"


def is_arm_capture(path: str | Path) -> bool:
    """Whether ``path`` is an arm capture folder (``manifest.json`` of format bodystudio-arm-capture)."""
    import json

    manifest = Path(path) / "manifest.json"
    if not manifest.is_file():
        return False
    try:
        return json.loads(manifest.read_text()).get("format") == ARM_CAPTURE_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def open_arm_view(path: str | Path, session_path: str | Path | None = None) -> ArmSequenceView:
    """An arm capture folder with its session (recorded in params.json) and the session's arm ground truth.

    A session that is gone or has no ground truth still shows the capture (no error colours / points).
    """
    import logging

    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError
    from bodystudio.muscle.capture import load_arm_capture

    path = Path(path)
    capture = load_arm_capture(path)
    session = truth = None
    source = session_path or capture.session_path
    if source is not None:
        try:
            session = open_session(source)
        except BodyStudioError as exc:
            logging.getLogger(__name__).warning("%s: its session is not readable (%s); showing the capture alone",
                                                path, exc)
    arm_mask = None
    if session is not None:
        gts = [session.frame(fid).gt_arm_mesh if fid in session.frame_ids else None for fid in capture.frame_ids]
        if all(g is not None and g.n_vertices == capture.vertices.shape[1] for g in gts):
            truth = np.stack([g.vertices for g in gts])
            from bodystudio.muscle.synthetic import session_arm_template

            try:
                arm_mask = session_arm_template(session).arm_mask
            except BodyStudioError:
                arm_mask = None
    return ArmSequenceView(path, tuple(int(f) for f in capture.frame_ids), capture.vertices, capture.faces,
                           truth, session, arm_mask)
