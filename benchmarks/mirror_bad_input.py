"""rel6a's figures (docs/mirror.md "Bad input"): a mirror session with its Kinect ids swapped, and mid-stream faults.

Usage: PYTHONPATH=. python -m benchmarks.mirror_bad_input renumber SESSION --work DIR [--from 60]
       PYTHONPATH=. python -m benchmarks.mirror_bad_input faults SESSION --work DIR [--frame 25] [--frames 36]

Both plant into a symlink copy of ``SESSION`` (a recorded two-actor / one-actor mirror session with its
``mirror init`` done, e.g. MIR-SYNTH 46 / 47), restamp the manifest and run ``bodystudio mirror run`` as a user does.
``renumber``: ids 1 and 2 swapped in the player masks and joints from frame ``--from`` on; prints ``eval mirror`` of the
clean and the swapped copy (the ground truth's edits) and the run's counts. ``faults``: one fault per copy in frame
``--frame`` of the first ``--frames`` frames (``--no-refine-pose``); prints the exit code, the frame's status and
warning or the error line.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np


def symlink_copy(src: Path, dest: Path, n_frames: int | None = None) -> Path:
    """``dest``: every file of ``src`` a symlink, ``session.json`` a copy (its frames cut to ``n_frames``); no
    ``mirror/run``."""
    shutil.rmtree(dest, ignore_errors=True)
    subprocess.run(["cp", "-rs", str(src.resolve()), str(dest)], check=True)
    shutil.rmtree(dest / "mirror" / "run", ignore_errors=True)
    manifest = json.loads((src / "session.json").read_text())
    if n_frames is not None:
        manifest["frames"] = manifest["frames"][:n_frames]
    (dest / "session.json").unlink()
    (dest / "session.json").write_text(json.dumps(manifest))
    return dest


def put(session: Path, rel: str, data: bytes | None) -> None:
    """Replace (None: delete) ``rel`` in the copy; a replaced file's sha256 goes into the manifest."""
    path = session / rel
    path.unlink()
    if data is None:
        return
    path.write_bytes(data)
    manifest = json.loads((session / "session.json").read_text())
    manifest["files"][rel] = hashlib.sha256(data).hexdigest()
    (session / "session.json").write_text(json.dumps(manifest))


def png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def image(session: Path, rel: str) -> np.ndarray:
    return cv2.imread(str(session / rel), cv2.IMREAD_UNCHANGED)


def joints(session: Path, frame: int, change) -> bytes:
    data = json.loads((session / f"kinect/joints/{frame:05d}.json").read_text())
    change(data)
    if data.get("bodies"):
        first = min(data["bodies"], key=lambda b: b["player"])  # the single-body fields: the lowest id's
        data.update({k: first[k] for k in ("names", "positions", "tracked")})
    return json.dumps(data).encode()


def swap_ids(session: Path, first: int) -> None:
    for f in range(first, len(json.loads((session / "session.json").read_text())["frames"])):
        mask = image(session, f"kinect/player/{f:05d}.png")
        out = mask.copy()
        out[mask == 1], out[mask == 2] = 2, 1
        put(session, f"kinect/player/{f:05d}.png", png(out))

        def swap(data):
            data["bodies"] = [{**b, "player": 3 - b["player"]} for b in data.get("bodies") or []]
        put(session, f"kinect/joints/{f:05d}.json", joints(session, f, swap))


def cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bodystudio.cli.main", *map(str, args)], capture_output=True,
                          text=True)


def renumber(src: Path, work: Path, first: int) -> None:
    edits = json.loads((src / "session.json").read_text())["metadata"].get("edits") or {"taller": 0.1}
    flags = [x for k, v in edits.items() for x in (f"--{k}", str(v))]
    for name in ("clean", "swapped"):
        s = symlink_copy(src, work / name)
        if name == "swapped":
            swap_ids(s, first)
        run = cli("mirror", "run", s, *flags, "--out", work / f"{name}.mp4", "--no-side-by-side")
        if run.returncode:
            print(name, "mirror run exit", run.returncode, run.stderr.strip().splitlines()[-1:])
            continue
        scores = json.loads(cli("eval", "mirror", s).stdout)
        summary = json.loads((s / "mirror" / "run" / "run.json").read_text())["summary"]
        print(name, {k: round(scores[k], 4) for k in ("warp_iou", "fg_iou", "fg_iou_raw", "warp_iou_unwarped")},
              {k: summary.get(k) for k in ("n_ok", "n_empty", "n_passed_through", "n_subject_missing")})


def fault_cases(frame: int) -> dict:
    rel = {k: f"kinect/{k}/{frame:05d}.png" for k in ("rgb", "depth", "player")}
    rel["joints"] = f"kinect/joints/{frame:05d}.json"

    def each(change):
        def plant(s):
            def on_bodies(data):
                for b in data.get("bodies") or []:
                    change(b)
            put(s, rel["joints"], joints(s, frame, on_bodies))
        return plant

    def nan_all(b):
        b["positions"] = [[float("nan")] * 3 for _ in b["positions"]]

    def far(b):
        b["positions"][6] = [1e6, 1.0, 2.0]

    return {
        "clean": lambda s: None,
        "joints: no body": lambda s: put(s, rel["joints"], joints(s, frame, lambda d: d.update(bodies=[]))),
        "joints: all NaN": each(nan_all),
        "joints: a joint at 1e6 m": each(far),
        "joints: file deleted": lambda s: put(s, rel["joints"], None),
        "depth: truncated": lambda s: put(s, rel["depth"], (s / rel["depth"]).read_bytes()[:2000]),
        "depth: 320x240": lambda s: put(s, rel["depth"], png(cv2.resize(image(s, rel["depth"]), (320, 240),
                                                                        interpolation=cv2.INTER_NEAREST))),
        "depth: none measured": lambda s: put(s, rel["depth"], png(np.zeros_like(image(s, rel["depth"])))),
        "depth: file deleted": lambda s: put(s, rel["depth"], None),
        "mask: values 9": lambda s: put(s, rel["player"], png(np.where(image(s, rel["player"]) > 0, 9, 0)
                                                              .astype(np.uint8))),
        "mask: empty": lambda s: put(s, rel["player"], png(np.zeros_like(image(s, rel["player"])))),
        "colour: truncated": lambda s: put(s, rel["rgb"], (s / rel["rgb"]).read_bytes()[:2000]),
        "colour: file deleted": lambda s: put(s, rel["rgb"], None),
    }


def faults(src: Path, work: Path, frame: int, n_frames: int) -> None:
    for k, (name, plant) in enumerate(fault_cases(frame).items()):
        s = symlink_copy(src, work / f"fault{k}", n_frames)
        plant(s)
        run = cli("mirror", "run", s, "--taller", "0.1", "--out", work / f"fault{k}.mp4", "--no-side-by-side",
                  "--no-refine-pose")
        if run.returncode:
            print(f"{name}: exit {run.returncode}: {run.stderr.strip().splitlines()[-1][:200]}")
            continue
        doc = json.loads((s / "mirror" / "run" / "run.json").read_text())
        f = next(r for r in doc["frames"] if r["index"] == frame)
        print(f"{name}: exit 0, frame {frame} {f['status']} {f['warning'] or ''}"[:260])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("renumber", "faults"))
    ap.add_argument("session", type=Path)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--from", dest="first", type=int, default=60)
    ap.add_argument("--frame", type=int, default=25)
    ap.add_argument("--frames", type=int, default=36)
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    if a.what == "renumber":
        renumber(a.session, a.work, a.first)
    else:
        faults(a.session, a.work, a.frame, a.frames)


if __name__ == "__main__":
    main()
