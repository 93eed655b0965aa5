"""The self-contained HTML report of a run or session: metrics tables, plots, screenshots, a 3D view.

Stages write their metrics as JSON (calibration report, per-frame reconstruction metrics, rig
evaluation, body measurements). The report reads every metrics JSON under the folder, whatever its
stage, and turns it into tables; it draws a plot only when its data exists:

* error per frame: a table of records with a frame column and error columns (``*err*``, ``*_mm``)
* error histogram: a long list of errors (``*err*``), or per-vertex errors of reconstructed meshes
  against the session's ground truth
* solver convergence: lists named ``*energy*``, ``*cost*``, ``*loss*``, ``*objective*``, ``*history*``,
  ``*convergence*``
* calibration residuals: ``*residual*`` lists (histogram) or per-camera values (bars)

Mirror sessions and mirror run folders (issue 12) get a section of before/after frames (input | mirror
output | truth) and the ``eval mirror`` scores (:func:`mirror_sections`); garment fit folders (issue 13)
one of before/after frames (input | composite | truth) and the ``eval garment`` scores, saying what is
missing when the folder is incomplete (:func:`garment_sections`).

Images are embedded as base64 PNG and the 3D view as inline WebGL (:mod:`bodystudio.viewer.webgl`),
so the page opens from disk without a server or network.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bodystudio.errors import InputError
from bodystudio.fileio import atomic_write
from bodystudio.viewer.scene import render_image
from bodystudio.viewer.webgl import page_head, scene_payload, viewer_fragment

log = logging.getLogger(__name__)

# Session data streams and big inputs are not metrics.
_SKIP_PARTS = re.compile(r"^(cam_[^/]*|kinect|gt|\.staging|calibration_images|background|rgb|mask)$")
_SKIP_NAMES = {"session.json", "cameras.json", "commit.json", "board.json"}
MAX_JSON_BYTES = 2_000_000
MAX_ROWS = 200
MAX_SCREENSHOTS = 12
MAX_PLOTS_PER_FILE = 8
FRAME_KEYS = ("frame", "frame_id", "frame_index", "frame_idx")
_ERR = re.compile(r"err|_mm$|rmse|mae|distance", re.I)
_CONV = re.compile(r"energy|cost|loss|objective|history|convergence", re.I)
_RESID = re.compile(r"residual|reproj", re.I)
_MAIN_ERR = re.compile(r"median|mean|p90|rms", re.I)


@dataclass(frozen=True)
class Table:
    title: str
    columns: list[str]
    rows: list[list[Any]]


@dataclass(frozen=True)
class Plot:
    title: str
    png: bytes


@dataclass(frozen=True)
class ReportResult:
    path: Path
    tables: list[Table] = field(default_factory=list)
    plots: list[Plot] = field(default_factory=list)
    screenshots: list[tuple[str, bytes]] = field(default_factory=list)
    has_3d: bool = False
    mirrors: list = field(default_factory=list)  # MirrorSection per mirror session / run
    garments: list = field(default_factory=list)  # GarmentSection per garment fit folder


def _is_scalar(v: Any) -> bool:
    return v is None or isinstance(v, (bool, int, float, str))


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _is_numeric_list(v: Any) -> bool:
    return isinstance(v, list) and len(v) > 0 and all(_is_number(x) for x in v)


def _is_record(v: Any) -> bool:
    return isinstance(v, dict) and len(v) > 0 and all(_is_scalar(x) for x in v.values())


def flatten_record(record: dict, prefix: str = "", depth: int = 2) -> dict:
    """Scalars of a (nested) dict with dotted keys; lists and deeper levels are left out."""
    out = {}
    for k, v in record.items():
        key = f"{prefix}{k}"
        if _is_scalar(v):
            out[key] = v
        elif isinstance(v, dict) and depth > 0:
            out.update(flatten_record(v, f"{key}.", depth - 1))
    return out


def _record_list(v: Any) -> list[dict] | None:
    """A list of dicts as flat records (None when it is not one)."""
    if not (isinstance(v, list) and v and all(isinstance(r, dict) for r in v)):
        return None
    flat = [flatten_record(r) for r in v]
    return flat if all(flat) else None


def _records_table(title: str, records: list[dict], index_name: str | None = None,
                   index: list[str] | None = None) -> Table:
    columns: list[str] = []
    for r in records:
        columns += [k for k in r if k not in columns]
    rows = [[r.get(c) for c in columns] for r in records[:MAX_ROWS]]
    if index is not None:
        columns = [index_name or ""] + columns
        rows = [[name] + row for name, row in zip(index, rows, strict=False)]
    return Table(title, columns, rows)


def tables_from_json(title: str, data: Any) -> list[Table]:
    """Tables of a metrics JSON: scalars as key/value rows, record lists and record maps as tables."""
    tables: list[Table] = []

    def walk(prefix: str, obj: Any) -> None:
        records = _record_list(obj)
        if records is not None:
            tables.append(_records_table(prefix, records))
            return
        if not isinstance(obj, dict):
            return
        start = len(tables)
        kv: list[list[Any]] = []
        for key, value in obj.items():
            name = f"{prefix} / {key}" if prefix != title else f"{title} / {key}"
            if _is_scalar(value):
                kv.append([str(key), value])
            elif _is_numeric_list(value):
                a = np.asarray(value, dtype=np.float64)
                kv.append([f"{key} (n={len(a)})", f"mean {a.mean():.4g}, min {a.min():.4g}, max {a.max():.4g}"])
            elif isinstance(value, dict) and len(value) > 0 and all(_is_record(v) for v in value.values()):
                tables.append(_records_table(name, list(value.values()), "name", [str(k) for k in value]))
            else:
                walk(name, value)
        if kv:
            tables.insert(start, Table(prefix, ["quantity", "value"], kv))

    walk(title, data)
    return tables


def _series(data: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """Every (key path, value) pair in a JSON tree."""
    out = []
    if isinstance(data, dict):
        for k, v in data.items():
            path = f"{prefix}.{k}" if prefix else str(k)
            out.append((path, v))
            out += _series(v, path)
    elif isinstance(data, list) and data and all(isinstance(x, dict) for x in data):
        for i, v in enumerate(data[:MAX_ROWS]):
            out += _series(v, f"{prefix}[{i}]")
    return out


def _figure_png(fig) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _new_figure(title: str):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    ax.set_title(title, fontsize=11)
    ax.grid(True, alpha=0.3)
    return fig, ax


def _integer_ticks(ax) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _frame_records(data: Any) -> list[tuple[str, list[dict]]]:
    """Lists of per-frame records (each with a frame key) anywhere in a JSON tree."""
    found = []
    candidates = [("", data)] + _series(data)
    for path, v in candidates:
        records = _record_list(v)
        if records is not None:
            if all(any(k in r for k in FRAME_KEYS) for r in records):
                found.append((path, records))
        elif isinstance(v, dict) and v and all(re.fullmatch(r"\d+", str(k)) for k in v) and all(
                _is_record(r) for r in v.values()):
            found.append((path, [{"frame": int(k), **r} for k, r in v.items()]))
    return found


def plots_from_json(name: str, data: Any) -> list[Plot]:
    """The plots a metrics JSON has data for (see the module docstring)."""
    plots: list[Plot] = []
    for path, records in _frame_records(data):
        fkey = next(k for k in FRAME_KEYS if k in records[0])
        frames = [r.get(fkey) for r in records]
        cols = [k for k in records[0] if k != fkey and _ERR.search(k) and all(_is_number(r.get(k)) for r in records)]
        cols.sort(key=lambda c: (not _MAIN_ERR.search(c), "region" in c, c.count(".")))
        if cols and len(records) >= 1:
            fig, ax = _new_figure(f"error per frame: {name}{' ' + path if path else ''}")
            for c in cols[:6]:
                ax.plot(frames, [r[c] for r in records], marker="o", label=c)
            ax.set_xlabel("frame")
            _integer_ticks(ax)
            ax.set_ylabel("error" + (" (mm)" if any(c.endswith("mm") for c in cols) else ""))
            ax.legend(fontsize=8)
            plots.append(Plot(f"Error per frame ({name})", _figure_png(fig)))
    for path, v in _series(data):
        if len(plots) >= MAX_PLOTS_PER_FILE:
            break
        key = path.rsplit(".", 1)[-1]
        if _is_numeric_list(v) and len(v) >= 3 and _CONV.search(key):
            a = np.asarray(v, dtype=np.float64)
            fig, ax = _new_figure(f"solver convergence: {name} {path}")
            ax.plot(np.arange(len(a)), a, marker=".")
            if np.all(a > 0) and a.max() / max(a.min(), 1e-300) > 20:
                ax.set_yscale("log")
            ax.set_xlabel("iteration")
            ax.set_ylabel(key)
            plots.append(Plot(f"Solver convergence ({name}: {path})", _figure_png(fig)))
        elif _is_numeric_list(v) and len(v) >= 10 and (_RESID.search(key) or _ERR.search(key)):
            a = np.asarray(v, dtype=np.float64)
            kind = "Calibration residuals" if _RESID.search(key) else "Error histogram"
            fig, ax = _new_figure(f"{kind.lower()}: {name} {path}")
            ax.hist(a[np.isfinite(a)], bins=40, color="#4a7fb5")
            ax.set_xlabel(key)
            ax.set_ylabel("count")
            plots.append(Plot(f"{kind} ({name}: {path})", _figure_png(fig)))
        elif isinstance(v, dict) and len(v) >= 2 and _RESID.search(key) and all(_is_number(x) for x in v.values()):
            fig, ax = _new_figure(f"calibration residuals: {name} {path}")
            ax.bar(list(map(str, v)), list(v.values()), color="#4a7fb5")
            ax.set_ylabel(key)
            ax.tick_params(axis="x", rotation=45, labelsize=8)
            plots.append(Plot(f"Calibration residuals ({name}: {path})", _figure_png(fig)))
    return plots


def error_histogram(err_mm: np.ndarray, title: str) -> Plot:
    """Histogram of per-vertex errors in millimetres."""
    fig, ax = _new_figure(title)
    err = np.asarray(err_mm, dtype=np.float64)
    ax.hist(err, bins=50, color="#c0504d")
    ax.axvline(float(np.mean(err)), color="k", linestyle="--", label=f"mean {np.mean(err):.1f} mm")
    ax.set_xlabel("error (mm)")
    ax.set_ylabel("vertices")
    ax.legend(fontsize=8)
    return Plot(title, _figure_png(fig))


def metrics_files(root: Path) -> list[Path]:
    """Metrics JSON files under ``root`` (session streams, manifests and camera files left out)."""
    files = []
    for p in sorted(root.rglob("*.json")):
        rel = p.relative_to(root)
        if p.name in _SKIP_NAMES or any(_SKIP_PARTS.match(part) for part in rel.parts[:-1]):
            continue
        if p.name.startswith(".") or p.stat().st_size > MAX_JSON_BYTES:
            continue
        if _is_arm_capture_file(p):  # per-frame poses and transforms: data, not metrics
            continue
        files.append(p)
    return files


def _is_arm_capture_file(p: Path) -> bool:
    from bodystudio.viewer.arm import is_arm_capture

    return p.name in ("params.json", "manifest.json") and is_arm_capture(p.parent)


def screenshot_files(root: Path, exclude: Path | None = None) -> list[Path]:
    """PNG files under ``root`` that are pictures to show (session streams, mirror run frames and a garment
    fit's masks and render frames left out)."""
    from bodystudio.viewer.mirror import is_mirror_run

    runs = [p.parent.resolve() for p in root.rglob("run.json") if is_mirror_run(p.parent)]
    runs += [sub.resolve() for fit in garment_fit_dirs(root) for sub in (fit / "masks", fit / "render")]
    shots = []
    for p in sorted(root.rglob("*.png")):
        rel = p.relative_to(root)
        if any(_SKIP_PARTS.match(part) for part in rel.parts[:-1]) or p.name.startswith("."):
            continue
        if runs and any(r in p.resolve().parents for r in runs):  # per-frame outputs: the mirror section shows them
            continue
        if exclude is not None and p.resolve() == exclude.resolve():
            continue
        shots.append(p)
    return shots[:MAX_SCREENSHOTS]


def _sessions_under(root: Path) -> list[Path]:
    if (root / "session.json").is_file():
        return [root]
    return sorted(p.parent for p in root.glob("*/session.json"))


def session_figures(session_path: Path) -> tuple[list[Plot], list[Table]]:
    """Per-vertex error histogram and per-frame error of reconstructed meshes against the ground truth."""
    from bodystudio.capture.session import open_session
    from bodystudio.geometry.mesh import load_mesh
    from bodystudio.viewer.scene import vertex_errors_mm
    from bodystudio.viewer.views import reconstructed_mesh_path

    session = open_session(session_path)
    errors, rows = [], []
    for fid in session.frame_ids:
        path = reconstructed_mesh_path(session.path, fid)
        gt = session.frame(fid).gt_mesh if path is not None else None
        if path is None or gt is None:
            continue
        err = vertex_errors_mm(load_mesh(path).vertices, gt)
        errors.append(err)
        rows.append([fid, float(err.mean()), float(np.sqrt(np.mean(err ** 2))), float(np.percentile(err, 95)),
                     float(err.max())])
    if not rows:
        return [], []
    table = Table(f"{session.path.name}: reconstruction vs ground truth (per-vertex distance, mm)",
                  ["frame", "mean_mm", "rms_mm", "p95_mm", "max_mm"], rows)
    plots = [error_histogram(np.concatenate(errors), f"Error histogram, {session.path.name}, all frames")]
    if len(rows) > 1:
        fig, ax = _new_figure(f"error per frame: {session.path.name}")
        f = [r[0] for r in rows]
        for k, label in ((1, "mean"), (3, "p95")):
            ax.plot(f, [r[k] for r in rows], marker="o", label=label)
        ax.set_xlabel("frame")
        _integer_ticks(ax)
        ax.set_ylabel("error (mm)")
        ax.legend(fontsize=8)
        plots.insert(0, Plot(f"Error per frame ({session.path.name})", _figure_png(fig)))
    return plots, [table]


MIRROR_FRAMES = 3  # before/after strips per mirror session in the report


@dataclass(frozen=True)
class MirrorSection:
    """The report's mirror section of one session: before/after strips and the eval JSON (or why none)."""

    name: str
    strips: list[tuple[str, bytes]]
    scores: dict | None
    note: str | None


def _mirror_views(root: Path) -> list:
    from bodystudio.viewer.mirror import is_mirror_run, is_mirror_session, open_mirror_view

    if is_mirror_run(root):
        return [open_mirror_view(root)]
    return [open_mirror_view(s) for s in _sessions_under(root) if is_mirror_session(s)]


def mirror_sections(root: Path) -> list[MirrorSection]:
    """Mirror sessions / runs under ``root``: before/after frames (input | mirror | truth) and the scores of
    ``bodystudio eval mirror`` (``SESSION/mirror/eval.json`` when the demo or a user saved it, else computed
    when the session is synthetic and has a run and a source body)."""
    from bodystudio.errors import BodyStudioError
    from bodystudio.viewer.mirror import before_after_strip, mirror_frames

    out = []
    for view in _mirror_views(root):
        session_path = Path(view.session.path)
        strips = []
        for fid in mirror_frames(view, MIRROR_FRAMES):
            strip = before_after_strip(view, fid)
            strips.append((f"{session_path.name} frame {fid}", _png_bytes(strip[::2, ::2])))
        scores, note = None, None
        saved = session_path / "mirror" / "eval.json"
        if saved.is_file():
            from bodystudio.mirror.evaluate import strict_json_scores

            try:
                scores = json.loads(saved.read_text(encoding="utf-8"))
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                note = f"{saved}: not valid JSON ({exc})"
            else:  # an older eval.json may hold Infinity / NaN: shown as null (+ psnr_person_identical)
                scores = strict_json_scores(scores) if isinstance(scores, dict) else None
                note = None if scores is not None else f"{saved}: not a JSON object"
            if scores is not None and view.run_dir is not None and not _scores_of_this_run(scores, view):
                scores = None  # an eval.json of an earlier run or source body: re-scored below
        if scores is None and note is None and view.run_dir is None:
            note = "no mirror run yet (`bodystudio mirror run`)"
        elif scores is None and note is None:
            from bodystudio.mirror.evaluate import evaluate_mirror

            try:
                scores = evaluate_mirror(view.session, view.run_dir)
            except BodyStudioError as exc:
                note = f"not scored: {exc}"
            if saved.is_file():
                note = f"{saved} scores an earlier run or source body; " + (note or "scores recomputed")
        out.append(MirrorSection(session_path.name, strips, scores, note))
    return out


def _scores_of_this_run(scores: dict, view) -> bool:
    """Whether a saved ``eval mirror`` JSON is of the run folder and source body there now (its ``run_id`` and
    ``source_fingerprint``; a file without them predates this check and is not trusted)."""
    from bodystudio.errors import BodyStudioError
    from bodystudio.mirror.init import load_source_body, source_fingerprint

    block = (view.run or {}).get("run")
    if not isinstance(block, dict) or scores.get("run_id") != block.get("run_id"):
        return False
    if view.source_path is None:
        return scores.get("source_fingerprint") is None
    try:
        return scores.get("source_fingerprint") == source_fingerprint(load_source_body(view.source_path))
    except BodyStudioError:
        return False


def _strips_and_scores_html(name: str, strips: list, scores: dict | None, command: str) -> list[str]:
    """One before/after section's body: its strips (caption, PNG bytes) in a grid, then the scores of
    ``command`` as a table and the raw JSON."""
    parts = [f"<h3>{html.escape(name)}</h3><div class=\"grid\">"]
    parts += [f"<figure>{_img_tag(png, cap)}<figcaption>{html.escape(cap)}</figcaption></figure>"
              for cap, png in strips]
    parts.append("</div>")
    if scores is not None:
        rows = [[k, v] for k, v in flatten_record(scores).items()]
        parts.append(_table_html(Table(f"{name}: {command}", ["score", "value"], rows)))
        parts.append(f"<details><summary>eval JSON</summary><pre>"
                     f"{html.escape(json.dumps(scores, indent=2, allow_nan=False))}</pre></details>")
    return parts


def _mirror_html(sections: list[MirrorSection]) -> str:
    parts = ["<h2>Mirror: before / after</h2>",
             '<p class="meta">Each strip: the Kinect input | the mirror\'s output | the truth (the actor rendered '
             "with the edited body; synthetic sessions only).</p>"]
    for m in sections:
        parts += _strips_and_scores_html(m.name, m.strips, m.scores, "eval mirror")
        if m.note:
            parts.append(f'<p class="meta">{html.escape(m.note)}</p>')
    return "\n".join(parts)


GARMENT_FRAMES = 3  # before/after strips per garment fit in the report
GARMENT_SEARCH_DEPTH = 3  # fit.json files this deep under the report's folder are garment fits


def garment_fit_dirs(root: Path) -> list[Path]:
    """Garment fit folders at or under ``root`` (a folder with ``fit.json``; a ``render/`` folder given as
    ``root`` counts as its fit), hidden and session-stream folders left out."""
    from bodystudio.viewer.garment import is_garment_render

    root = Path(root)
    if (root / "fit.json").is_file():
        return [root]
    if is_garment_render(root) and (root.parent / "fit.json").is_file():
        return [root.parent]
    out = []
    for p in sorted(root.rglob("fit.json")):
        parts = p.relative_to(root).parts[:-1]
        if len(parts) > GARMENT_SEARCH_DEPTH or any(q.startswith(".") or _SKIP_PARTS.match(q) for q in parts):
            continue
        out.append(p.parent)
    return out


@dataclass(frozen=True)
class GarmentSection:
    """The report's garment section of one fit folder: before/after strips (input | composite | truth), the
    ``eval garment`` scores and one note per missing or unusable part."""

    name: str
    strips: list[tuple[str, bytes]]
    scores: dict | None
    notes: list[str]


def _strict_json(value):
    """``value`` with non-finite floats as None (the page's JSON is strict; identical images give PSNR inf)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _strict_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_strict_json(v) for v in value]
    return value


def garment_scores(view) -> tuple[dict | None, list[str]]:
    """``(scores, notes)`` of a garment view: the fit folder's saved ``eval.json``, else ``eval garment``'s
    scores computed against the synthetic session (the fit's, then the composite's when rendered); what could
    not be scored is said in the notes."""
    from bodystudio.errors import BodyStudioError
    from bodystudio.garment.composite import composite_errors
    from bodystudio.garment.evaluate import fit_errors, scored_run_ids

    notes = []
    if view.saved_scores is not None:
        now = scored_run_ids(view.fit_dir)
        if all(view.saved_scores.get(k) == v for k, v in now.items()):
            return _strict_json(view.saved_scores), []
        # an eval.json of an earlier fit or render (re-run since) would show its scores beside the new frames
        notes.append(f"{view.fit_dir / 'eval.json'} scores an earlier fit or render (or predates run ids); "
                     "scores recomputed")
    if view.session is None:
        return None, notes + ["not scored: the fit's source is not a session folder; `eval garment` needs a "
                              "synthetic session (`bodystudio synth garment`)"]
    scores = {}
    try:
        scores.update(fit_errors(view.fit, view.session))
    except BodyStudioError as exc:
        notes.append(f"fit not scored: {exc}")
    if view.render is not None:
        try:
            scores.update(composite_errors(view.fit_dir, view.session))
        except BodyStudioError as exc:
            notes.append(f"composite not scored: {exc}")
    return (_strict_json(scores) if scores else None), notes


def garment_sections(root: Path) -> list[GarmentSection]:
    """Garment fit folders under ``root``: before/after frames (input | composite | truth) and the scores of
    ``bodystudio eval garment`` (``DIR/eval.json`` when saved, else computed for a synthetic session). An
    incomplete folder (no render, source gone, damaged fit) gives a section that says what is missing."""
    from bodystudio.errors import BodyStudioError
    from bodystudio.viewer.garment import (
        before_after_panels,
        before_after_strip,
        garment_frames,
        input_frames,
        missing_panels,
        open_garment_view,
    )

    out = []
    for fit_dir in garment_fit_dirs(root):
        name = fit_dir.resolve().name
        try:
            view = open_garment_view(fit_dir)
        except BodyStudioError as exc:
            out.append(GarmentSection(name, [], None, [f"not shown: {exc}"]))
            continue
        notes = list(view.notes)
        frame_ids = garment_frames(view, GARMENT_FRAMES)
        try:
            frames = input_frames(view, frame_ids)
        except BodyStudioError as exc:
            frames = {}
            if view.has_source:  # a source that is gone is in the notes already
                notes.append(f"no input frames: {exc}")
        strips, missing = [], []
        for fid in frame_ids:
            try:
                panels = before_after_panels(view, fid, frames)
            except BodyStudioError as exc:
                notes.append(f"frame {fid}: {exc}")
                continue
            missing += [m for m in missing_panels(view, fid, panels) if m not in missing]
            strip = before_after_strip(view, fid, frames)
            step = 2 if strip.shape[0] >= 480 else 1
            strips.append((f"{name} frame {fid}", _png_bytes(strip[::step, ::step])))
        if missing:
            notes.insert(0, "strips lack: " + "; ".join(missing))
        scores, score_notes = garment_scores(view)
        out.append(GarmentSection(name, strips, scores, notes + score_notes))
    return out


def _garment_html(sections: list[GarmentSection]) -> str:
    parts = ["<h2>Garment: before / after</h2>",
             '<p class="meta">Each strip: the input video frame | the composite of `garment render` (the new garment '
             "on the fitted actor after the image-space refinement) | the truth (the actor rendered wearing the "
             "target garment; synthetic sessions only).</p>"]
    for g in sections:
        parts += _strips_and_scores_html(g.name, g.strips, g.scores, "eval garment")
        parts += [f'<p class="meta garment-note">{html.escape(n)}</p>' for n in g.notes]
    return "\n".join(parts)


def default_scene(root: Path):
    """(plotter, payload or None) the report embeds: an arm capture or a session (every frame), else an avatar,
    else a mesh."""
    from bodystudio.geometry.mesh import MESH_SUFFIXES
    from bodystudio.viewer.arm import arm_payload, is_arm_capture
    from bodystudio.viewer.views import build_view, open_viewable, session_payload

    if is_arm_capture(root):  # an arm capture folder: the sequence with its error colours and depth points
        item = open_viewable(root)
        plotter = build_view(item)
        still = render_image(plotter)
        return plotter, arm_payload(item.data, plotter), still
    found = _garment_scene(root)
    if found is not None:
        return found
    sessions = _sessions_under(root)
    if sessions or (root / "run.json").is_file():
        item = open_viewable(sessions[0] if sessions else root)
        if item.kind in ("session", "mirror"):
            plotter = build_view(item)
            still = render_image(plotter)
            payload = session_payload(item.data, plotter) if item.kind == "session" else scene_payload(plotter)
            return plotter, payload, still
    meshes = [p for p in sorted(root.rglob("*")) if p.suffix.lower() in MESH_SUFFIXES
              and not any(_SKIP_PARTS.match(part) for part in p.relative_to(root).parts[:-1])]
    avatars = [p for p in meshes if open_viewable(p).kind == "avatar"] if meshes else []
    pick = avatars[0] if avatars else (meshes[0] if meshes else None)
    if pick is None:
        return None
    plotter = build_view(pick)
    return plotter, scene_payload(plotter), render_image(plotter)


def _garment_scene(root: Path):
    """The 3D view of the first garment fit under ``root`` that opens (None when there is none)."""
    from bodystudio.errors import BodyStudioError
    from bodystudio.viewer.garment import dress_fitted_body, garment_payload, open_garment_view, scene_for_garment
    from bodystudio.viewer.scene import make_plotter

    for fit_dir in garment_fit_dirs(root):
        try:
            view = open_garment_view(fit_dir)
            dressed = dress_fitted_body(view)
            plotter = scene_for_garment(view, plotter=make_plotter(), dressed=dressed)
            still = render_image(plotter)
            payload = garment_payload(view, plotter, dressed=dressed)
        except BodyStudioError as exc:
            log.warning("%s: no 3D view of the garment fit (%s)", fit_dir, exc)
            continue
        return plotter, payload, still
    return None


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if math.isnan(v):
            return "n/a"
        return f"{v:.4g}"
    return html.escape(str(v))


def _table_html(t: Table) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in t.columns)
    body = "".join("<tr>" + "".join(f'<td class="t">{_fmt(v)}</td>' if isinstance(v, str) else f"<td>{_fmt(v)}</td>"
                                    for v in row) + "</tr>" for row in t.rows)
    return (f'<h3>{html.escape(t.title)}</h3><div class="scroll"><table><thead><tr>{head}</tr></thead>'
            f"<tbody>{body}</tbody></table></div>\n")


def _png_bytes(image: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()


def _img_tag(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode("ascii")}">'


REPORT_CSS = """
body{margin:0 auto;max-width:1150px;padding:12px 20px;font-family:system-ui,sans-serif;color:#222;background:#fafafa}
h1{font-size:22px}h2{font-size:18px;border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:28px}
h3{font-size:14px;margin:16px 0 4px}table{border-collapse:collapse;font-size:13px;margin-bottom:8px}
td,th{border:1px solid #ddd;padding:3px 8px;text-align:right}th{background:#eee}td:first-child,td.t{text-align:left}
.grid{display:flex;flex-wrap:wrap;gap:12px}.grid figure{margin:0}.grid img{max-width:540px;border:1px solid #ddd}
figcaption{font-size:12px;color:#555}.meta{color:#666;font-size:13px}.scroll{overflow-x:auto;max-width:100%}
"""


def write_report(path: str | Path, out: str | Path, with_3d: bool = True, title: str | None = None,
                 scenes: list[tuple[str, Any]] | None = None, notes: list[str] | None = None) -> ReportResult:
    """Write the report of a run or session folder to ``out`` (one self-contained .html file).

    ``scenes`` (caption, plotter or WebGL payload dict) pairs override the embedded 3D views (by default
    a session with all its frames, an avatar or a mesh found under ``path``); ``notes`` are shown at the
    top (e.g. which stages ran).
    """

    root = Path(path)
    out = Path(out)
    if not root.is_dir():
        raise InputError(f"{root}: not a folder; give a run folder (e.g. the demo's output) or a session folder")
    if out.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"{out}: the report is an HTML page; give a path ending in .html")
    tables: list[Table] = []
    plots: list[Plot] = []
    metric_paths = metrics_files(root)
    for f in metric_paths:
        name = str(f.relative_to(root))
        try:
            data = json.loads(f.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            log.warning("%s: skipped, not valid JSON (%s)", f, exc)
            continue
        tables += tables_from_json(name, data)
        plots += plots_from_json(name, data)
    for s in _sessions_under(root):
        p, t = session_figures(s)
        plots += p
        tables += t
    mirrors = mirror_sections(root)
    garments = garment_sections(root)
    shots = [(str(p.relative_to(root)), p.read_bytes()) for p in screenshot_files(root, exclude=out)]
    view_html = ""
    if with_3d:
        if scenes is None:
            found = default_scene(root)
            scenes = []
            if found is not None:
                plotter, payload, still = found
                plotter.close()
                scenes = [("", payload)]
                if not shots:  # a still of the view, for readers without WebGL
                    shots.append(("3D view (rendered)", _png_bytes(still)))
        for k, (caption, scene) in enumerate(scenes):
            if caption:
                view_html += f"<h3>{html.escape(caption)}</h3>"
            payload = scene if isinstance(scene, dict) else scene_payload(scene)
            view_html += viewer_fragment(payload, f"view3d_{k}")
    if not (metric_paths or tables or plots or mirrors or garments or shots or view_html or notes):
        raise InputError(f"{root}: nothing to report (no metrics JSON, session, mirror or garment folder, screenshot "
                         "or 3D scene under it); give a run folder or a session folder"
                         + ("" if with_3d else " (or drop --no-3d: a mesh folder has only its 3D view)"))
    title = title or f"bodystudio report: {root.resolve().name}"
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    parts = [page_head(title, REPORT_CSS), "<body>", f"<h1>{html.escape(title)}</h1>",
             f'<p class="meta">{html.escape(str(root.resolve()))} &middot; {stamp}</p>']
    if notes:
        parts.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    if view_html:
        parts += ["<h2>3D view</h2>", view_html]
    if mirrors:
        parts.append(_mirror_html(mirrors))
    if garments:
        parts.append(_garment_html(garments))
    if shots:
        parts.append("<h2>Screenshots</h2><div class=\"grid\">")
        parts += [f"<figure>{_img_tag(png, name)}<figcaption>{html.escape(name)}</figcaption></figure>"
                  for name, png in shots]
        parts.append("</div>")
    if plots:
        parts.append("<h2>Plots</h2><div class=\"grid\">")
        parts += [f"<figure>{_img_tag(p.png, p.title)}<figcaption>{html.escape(p.title)}</figcaption></figure>"
                  for p in plots]
        parts.append("</div>")
    parts.append("<h2>Metrics</h2>")
    parts += [_table_html(t) for t in tables] or ["<p>No metrics JSON found under this folder.</p>"]
    parts.append("</body></html>\n")
    with atomic_write(out, "w") as fh:
        fh.write("\n".join(parts))
    log.info("wrote %s", out)
    return ReportResult(out, tables, plots, shots, bool(view_html), mirrors, garments)
