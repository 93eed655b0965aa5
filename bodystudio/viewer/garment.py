"""The garment stage (issue 13, Garment Replacement in Monocular Video) in the viewer and the report.

A *garment view* opens a garment fit folder (``bodystudio garment fit``; its ``render/`` of ``garment
render`` and its ``eval.json`` when present) or that render folder. It shows

* the **fitted body** of a frame (§4), coloured by the fit's albedo (§5.1), wearing the **garment** of the
  render (or the session's target garment, else a striped T-shirt) with its cloth texture (§6);
* the **light directions** the fit estimated (§5.2, Eq. 7): one arrow per light from the body towards the
  light (``Lighting.directions`` point at the lights), its length proportional to the light's power (the
  brightest light of each set is :data:`ARROW_M` long), plus the power-weighted principal direction as a
  thicker arrow; for a synthetic session the **true** lights too, turned into the fit's world frame
  (joints and lights are compared camera to camera, as ``eval garment`` does);
* a **before/after strip** per frame: the input video frame | the composite of ``garment render`` | the
  true render of the actor wearing the target garment (synthetic sessions); missing panels are left out
  and :func:`missing_panels` says why.

:func:`before_after_strip` is the image (used by the report), :func:`scene_for_garment` the 3D scene.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from bodystudio.errors import BodyStudioError, InputError, SessionError

ARROW_M = 0.6  # length of the brightest light's arrow
ARROW_OFFSET_M = 0.35  # arrows start this far from the chest, outside the body
MIN_LIGHT_FRACTION = 0.02  # lights weaker than this fraction of the brightest are not drawn
MAX_ARROWS = 40  # NNLS leaves a few dozen non-zero lights at most; the brightest are drawn
ESTIMATED_LIGHT_COLOR = (1.0, 0.62, 0.10)
TRUE_LIGHT_COLOR = (0.30, 0.80, 1.00)
PANEL_WIDTH_M = 0.9  # width of one strip panel in the 3D view
PANEL_BEHIND_M = 0.8  # the strip stands this far behind the body
DEFAULT_GARMENT = ("tshirt", "stripes", 0, 256)  # name, pattern, seed, texture size without a render or target
EVAL_JSON = "eval.json"


@dataclass(frozen=True, eq=False)
class GarmentView:
    """A garment fit folder with what is there of its render, source and scores.

    ``render`` is render.json (None when there is no usable render; ``notes`` says why); ``session`` the
    fit's source when it is a session folder; ``saved_scores`` DIR/eval.json when present; ``notes`` one line
    per missing or unusable part.
    """

    fit_dir: Path
    fit: object  # bodystudio.garment.fitfile.GarmentFit
    render: dict | None
    session: object | None  # bodystudio.capture.session.Session
    saved_scores: dict | None
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def render_dir(self) -> Path:
        return self.fit_dir / "render"

    @property
    def name(self) -> str:
        return self.fit_dir.resolve().name

    @property
    def has_source(self) -> bool:
        """Whether the fit's source (a readable session, or a video file) is there to give input frames."""
        return self.session is not None or _source_path(self.fit, self.fit_dir).is_file()


def _json_format(path: Path) -> str | None:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc.get("format") if isinstance(doc, dict) else None


def is_garment_fit(path: str | Path) -> bool:
    """Whether ``path`` is a folder with a garment fit's ``fit.json``."""
    from bodystudio.garment.fitfile import FIT_FORMAT, FIT_JSON

    return _json_format(Path(path) / FIT_JSON) == FIT_FORMAT


def is_garment_render(path: str | Path) -> bool:
    """Whether ``path`` is the ``render/`` folder of ``garment render`` (its parent is the fit)."""
    from bodystudio.garment.composite import RENDER_FORMAT, RENDER_JSON

    return _json_format(Path(path) / RENDER_JSON) == RENDER_FORMAT


def _source_path(fit, fit_dir: Path) -> Path:
    source = Path(fit.source)
    if not source.is_absolute() and not source.exists():
        source = fit_dir / source
    return source


def open_garment_view(path: str | Path) -> GarmentView:
    """A garment fit folder (or its ``render/``): the fit (one-line error when it is damaged), and whatever of
    the render, the source session and ``eval.json`` is there (what is not is said in ``notes``)."""
    from bodystudio.garment.composite import load_render
    from bodystudio.garment.fitfile import load_garment_fit

    path = Path(path)
    if not is_garment_fit(path) and is_garment_render(path):
        path = path.parent
    if not (path / "fit.json").is_file():
        raise SessionError(f"{path}: not a garment fit folder (no fit.json); run 'bodystudio garment fit VIDEO "
                           f"--stature S --out {path}' first")
    fit = load_garment_fit(path)
    notes: list[str] = []
    render = None
    if not (path / "render").exists():
        notes.append(f"no render yet: run 'bodystudio garment render {path} --out OUT.mp4' for the composite")
    else:
        try:
            render = load_render(path)
        except BodyStudioError as exc:
            notes.append(f"render not shown: {exc}")
    session = None
    source = _source_path(fit, path)
    if source.is_dir():
        from bodystudio.capture.session import open_session

        try:
            session = open_session(source)
        except BodyStudioError as exc:
            notes.append(f"the fit's source session is unreadable, no input frames or truth: {exc}")
    elif not source.is_file():
        notes.append(f"the fit's source {source} is gone: no input frames or ground truth")
    saved = None
    eval_path = path / EVAL_JSON
    if eval_path.is_file():
        try:
            saved = json.loads(eval_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            notes.append(f"{eval_path}: not valid JSON ({exc.__class__.__name__}); rerun 'bodystudio eval garment'")
        else:
            if not isinstance(saved, dict):
                notes.append(f"{eval_path}: not a JSON object; rerun 'bodystudio eval garment'")
                saved = None
    return GarmentView(path, fit, render, session, saved, tuple(notes))


def _frame_index(view: GarmentView, frame_id: int) -> int:
    ids = [int(f) for f in view.fit.frame_ids]
    if int(frame_id) not in ids:
        raise InputError(f"--frame {frame_id}: not a frame of the fit {view.fit_dir} (it has {len(ids)} frames, "
                         f"{ids[0]}..{ids[-1]})")
    return ids.index(int(frame_id))


def garment_frames(view: GarmentView, n: int = 3) -> list[int]:
    """Up to ``n`` frames worth showing, evenly spread: frames the render composited (status ``ok``), else the
    frames the fit matched (silhouette IoU >= its gate), else every fitted frame."""
    ids = [int(f) for f in view.fit.frame_ids]
    good = [i for i, ok in zip(ids, view.fit.fitted, strict=True) if ok] or ids
    if view.render is not None:
        done = {int(r["frame"]) for r in view.render.get("frames", [])
                if isinstance(r, dict) and r.get("status") == "ok"}
        good = [i for i in good if i in done] or good
    if len(good) <= n:
        return good
    return [good[int(round(k))] for k in np.linspace(0, len(good) - 1, n)]


# ------------------------------------------------------------------------------------------ lights

def light_power(lighting) -> np.ndarray:
    """(L,) power of each light: the sum of its non-negative RGB intensities (§5.2's ``x_l`` per channel)."""
    return np.clip(np.asarray(lighting.colors, np.float64), 0.0, None).sum(1)


def light_arrows(lighting, origin, length_m: float = ARROW_M, offset_m: float = ARROW_OFFSET_M,
                 min_fraction: float = MIN_LIGHT_FRACTION, max_arrows: int = MAX_ARROWS
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrows of the lights of Eq. 7 (§5.2 of Garment Replacement): ``(starts, vectors, power)``.

    Each drawn light gets an arrow from ``origin + offset_m d_l`` along its direction ``d_l`` (towards the
    light), ``length_m * power_l / max power`` long; lights under ``min_fraction`` of the brightest are left
    out, and at most ``max_arrows`` of the brightest are kept. No light with power: empty arrays.
    """
    d = np.asarray(lighting.directions, np.float64).reshape(-1, 3)
    power = light_power(lighting)
    top = float(power.max(initial=0.0))
    if top <= 0.0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    keep = np.flatnonzero(power >= min_fraction * top)
    keep = keep[np.argsort(-power[keep], kind="stable")][:max_arrows]
    starts = np.asarray(origin, np.float64)[None] + offset_m * d[keep]
    return starts, d[keep] * (length_m * power[keep] / top)[:, None], power[keep]


def true_lighting_in_fit_frame(view: GarmentView):
    """The session's true lights (``gt/lighting.json``) in the fit's world frame, or None without them.

    The fit's world is its own (assumed) camera's: a direction is carried camera to camera,
    ``d_fit = R_fit^T R_true d_true``, as ``eval garment`` compares them."""
    from bodystudio.garment.lighting import Lighting

    session = view.session
    gt = session.gt_lighting if session is not None else None
    if gt is None:
        return None
    cam_gt = session.cameras[session.camera_names[0]]
    truth = Lighting.from_dict(gt, str(Path(session.path) / "gt" / "lighting.json"))
    R = np.asarray(view.fit.camera.R, np.float64).T @ np.asarray(cam_gt.R, np.float64)
    return Lighting(truth.directions @ R.T, truth.colors, truth.ambient)


def add_arrows(plotter, starts: np.ndarray, vectors: np.ndarray, color, name: str, shaft_radius: float = 0.012):
    """Arrows (one merged mesh) from ``starts`` along ``vectors``; nothing when there are none."""
    import pyvista as pv

    parts = []
    for s, v in zip(np.asarray(starts, float), np.asarray(vectors, float), strict=True):
        length = float(np.linalg.norm(v))
        if length < 1e-6:
            continue
        # pyvista scales the unit arrow's radii with its length: keep the shaft width constant in metres
        parts.append(pv.Arrow(start=s, direction=v / length, scale=length, tip_length=min(0.35, 0.08 / length),
                              tip_radius=min(0.5, 2.5 * shaft_radius / length),
                              shaft_radius=min(0.2, shaft_radius / length), shaft_resolution=10, tip_resolution=12))
    if parts:
        mesh = parts[0].merge(parts[1:]) if len(parts) > 1 else parts[0]
        plotter.add_mesh(mesh, color=color, name=name, smooth_shading=True)
    return plotter


def add_lights(plotter, lighting, origin, color, name: str) -> int:
    """The lights of ``lighting`` as arrows around ``origin`` and their principal direction (the power-weighted
    mean direction, ``eval garment``'s ``light_dir_err_deg``) as one thick arrow; returns the arrows drawn."""
    from bodystudio.garment.evaluate import principal_light_direction

    starts, vectors, _ = light_arrows(lighting, origin)
    add_arrows(plotter, starts, vectors, color, name)
    if len(starts):
        d = principal_light_direction(lighting.directions, lighting.colors)
        add_arrows(plotter, [np.asarray(origin, float) + ARROW_OFFSET_M * d], [1.25 * ARROW_M * d], color,
                   f"{name}-principal", shaft_radius=0.025)
    return len(starts)


# ------------------------------------------------------------------------------------------ body, garment

def garment_choice(view: GarmentView) -> tuple[str, str, int, int]:
    """``(garment, pattern, seed, texture size)`` to dress the fitted body in: the render's, else the synthetic
    session's target garment, else :data:`DEFAULT_GARMENT`."""
    r = view.render
    if r is not None and r.get("garment"):
        return str(r["garment"]), str(r.get("texture", "stripes")), int(r.get("seed", 0)), int(
            r.get("texture_size", 512))
    target = (view.session.gt_garment or {}) if view.session is not None else {}
    if "target" in target:
        t = target["target"]
        return str(t["name"]), str(t["pattern"]), int(t.get("seed", 0)), int(target.get("texture_size", 256))
    return DEFAULT_GARMENT


@dataclass(frozen=True, eq=False)
class FittedScene:
    """The fitted body and the garment at one frame (the fit's world frame)."""

    body_vertices: np.ndarray
    body_faces: np.ndarray
    body_colors: np.ndarray | None  # (V, 3) uint8 from the fit's albedo
    garment: object  # bodystudio.garment.garments.Garment
    garment_vertices: np.ndarray
    joints: np.ndarray  # (B, 3) posed bone heads


def fitted_scene(view: GarmentView, frame_id: int, body=None, garment=None) -> FittedScene:
    """Pose the fitted body of ``frame_id`` and the garment of :func:`garment_choice` on it (§4, §6)."""
    from bodystudio.body.skinning import posed_joints
    from bodystudio.garment.garments import dress, pose_garment

    i = _frame_index(view, frame_id)
    fit = view.fit
    body = fit.body() if body is None else body
    if garment is None:
        name, pattern, seed, size = garment_choice(view)
        garment = dress(body, name, pattern, size, seed)
    pose = fit.pose(i)
    V, _ = body.pose(pose)
    colors = None
    if fit.albedo is not None and len(fit.albedo) == len(V):
        a = np.asarray(fit.albedo, np.float64)
        a = a / max(float(np.percentile(a, 99)), 1e-6)  # albedo and light share a scale: show it normalised
        colors = np.clip(np.round(255 * a), 0, 255).astype(np.uint8)
    return FittedScene(V, np.asarray(body.faces), colors, garment, pose_garment(garment, body, pose),
                       posed_joints(body.skeleton, pose)[0])


def light_origin(body_vertices: np.ndarray) -> np.ndarray:
    """Where the light arrows start from: the chest (centre of the body's box, 70 % of its height up)."""
    lo, hi = np.min(body_vertices, axis=0), np.max(body_vertices, axis=0)
    return np.array([(lo[0] + hi[0]) / 2, lo[1] + 0.7 * (hi[1] - lo[1]), (lo[2] + hi[2]) / 2])


def add_textured_mesh(plotter, V: np.ndarray, F: np.ndarray, uv: np.ndarray, texture: np.ndarray, name: str):
    """A mesh with per-vertex texture coordinates (v up) and an RGB texture image (rows top-down)."""
    import pyvista as pv

    from bodystudio.viewer.scene import _rgb_image, polydata

    pd = polydata(V, F)
    pd.active_texture_coordinates = np.asarray(uv, dtype=np.float32)
    img = _rgb_image(np.asarray(texture))
    plotter.add_mesh(pd, texture=pv.numpy_to_texture(img), name=name, smooth_shading=True)
    return plotter


# ------------------------------------------------------------------------------------------ the strip

def input_frames(view: GarmentView, frame_ids) -> dict[int, np.ndarray]:
    """The video frames (H, W, 3) uint8 RGB of ``frame_ids`` from the fit's source (session or video); raises a
    one-line error when the source is gone or unreadable."""
    from bodystudio.garment.composite import source_frames

    ids = [int(f) for f in frame_ids]
    if view.session is not None:
        cam = view.fit.camera.name if view.fit.camera.name in view.session.camera_names else \
            view.session.camera_names[0]
        return {f: view.session.frame(f).images[cam] for f in ids}
    stub = SimpleNamespace(source=view.fit.source, frame_ids=np.asarray(ids), camera=view.fit.camera)
    return dict(zip(ids, source_frames(stub, view.fit_dir), strict=True))


def _read_png(path: Path) -> np.ndarray | None:
    import cv2

    if not path.is_file():
        return None
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if img is None else img[..., ::-1].copy()


def truth_frame(view: GarmentView, frame_id: int) -> np.ndarray | None:
    """The true render of the actor wearing the target garment (``gt/garment_target``), None without one."""
    session = view.session
    if session is None or session.gt_garment is None or int(frame_id) not in session.frame_ids:
        return None
    cam = session.camera_names[0]
    try:
        return session.frame(int(frame_id)).gt_target[cam]
    except (KeyError, BodyStudioError):
        return None


def before_after_panels(view: GarmentView, frame_id: int, frames: dict | None = None
                        ) -> list[tuple[str, np.ndarray]]:
    """``[(caption, rgb)]`` of a frame: input, the composite (when rendered), the truth (synthetic sessions).
    ``frames`` holds input frames already read (:func:`input_frames`)."""
    _frame_index(view, frame_id)
    panels = []
    if frames is not None and frame_id in frames:
        panels.append(("input", frames[frame_id]))
    elif frames is None:
        try:
            panels.append(("input", input_frames(view, [frame_id])[int(frame_id)]))
        except BodyStudioError:
            pass  # the source is gone: view.notes says so
    if view.render is not None:
        out = _read_png(view.render_dir / "frames" / f"{int(frame_id):05d}.png")
        if out is not None:
            panels.append(("composite", out))
    truth = truth_frame(view, frame_id)
    if truth is not None:
        panels.append(("truth", truth))
    if not panels:
        raise SessionError(f"{view.fit_dir}: frame {frame_id} has no input frame, composite or truth to show "
                           f"({'; '.join(view.notes) or 'nothing found'})")
    return panels


def missing_panels(view: GarmentView, frame_id: int, panels) -> list[str]:
    """Which of input | composite | truth a frame's strip lacks, and why (one short phrase each)."""
    have = {c.split(" ")[0] for c, _ in panels}
    out = []
    if "input" not in have:
        out.append("input (the fit's source is gone)")
    if "composite" not in have:
        out.append("composite (no render)" if view.render is None else f"composite (render/frames/{frame_id:05d}.png "
                                                                        "missing)")
    if "truth" not in have:
        out.append("truth (not a synthetic garment session)")
    return out


def caption_image(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` in white on a black box in its top-left corner."""
    import cv2

    out = np.ascontiguousarray(image)
    cv2.rectangle(out, (0, 0), (8 + 9 * len(text), 22), (0, 0, 0), -1)
    cv2.putText(out, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


MIN_STRIP_HEIGHT = 240  # smaller videos are enlarged (whole pixels) so that the captions stay readable


def before_after_strip(view: GarmentView, frame_id: int, frames: dict | None = None) -> np.ndarray:
    """The panels of :func:`before_after_panels` side by side (H, k W, 3) uint8, each captioned (input |
    composite | truth); videos under :data:`MIN_STRIP_HEIGHT` rows are enlarged by a whole factor."""
    panels = before_after_panels(view, frame_id, frames)
    h = min(p.shape[0] for _, p in panels)
    k = max(1, int(np.ceil(MIN_STRIP_HEIGHT / h)))
    return np.concatenate([caption_image(np.array(np.repeat(np.repeat(p[:h], k, 0), k, 1), dtype=np.uint8), c)
                           for c, p in panels], axis=1)


# ------------------------------------------------------------------------------------------ the 3D scene

#: Actors :func:`scene_for_garment_frame` replaces on every frame.
GARMENT_LAYERS = ("fitted-body", "garment", "lights-estimated", "lights-estimated-principal", "lights-true",
                  "lights-true-principal", "garment-strip")


def dress_fitted_body(view: GarmentView):
    """``(body, garment)``: the fitted body (shape only) and the garment of :func:`garment_choice` on it, built
    once per view and reused for every frame."""
    from bodystudio.garment.garments import dress

    body = view.fit.body()
    name, pattern, seed, size = garment_choice(view)
    return body, dress(body, name, pattern, size, seed)


def scene_for_garment_frame(view: GarmentView, frame_id: int, plotter, body=None, garment=None,
                            strip: bool = True) -> tuple[np.ndarray, str]:
    """The per-frame layers (:data:`GARMENT_LAYERS`, the previous frame's removed): the fitted body with its
    albedo, the garment, the estimated lights (orange) and the true ones (blue, synthetic sessions) as arrows
    from the chest, and the before/after strip behind the body. Returns the layers' bounds (2, 3) and the
    frame's title."""
    from bodystudio.geometry.mesh import Mesh
    from bodystudio.viewer import scene as sc
    from bodystudio.viewer.mirror import add_image_panel

    if body is None or garment is None:
        body, garment = dress_fitted_body(view)
    present = set(plotter.renderer.actors)
    for name in GARMENT_LAYERS:
        if name in present:
            plotter.remove_actor(name)
    fs = fitted_scene(view, frame_id, body, garment)
    sc.add_mesh(plotter, Mesh(fs.body_vertices, fs.body_faces, vertex_colors=fs.body_colors), name="fitted-body")
    g = fs.garment
    add_textured_mesh(plotter, fs.garment_vertices, g.faces, g.uv, g.texture, "garment")
    lo, hi = fs.body_vertices.min(0), fs.body_vertices.max(0)
    chest = light_origin(fs.body_vertices)
    what = [f"{g.name} ({garment_choice(view)[1]})"]
    lighting = view.fit.lighting
    if lighting is not None:
        n = add_lights(plotter, lighting, chest, ESTIMATED_LIGHT_COLOR, "lights-estimated")
        what.append(f"{n} estimated light{'s' * (n != 1)} (orange)")
    else:
        what.append("no lights estimated")
    truth = true_lighting_in_fit_frame(view)
    if truth is not None:
        what.append(f"{add_lights(plotter, truth, chest, TRUE_LIGHT_COLOR, 'lights-true')} true (blue)")
    reach = ARROW_OFFSET_M + 1.25 * ARROW_M
    bounds = np.array([np.minimum(lo, chest - reach), np.maximum(hi, chest + reach)])
    if strip:
        try:
            image = before_after_strip(view, frame_id)
        except SessionError:
            image = None
        if image is not None:
            k = image.shape[1] / max(1, image.shape[0]) / (view.fit.camera.width / view.fit.camera.height)
            width = PANEL_WIDTH_M * max(1.0, round(k))
            step = max(1, int(np.ceil(image.shape[1] / 1280)))  # keeps the HTML export light
            z = lo[2] - PANEL_BEHIND_M
            height = width * image.shape[0] / image.shape[1]
            add_image_panel(plotter, image[::step, ::step], (chest[0], lo[1] + height / 2, z), width, "garment-strip")
            bounds = np.array([np.minimum(bounds[0], [chest[0] - width / 2, lo[1], z]),
                               np.maximum(bounds[1], [chest[0] + width / 2, lo[1] + height, hi[2]])])
    return bounds, f"{view.name}  frame {frame_id}: fitted body, " + ", ".join(what)


def scene_for_garment(view: GarmentView, frame_id: int | None = None, plotter=None, key_help: bool = True,
                      strip: bool = True, dressed=None):
    """The garment view of ``frame_id`` (default: a frame the render composited): the layers of
    :func:`scene_for_garment_frame`, a floor, the title and key help, seen from the front and a little above.
    ``dressed`` is :func:`dress_fitted_body`'s pair when the caller has it."""
    from bodystudio.viewer import scene as sc

    frame_id = garment_frames(view, 1)[0] if frame_id is None else int(frame_id)
    plotter = plotter if plotter is not None else sc.make_plotter()
    body, garment = dress_fitted_body(view) if dressed is None else dressed
    bounds, title = scene_for_garment_frame(view, frame_id, plotter, body, garment, strip)
    sc.add_floor(plotter, np.array([bounds.mean(0)[0], 0.0, bounds.mean(0)[2]]), size=3.0)
    sc.add_title(plotter, title)
    if key_help:
        sc.add_key_help(plotter, sc.KEY_HELP + ("\nslider or n / p: next / previous frame"
                                                if len(view.fit.frame_ids) > 1 else ""))
    sc.frame_front(plotter, bounds, direction=(0.35, 0.3, 1.0), margin=0.8, fit="sphere")
    return plotter


def add_garment_time_slider(plotter, view: GarmentView, frame_id: int | None = None, dressed=None):
    """A slider over the fit's frames that swaps the per-frame layers, and keys n / p (interactive windows)."""
    from bodystudio.viewer import scene as sc

    ids = [int(f) for f in view.fit.frame_ids]
    if len(ids) < 2:
        return plotter
    body, garment = dress_fitted_body(view) if dressed is None else dressed

    def show(k: int) -> None:
        _, title = scene_for_garment_frame(view, ids[k], plotter, body, garment)
        sc.add_title(plotter, title)

    return sc.add_frame_slider(plotter, ids, ids.index(frame_id) if frame_id in ids else 0, show)


def garment_payload(view: GarmentView, plotter, max_frames: int | None = None, start: int | None = None,
                    dressed=None) -> dict:
    """The WebGL payload of a garment view with up to ``max_frames`` of the fit's frames (evenly spread; the
    floor once, the body, garment, arrows and strip per frame), opening at the frame nearest ``start``.
    ``plotter`` holds a :func:`scene_for_garment` view."""
    from bodystudio.viewer.views import MAX_HTML_FRAMES
    from bodystudio.viewer.webgl import scene_payload

    max_frames = MAX_HTML_FRAMES if max_frames is None else max_frames
    ids = [int(f) for f in view.fit.frame_ids]
    if len(ids) > max_frames:
        ids = [ids[int(round(k))] for k in np.linspace(0, len(ids) - 1, max_frames)]
    body, garment = dress_fitted_body(view) if dressed is None else dressed
    names = set(GARMENT_LAYERS)
    frames = []
    for fid in ids:
        scene_for_garment_frame(view, fid, plotter, body, garment)
        layer = scene_payload(plotter, include=names, allow_empty=True)
        frames.append({"id": fid, "objects": layer["objects"], "colorBars": layer["colorBars"]})
    first = garment_frames(view, 1)[0] if start is None else int(start)
    k0 = int(np.argmin(np.abs(np.asarray(ids) - first)))
    scene_for_garment_frame(view, ids[k0], plotter, body, garment)
    payload = scene_payload(plotter, exclude=names, allow_empty=True)
    payload["frames"] = frames
    payload["start"] = k0
    return payload
