"""Scene building on a PyVista plotter: meshes, error heat maps, skeletons, skin weights, cameras, clouds.

Every ``add_*`` function adds actors to a :class:`pyvista.Plotter` and returns it, so the same code path
drives the interactive window, offscreen screenshots and the standalone HTML export. No function here
opens a window; :func:`screenshot` renders offscreen and refuses an empty scene.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from bodystudio.errors import BodyStudioError, InputError
from bodystudio.fileio import atomic_path
from bodystudio.geometry.mesh import Mesh

log = logging.getLogger(__name__)

BACKGROUND = (0.16, 0.17, 0.20)  # solid, so tests can tell drawn pixels from the background
BACKGROUND_RGB = tuple(int(round(255 * c)) for c in BACKGROUND)
MESH_COLOR = (0.85, 0.78, 0.70)
GT_COLOR = (0.55, 0.75, 0.95)
BONE_COLOR = (0.95, 0.85, 0.20)
JOINT_COLOR = (0.95, 0.30, 0.20)
ERROR_CMAP = "turbo"
WEIGHT_CMAP = "coolwarm"
WINDOW_SIZE = (1024, 768)

KEY_HELP = ("mouse: rotate / shift+drag: pan / wheel: zoom\n"
            "r: reset view   s: surface   w: wireframe   q: quit")


class EmptySceneError(BodyStudioError):
    """The scene has nothing visible to draw."""


def _prefer_egl_offscreen() -> None:
    """Without an X display, ask VTK for its EGL window straight away instead of failing over from X."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def make_plotter(off_screen: bool = True, window_size: tuple[int, int] = WINDOW_SIZE):
    """A plotter with the viewer's background; ``off_screen`` needs no display (EGL / OSMesa)."""
    if off_screen:
        _prefer_egl_offscreen()
    import pyvista as pv

    plotter = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    plotter.set_background(BACKGROUND)
    return plotter


def polydata(vertices: np.ndarray, faces: np.ndarray):
    """A :class:`pyvista.PolyData` triangle mesh from ``(n, 3)`` vertices and ``(m, 3)`` faces."""
    import pyvista as pv

    faces = np.asarray(faces, dtype=np.int64)
    cells = np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces]).ravel()
    return pv.PolyData(np.asarray(vertices, dtype=np.float64), cells)


def add_mesh(plotter, mesh: Mesh, color=MESH_COLOR, opacity: float = 1.0, name: str = "mesh"):
    """A shaded mesh; per-vertex colours of the mesh are used when present."""
    pd = polydata(mesh.vertices, mesh.faces)
    if mesh.vertex_colors is not None and len(mesh.vertex_colors) == mesh.n_vertices:
        pd.point_data["rgb"] = np.asarray(mesh.vertex_colors, dtype=np.uint8)[:, :3]
        plotter.add_mesh(pd, scalars="rgb", rgb=True, opacity=opacity, name=name, smooth_shading=True)
    else:
        plotter.add_mesh(pd, color=color, opacity=opacity, name=name, smooth_shading=True)
    return plotter


def vertex_errors_mm(vertices: np.ndarray, reference: Mesh) -> np.ndarray:
    """Distance (mm) of each vertex to the nearest point of the reference surface."""
    import igl

    sq, _, _ = igl.point_mesh_squared_distance(np.asarray(vertices, dtype=np.float64), reference.vertices,
                                               reference.faces)
    return 1000.0 * np.sqrt(np.maximum(sq, 0.0))


def add_error_map(plotter, mesh: Mesh, err_mm: np.ndarray, clim: tuple[float, float] | None = None,
                  title: str = "error (mm)", name: str = "error"):
    """A per-vertex error heat map with a millimetre colour bar."""
    err_mm = np.asarray(err_mm, dtype=np.float64).ravel()
    if len(err_mm) != mesh.n_vertices:
        raise InputError(f"error map has {len(err_mm)} values for {mesh.n_vertices} vertices")
    if clim is None:
        top = float(np.percentile(err_mm, 98)) if len(err_mm) else 1.0
        clim = (0.0, max(top, 1e-3))
    pd = polydata(mesh.vertices, mesh.faces)
    pd.point_data[title] = err_mm
    plotter.add_mesh(pd, scalars=title, cmap=ERROR_CMAP, clim=list(clim), name=name, smooth_shading=True,
                     scalar_bar_args=_bar_args(title))
    return plotter


def _bar_args(title: str) -> dict:
    return dict(title=title, vertical=True, position_x=0.86, position_y=0.2, width=0.08, height=0.6,
                n_labels=5, fmt="%.1f", color="white", title_font_size=14, label_font_size=12)


def add_skin_weights(plotter, mesh: Mesh, weights: np.ndarray, bone_names, bone: str, name: str = "weights"):
    """The skin weights of one bone as a colour map over the mesh."""
    bone_names = tuple(bone_names)
    if bone not in bone_names:
        raise InputError(f"unknown bone {bone!r}; valid bones: {', '.join(bone_names)}")
    w = np.asarray(weights)[:, bone_names.index(bone)]
    pd = polydata(mesh.vertices, mesh.faces)
    title = f"weight {bone}"
    pd.point_data[title] = w.astype(np.float64)
    plotter.add_mesh(pd, scalars=title, cmap=WEIGHT_CMAP, clim=[0.0, 1.0], name=name, smooth_shading=True,
                     scalar_bar_args={**_bar_args(title), "fmt": "%.2f"})
    return plotter


def add_skeleton(plotter, heads: np.ndarray, tails: np.ndarray, radius: float = 0.008, name: str = "skeleton"):
    """Bones as tubes from head to tail and joints (bone heads) as spheres."""
    import pyvista as pv

    heads = np.asarray(heads, dtype=np.float64).reshape(-1, 3)
    tails = np.asarray(tails, dtype=np.float64).reshape(-1, 3)
    if len(heads) == 0:
        return plotter
    B = len(heads)
    points = np.vstack([heads, tails])
    lines = np.column_stack([np.full(B, 2), np.arange(B), np.arange(B) + B]).ravel()
    bones = pv.PolyData(points, lines=lines)
    plotter.add_mesh(bones.tube(radius=radius, n_sides=8), color=BONE_COLOR, name=f"{name}-bones")
    joints = pv.PolyData(heads).glyph(geom=pv.Sphere(radius=radius * 1.8, theta_resolution=10, phi_resolution=10),
                                      scale=False, orient=False)
    plotter.add_mesh(joints, color=JOINT_COLOR, name=f"{name}-joints")
    return plotter


def add_point_cloud(plotter, points: np.ndarray, colors: np.ndarray | None = None, point_size: float = 3.0,
                    name: str = "cloud", color=(0.3, 0.9, 0.5)):
    """A point cloud (e.g. Kinect depth back-projected), optionally with uint8 RGB colours."""
    import pyvista as pv

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) == 0:
        return plotter
    cloud = pv.PolyData(points)
    if colors is not None and len(colors) == len(points):
        cloud.point_data["rgb"] = np.asarray(colors, dtype=np.uint8)[:, :3]
        plotter.add_mesh(cloud, scalars="rgb", rgb=True, point_size=point_size, style="points", name=name)
    else:
        plotter.add_mesh(cloud, color=color, point_size=point_size, style="points", name=name)
    return plotter


def add_camera(plotter, camera, image: np.ndarray | None = None, near: float = 0.05, far: float = 0.35,
               color=(0.9, 0.9, 0.9), name: str | None = None):
    """A camera as a frustum (lines from the optical centre to the far image corners) with its image.

    ``image`` (H, W) or (H, W, 3) is drawn as a texture on the far rectangle; masks show as grey.
    """
    import pyvista as pv

    name = name or f"camera-{camera.name}"
    corners = camera.frustum(near, far)[4:]  # image corners (0,0), (W,0), (W,H), (0,H) at ``far``
    center = np.asarray(camera.center, dtype=np.float64)
    points = np.vstack([center, corners])
    lines = np.array([2, 0, 1, 2, 0, 2, 2, 0, 3, 2, 0, 4, 5, 1, 2, 3, 4, 1])
    plotter.add_mesh(pv.PolyData(points, lines=lines), color=color, line_width=2, name=name)
    if image is not None:
        quad = pv.PolyData(corners, faces=np.array([4, 0, 1, 2, 3]))
        # Texture rows run bottom-up, image rows top-down: corner (0,0) is the image's top-left.
        quad.active_texture_coordinates = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)
        plotter.add_mesh(quad, texture=pv.numpy_to_texture(_rgb_image(image)), name=f"{name}-image",
                         lighting=False)
    return plotter


def _rgb_image(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    elif np.issubdtype(img.dtype, np.floating):
        img = np.clip(img * (255.0 if img.max(initial=0) <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    img = img.astype(np.uint8)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3])


def add_cameras(plotter, cameras, images: dict | None = None, near: float = 0.05, far: float = 0.35):
    """Every camera of a rig (anything iterable over cameras) with its image when given."""
    for camera in cameras:
        plotter = add_camera(plotter, camera, None if images is None else images.get(camera.name), near, far)
    return plotter


def add_floor(plotter, center: np.ndarray, size: float = 3.0, name: str = "floor"):
    """A faint grid on y = 0 for orientation."""
    import pyvista as pv

    plane = pv.Plane(center=(float(center[0]), 0.0, float(center[2])), direction=(0, 1, 0), i_size=size,
                     j_size=size, i_resolution=12, j_resolution=12)
    plotter.add_mesh(plane, color=(0.45, 0.45, 0.5), style="wireframe", opacity=0.35, name=name)
    return plotter


def add_key_help(plotter, text: str = KEY_HELP):
    """On-screen key help in the lower left corner."""
    plotter.add_text(text, position="lower_left", font_size=9, color="white", name="key-help")
    return plotter


def add_title(plotter, text: str):
    plotter.add_text(text, position="upper_left", font_size=11, color="white", name="title")
    return plotter


def frame_front(plotter, bounds: np.ndarray | None = None, direction=(0.0, 0.15, 1.0), margin: float = 1.1,
                fit: str = "box"):
    """Point the plotter's camera at ``bounds`` (2, 3) from the front (+z, the body faces +z), y up.

    ``fit="box"`` fits the box's height and width to the window (front views); ``"sphere"`` fits its
    bounding sphere (any direction). ``margin`` scales the distance (below 1 crops the edges).
    """
    if bounds is None:
        b = np.asarray(plotter.bounds, dtype=np.float64)
        bounds = np.array([[b[0], b[2], b[4]], [b[1], b[3], b[5]]])
    bounds = np.asarray(bounds, dtype=np.float64)
    center = bounds.mean(0)
    radius = 0.5 * float(np.linalg.norm(bounds[1] - bounds[0]))
    d = np.asarray(direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    view_angle = np.radians(plotter.camera.view_angle)
    if fit == "sphere":
        distance = margin * max(radius, 1e-3) / np.sin(view_angle / 2)
    else:
        width, height = plotter.window_size
        half_h = np.tan(view_angle / 2)
        half_w = half_h * width / height
        size = bounds[1] - bounds[0]
        distance = margin * max(size[1] / 2 / half_h, max(size[0], size[2]) / 2 / half_w, 1e-3) + size[2] / 2
    plotter.camera_position = [tuple(center + distance * d), tuple(center), (0.0, 1.0, 0.0)]
    plotter.reset_camera_clipping_range()
    return plotter


def visible_points(plotter) -> int:
    """Number of points over the plotter's visible 3D actors (0 means an empty scene)."""
    total = 0
    for actor in plotter.renderer.actors.values():
        if not hasattr(actor, "GetMapper") or not actor.GetVisibility():
            continue
        mapper = actor.GetMapper()
        data = mapper.GetInput() if mapper is not None else None
        if data is not None and hasattr(data, "GetNumberOfPoints"):
            total += int(data.GetNumberOfPoints())
    return total


def render_image(plotter) -> np.ndarray:
    """Render offscreen to an (H, W, 3) uint8 array; an empty scene raises :class:`EmptySceneError`."""
    if visible_points(plotter) == 0:
        raise EmptySceneError("nothing to draw: the scene is empty; give a mesh, avatar or session with data")
    img = plotter.screenshot(return_img=True)
    if img is None or np.all(np.abs(img[..., :3].astype(int) - BACKGROUND_RGB).max(-1) <= 2):
        raise EmptySceneError("the rendered image is blank: nothing in the scene is in view")
    return np.asarray(img[..., :3], dtype=np.uint8)


def save_screenshot(plotter, path: str | Path) -> np.ndarray:
    """Render offscreen and write a PNG atomically; returns the image."""
    from PIL import Image

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: screenshots are PNG; give a path ending in .png")
    img = render_image(plotter)
    with atomic_path(path) as tmp:
        Image.fromarray(img).save(tmp, format="PNG")
    log.info("wrote %s (%dx%d)", path, img.shape[1], img.shape[0])
    return img


def project_to_screen(plotter, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (N, 2) (x right, y down from the top-left) of world points in the plotter's view."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    renderer = plotter.renderer
    width, height = plotter.window_size
    cam = renderer.GetActiveCamera()
    aspect = width / height
    M = np.array([[cam.GetCompositeProjectionTransformMatrix(aspect, -1, 1).GetElement(i, j) for j in range(4)]
                  for i in range(4)])
    P = np.c_[points, np.ones(len(points))] @ M.T
    ndc = P[:, :3] / P[:, 3:4]
    x = (ndc[:, 0] + 1) / 2 * width
    y = (1 - (ndc[:, 1] + 1) / 2) * height
    return np.c_[x, y]


def add_frame_slider(plotter, frame_ids, start: int, show):
    """A frame slider over ``frame_ids`` and keys n / p for the next / previous frame (interactive windows);
    ``show(k)`` draws the frame at index ``k``."""
    ids = list(frame_ids)
    state = {"k": start}

    def draw(k: int) -> None:
        state["k"] = k
        show(k)

    slider = plotter.add_slider_widget(lambda value: draw(int(np.argmin(np.abs(np.asarray(ids) - value)))),
                                       [ids[0], ids[-1]], value=ids[start], title="frame", fmt="%.0f",
                                       pointa=(0.25, 0.92), pointb=(0.75, 0.92), style="modern")

    def step(delta: int) -> None:
        k = min(max(state["k"] + delta, 0), len(ids) - 1)
        slider.GetRepresentation().SetValue(ids[k])
        draw(k)
        plotter.render()

    plotter.add_key_event("n", lambda: step(1))
    plotter.add_key_event("p", lambda: step(-1))
    return plotter
