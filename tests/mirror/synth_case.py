"""Small synthetic mirror sessions shared by the mirror tests (built once per test process, read-only)."""

from __future__ import annotations

import atexit
import functools
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

_ROOT = Path(tempfile.mkdtemp(prefix="bodystudio-mirror-case-"))
atexit.register(shutil.rmtree, _ROOT, True)

#: Frames of the small case: the 10 empty-room frames, then the actor standing in place.
N_FRAMES = 14
TALLER_M = 0.15  # ~ +10 % of an adult's height


@functools.lru_cache(maxsize=4)
def small_mirror_session(taller: float = TALLER_M, actors: int = 1, version: str = "v2") -> Path:
    """A 14-frame mirror session (actor(s) appear in place at frame 10) with a ``taller`` edit."""
    from bodystudio.mirror.synthetic import synth_mirror_session

    path = _ROOT / f"mirror-{taller}-{actors}-{version}"
    synth_mirror_session(path, subject_seed=3, n_frames=N_FRAMES, actors=actors, edits={"taller": taller},
                         version=version, walk_in=False)
    return path


def write_fake_run(session, run_dir, output, foreground, warped, edits=None, player=1, session_path=None,
                   frames=None, extra=None) -> Path:
    """A run folder in the layout of ``bodystudio mirror run`` whose images come from the callables
    ``output(frame)``, ``foreground(frame)``, ``warped(frame)`` (frame: a session Frame)."""
    import cv2

    from bodystudio.runfolder import RunLayout, RunWriter

    run_dir = Path(run_dir)
    layout = RunLayout(run_dir, "run.json", ".", str(run_dir))
    ids = session.frame_ids if frames is None else frames
    with RunWriter(layout, "test fake mirror run", {"stage": "mirror"}) as w:
        rows = []
        for i in ids:
            f = session.frame(i)
            name = f"{i:05d}.png"
            bgr = np.ascontiguousarray(output(f)[..., ::-1])
            w.write_bytes(f"frames/{name}", cv2.imencode(".png", bgr)[1].tobytes())
            for key, fn in (("foreground", foreground), ("warped", warped)):
                w.write_bytes(f"masks/{key}/{name}", cv2.imencode(".png", fn(f).astype(np.uint8) * 255)[1].tobytes())
            rows.append({"index": i, "status": "ok", "warning": None, "ms": {"foreground": 2.0, "warp": 1.0}})
        w.commit({"format": "bodystudio-mirror-run", "version": 1,
                  "session": str(Path(session_path or session.path).resolve()), "session_run_id": None,
                  "edits": dict(session.metadata["edits"] if edits is None else edits), "player": player,
                  "frames": rows, "summary": {"ms_per_frame": {"foreground": 2.0, "warp": 1.0}, "fps_wall": 50.0},
                  **(extra or {})})
    return run_dir


_TRUTH_RUNS: dict = {}


def truth_run(session, path, **kw) -> Path:
    """A fake run (:func:`write_fake_run`) whose images are the ground truth, written once per (session, options)
    and copied to ``path``."""
    key = (str(session.path), json.dumps(kw, sort_keys=True))
    if key not in _TRUTH_RUNS:
        _TRUTH_RUNS[key] = write_fake_run(session, Path(tempfile.mkdtemp(prefix="mirror-truth-run-")) / "run",
                                          lambda f: f.gt_target_rgb, lambda f: f.gt_person == 1,
                                          lambda f: f.gt_target_person == 1, **kw)
    shutil.copytree(_TRUTH_RUNS[key], path)
    return Path(path)


def edit_manifest(run_dir, change) -> Path:
    """Apply ``change`` to the run's run.json (a dict, changed in place) and write it back."""
    p = Path(run_dir) / "run.json"
    run = json.loads(p.read_text())
    change(run)
    p.write_text(json.dumps(run))
    return Path(run_dir)
