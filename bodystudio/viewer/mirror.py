"""The mirror (issue 12) in the viewer and the report: before/after frames and the source body.

A *mirror view* opens a Kinect mirror session (``kinect/player`` stream; ``bodystudio synth mirror`` or an
import) or a run folder of ``bodystudio mirror run`` (its ``run.json`` names the session). It shows

* per frame a **before/after strip**: the Kinect colour input, the mirror's output (the run's
  ``frames/NNNNN.png``) and, for synthetic sessions, the truth (``gt/target/rgb``: the actor rendered with
  the edited body); panels that do not exist (no run yet, not synthetic) are left out;
* the **source body** of ``bodystudio mirror init`` (``SESSION/mirror/source_body.npz``) in its rest pose,
  standing in front of the strip; for a run of ``--player N`` (or several ``--player``) each run player's own
  body (``source_body_playerN.npz``, :func:`bodystudio.mirror.run.source_body_path`), side by side.

:func:`before_after_strip` is the image (used by the report), :func:`scene_for_mirror` the 3D scene.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodystudio.errors import InputError, SessionError

MIRROR_RUN_FORMAT = "bodystudio-mirror-run"
PANEL_WIDTH_M = 1.2  # width of one strip panel in the 3D view
PANEL_Z_M = -0.6  # the strip stands behind the source body
SOURCE_BODY_SPACING_M = 0.8  # several run players' bodies stand this far apart


@dataclass(frozen=True)
class MirrorView:
    """A mirror session with (optionally) a run folder and the source body's file."""

    session: object  # capture.session.Session
    run_dir: Path | None
    source_path: Path | None  # the (first) run player's source body; player 1's without a run
    source_paths: tuple = ()  # ((player, Path), ...): the body file of each run player that has one

    @property
    def run(self) -> dict | None:
        return read_run_manifest(self.run_dir) if self.run_dir is not None else None


def read_run_manifest(run_dir: Path) -> dict:
    """``run.json`` of a mirror run folder (one-line FileFormatError-style InputError when it is not one)."""
    path = Path(run_dir) / "run.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable mirror run manifest ({exc.__class__.__name__}); "
                         "re-run `bodystudio mirror run`") from None
    if not isinstance(doc, dict) or doc.get("format") != MIRROR_RUN_FORMAT:
        fmt = doc.get("format") if isinstance(doc, dict) else None
        raise InputError(f"{path}: not a mirror run manifest (format {fmt!r}); give a `bodystudio mirror run` folder")
    return doc


def is_mirror_run(path: Path) -> bool:
    """Whether ``path`` is a folder with a mirror run's ``run.json``."""
    p = Path(path) / "run.json"
    if not p.is_file():
        return False
    try:
        return json.loads(p.read_text(encoding="utf-8")).get("format") == MIRROR_RUN_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def is_mirror_session(path: Path) -> bool:
    """Whether ``path`` is a session folder with the mirror's Kinect player-mask stream."""
    path = Path(path)
    return (path / "session.json").is_file() and (path / "kinect" / "player").is_dir()


def open_mirror_view(path: str | Path) -> MirrorView:
    """A mirror session (its ``mirror/run`` when there is one) or a mirror run folder (its session)."""
    from bodystudio.capture.session import open_session

    path = Path(path)
    if is_mirror_run(path):
        run = read_run_manifest(path)
        session_path = Path(str(run.get("session", "")))
        if not (session_path / "session.json").is_file():
            raise SessionError(f"{path}: the run's session {session_path} is gone; view the session folder instead")
        session, run_dir = open_session(session_path), path
    elif is_mirror_session(path):
        session = open_session(path)
        run_dir = path / "mirror" / "run"
        run_dir = run_dir if is_mirror_run(run_dir) else None
    else:
        raise SessionError(f"{path}: neither a mirror session (kinect/player) nor a mirror run folder (run.json)")
    if run_dir is not None:
        check_run_complete(run_dir)
    players = run_players(read_run_manifest(run_dir) if run_dir is not None else None)
    paths = _source_paths(Path(session.path), players)
    first = dict(paths).get(players[0])
    return MirrorView(session, run_dir, first, paths)


def run_players(run: dict | None) -> list[int]:
    """The players a run reshaped (``players`` of ``mirror run --player 1 --player 2``, else its ``player``), the
    first first; ``[1]`` without a run or for a manifest that names none usable."""
    if not isinstance(run, dict):
        return [1]
    players = run.get("players")
    if not isinstance(players, list) or not players:
        players = [run.get("player", 1)]
    try:
        out = [int(p) for p in players]
    except (TypeError, ValueError):
        return [1]
    return out if all(p >= 1 for p in out) else [1]


def _source_paths(session_path: Path, players: list[int]) -> tuple:
    """``((player, path), ...)`` of the players' source-body files that exist (``mirror init --player N``)."""
    from bodystudio.mirror.run import source_body_path

    found = ((p, Path(source_body_path(session_path, p))) for p in players)
    return tuple((p, path) for p, path in found if path.is_file())


def check_run_complete(run_dir: Path) -> None:
    """Refuse (one line) a run folder that a writer holds, whose write was killed after its commit point, or
    whose files are not the ones its ``run.json`` lists (parts of two runs): before, the viewer and the
    report showed such a folder's frames, old and new mixed. The videos (outside the folder) are not read
    here and not checked."""
    from bodystudio.runfolder import RunLayout, check_readable, verify_run_files

    layout = RunLayout(Path(run_dir), "run.json", ".", str(run_dir))
    check_readable(layout)
    block = read_run_manifest(run_dir).get("run")
    inside = tuple(k for k in (block or {}).get("files", {}) if not k.startswith("..") and not Path(k).is_absolute()) \
        if isinstance(block, dict) else None
    verify_run_files(layout, block, only=inside)


def _read_png(path: Path) -> np.ndarray | None:
    import cv2

    if not path.is_file():
        return None
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if img is None else img[..., ::-1].copy()


def _label(image: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = np.ascontiguousarray(image)
    cv2.rectangle(out, (0, 0), (8 + 9 * len(text), 22), (0, 0, 0), -1)
    cv2.putText(out, text, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def before_after_panels(view: MirrorView, frame_id: int) -> list[tuple[str, np.ndarray]]:
    """``[(caption, rgb)]`` of a frame: input, mirror output (when a run has it), truth (synthetic sessions)."""
    session = view.session
    if frame_id not in session.frame_ids:
        raise InputError(f"--frame {frame_id}: not a frame of {session.path} (it has {len(session.frame_ids)} "
                         f"frames, {session.frame_ids[0]}..{session.frame_ids[-1]})")
    frame = session.frame(frame_id)
    panels = []
    rgb = frame.kinect_rgb
    if rgb is not None:
        panels.append(("input", rgb))
    listed = ((view.run or {}).get("run") or {}).get("files") if view.run_dir is not None else None
    key = f"frames/{frame_id:05d}.png"
    # a frame file the run does not list is a leftover of an earlier, longer run: not this run's output
    if view.run_dir is not None and (not isinstance(listed, dict) or key in listed):
        out = _read_png(view.run_dir / key)
        if out is not None:
            edits = ", ".join(f"{k} {v:+g}" for k, v in (view.run or {}).get("edits", {}).items() if v)
            panels.append((f"mirror ({edits})" if edits else "mirror", out))
    truth = frame.gt_target_rgb
    if truth is not None:
        panels.append(("truth (edited body)", truth))
    if not panels:
        raise SessionError(f"{session.path}: frame {frame_id} has no Kinect colour image; nothing to show")
    return panels


def before_after_strip(view: MirrorView, frame_id: int) -> np.ndarray:
    """The panels of :func:`before_after_panels` side by side (H, k W, 3) uint8, each captioned."""
    panels = before_after_panels(view, frame_id)
    h = min(p.shape[0] for _, p in panels)
    return np.concatenate([_label(p[:h].astype(np.uint8), c) for c, p in panels], axis=1)


def mirror_frames(view: MirrorView, n: int = 4) -> list[int]:
    """Up to ``n`` frames worth showing, evenly spread: frames with a tracked person (the run's player) that
    the run reshaped (``ok``); without a run, every frame with a tracked person."""
    session = view.session
    run = view.run
    player = int((run or {}).get("player", 1))
    ids = list(session.frame_ids)
    if run is not None:
        ok = [int(r["index"]) for r in run.get("frames", []) if isinstance(r, dict) and r.get("status") == "ok"]
        ids = [i for i in ok if i in set(ids)] or ids

    def tracked(i: int) -> bool:
        bodies = session.frame(i).kinect_bodies or []
        return any(int(b.get("player", 0)) == player for b in bodies)

    good = [i for i in ids if tracked(i)] or ids
    if len(good) <= n:
        return good
    return [good[int(round(k))] for k in np.linspace(0, len(good) - 1, n)]


def _player_path(view: MirrorView, player: int | None) -> Path | None:
    if player is None:
        return view.source_path
    return dict(view.source_paths).get(int(player))


def source_body_mesh(view: MirrorView, player: int | None = None):
    """The source body's rest mesh (``geometry.mesh.Mesh``) of the run's (first) player, or of ``player`` (one of
    the run's players), or None before ``mirror init`` (``--player N``)."""
    path = _player_path(view, player)
    if path is None:
        return None
    from bodystudio.body.model import RESOLUTIONS, template_topology
    from bodystudio.geometry.mesh import Mesh
    from bodystudio.mirror.init import load_source_body

    body = load_source_body(path)
    V = np.asarray(body.vertices, np.float64)
    for resolution in RESOLUTIONS:
        ids, F = template_topology(resolution)
        if (13380 if ids is None else len(ids)) == len(V):
            return Mesh(V, np.asarray(F))
    raise InputError(f"{path}: a source body with {len(V)} vertices is in no body template; "
                     "rerun `bodystudio mirror init`")


def source_body_is_the_runs(view: MirrorView, player: int | None = None) -> bool:
    """Whether the session's source body of the run's (first) player, or of ``player``, is the one the run used
    (its ``source_fingerprint``, per player ``source_fingerprints``, in run.json; True when there is no run or the
    run records none): after ``mirror init --force`` the view showed the new body beside frames made with the
    old one."""
    path = _player_path(view, player)
    if view.run_dir is None or path is None:
        return True
    run = view.run or {}
    used = run.get("source_fingerprint")
    if player is not None and isinstance(run.get("source_fingerprints"), dict):
        used = run["source_fingerprints"].get(str(int(player)), used)
    elif player is not None and int(player) != run_players(run)[0]:
        used = None
    if used is None:
        return True
    from bodystudio.mirror.init import load_source_body, source_fingerprint

    return used == source_fingerprint(load_source_body(path))


def add_image_panel(plotter, image: np.ndarray, center, width_m: float, name: str):
    """``image`` as a textured upright rectangle facing +z, ``width_m`` wide, centred at ``center``."""
    import pyvista as pv

    from bodystudio.viewer.scene import _rgb_image

    img = _rgb_image(image)
    h = width_m * img.shape[0] / img.shape[1]
    cx, cy, cz = (float(c) for c in center)
    corners = np.array([[cx - width_m / 2, cy + h / 2, cz], [cx + width_m / 2, cy + h / 2, cz],
                        [cx + width_m / 2, cy - h / 2, cz], [cx - width_m / 2, cy - h / 2, cz]])
    quad = pv.PolyData(corners, faces=np.array([4, 0, 1, 2, 3]))
    quad.active_texture_coordinates = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)
    plotter.add_mesh(quad, texture=pv.numpy_to_texture(img), name=name, lighting=False)
    return plotter


def scene_for_mirror(view: MirrorView, frame_id: int | None = None, plotter=None, key_help: bool = True):
    """The mirror view: the before/after strip of ``frame_id`` (default: a frame the run changed) behind the
    source body in its rest pose."""
    from bodystudio.viewer import scene as sc

    frame_id = mirror_frames(view, 1)[0] if frame_id is None else int(frame_id)
    plotter = plotter if plotter is not None else sc.make_plotter()
    panels = before_after_panels(view, frame_id)
    width = PANEL_WIDTH_M * len(panels)
    strip = before_after_strip(view, frame_id)
    step = max(1, int(np.ceil(strip.shape[1] / 1280)))  # keeps the HTML export light
    add_image_panel(plotter, strip[::step, ::step], (0.0, 1.1, PANEL_Z_M), width, "mirror-strip")
    shown, changed = [], []
    players = [p for p, _ in view.source_paths] or [None]
    for k, player in enumerate(players):  # each run player's own body, side by side (SOURCE_BODY_SPACING_M)
        mesh = source_body_mesh(view, player)
        if mesh is None:
            continue
        if not source_body_is_the_runs(view, player):
            changed.append(player)
            continue
        shift = (k - (len(players) - 1) / 2) * SOURCE_BODY_SPACING_M
        if shift:
            from bodystudio.geometry.mesh import Mesh

            mesh = Mesh(mesh.vertices + np.array([shift, 0.0, 0.0]), mesh.faces)
        sc.add_mesh(plotter, mesh, name="source-body" if k == 0 else f"source-body-player{player}")
        shown.append(player)
    sc.add_floor(plotter, np.zeros(3), size=max(3.0, width))
    several = len(players) > 1
    what = " | ".join(c for c, _ in panels) + (
        "  (source body changed since this run: re-run `bodystudio mirror run`)" if changed and not several
        else f"  (source body of player {', '.join(map(str, changed))} changed since this run: re-run "
             "`bodystudio mirror run`)" if changed
        else f"  + source bodies of players {', '.join(map(str, shown))}" if several and shown
        else f"  + source body of player {shown[0]}" if shown and shown[0] not in (None, 1)
        else "  + source body" if shown else "  (no source body yet)")
    sc.add_title(plotter, f"{Path(view.session.path).name}  frame {frame_id}: {what}")
    if key_help:
        sc.add_key_help(plotter)
    h = 1.1 + 0.5 * width * strip.shape[0] / strip.shape[1]
    sc.frame_front(plotter, np.array([[-width / 2, 0.0, PANEL_Z_M], [width / 2, max(h, 1.9), 0.3]]))
    return plotter
