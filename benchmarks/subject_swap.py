"""rel6b's figures (docs/plausibility.md "rel6b"): the Kinect SDK renumbering the subject mid-session, planted in a
real-size reconstruct session and a real-size arm-muscle session.

Usage: PYTHONPATH=. python -m benchmarks.subject_swap reconstruct --work DIR [--frames 8] [--at 4]
       PYTHONPATH=. python -m benchmarks.subject_swap muscle SESSION MODEL --work DIR [--frames 60] [--at 30]

A bystander (the subject's joints 0.8 m to the side and 0.3 m back, no pixels) is tracked in every frame of each copy
(``two``: subject player 1, bystander 2, the reference run), and from frame ``--at`` on:

* ``swap``: the ids exchanged (subject 2, bystander 1; the player mask's subject pixels 1 -> 2);
* ``lost``: the subject not tracked in frame ``--at`` (the bystander alone, holding id 1), then back as player 2.

``reconstruct`` synthesises a 4-camera 640x480 walk (Kinect v2, ``--frames`` frames) and reconstructs each copy per
frame (template 2k); ``muscle`` plants into a symlink copy of an arm session (e.g. /work/musw/seq_501_s0_200) and runs
``muscle capture`` over its first ``--frames`` frames. Each prints, per copy, the exit (or the error line) and the
largest vertex distance to the reference run's result, before and from ``--at`` (0 mm: the subject followed).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

SHIFT = (0.8, 0.0, -0.3)


def symlink_copy(src: Path, dest: Path) -> Path:
    """``dest``: every file of ``src`` a symlink, ``session.json`` a copy."""
    shutil.rmtree(dest, ignore_errors=True)
    subprocess.run(["cp", "-rs", str(src.resolve()), str(dest)], check=True)
    (dest / "session.json").unlink()
    shutil.copy(src / "session.json", dest / "session.json")
    return dest


def _restamp(S: Path, rel: str) -> None:
    from bodystudio.capture.faults import restamp

    restamp(S, rel)


def _write(S: Path, rel: str, text: str | bytes) -> None:
    p = S / rel
    if p.is_symlink():
        p.unlink()
    (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
    _restamp(S, rel)


def _body(data: dict, player: int, shift=(0.0, 0.0, 0.0)) -> dict:
    return {"player": player, "names": data["names"], "tracked": data["tracked"],
            "positions": [None if p[0] is None else [p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]
                          for p in data["positions"]]}


def plant(S: Path, n_frames: int, at: int, case: str) -> None:
    """The bystander in every frame of ``S``; from ``at`` on the ``case`` (``two``: nothing more)."""
    import cv2

    for f in range(n_frames):
        rel = f"kinect/joints/{f:05d}.json"
        data = json.loads((S / rel).read_text())
        first = data["bodies"][0] if data.get("bodies") else data
        subject, bystander = _body(first, 1), _body(first, 2, SHIFT)
        swapped = case in ("swap", "lost") and f >= at
        if swapped:
            subject["player"], bystander["player"] = 2, 1
        bodies = [bystander] if case == "lost" and f == at else [subject, bystander]
        low = min(bodies, key=lambda b: b["player"])
        data.update({k: low[k] for k in ("names", "positions", "tracked")})
        data["bodies"] = bodies
        _write(S, rel, json.dumps(data))
        rel = f"kinect/player/{f:05d}.png"
        if swapped and (S / rel).exists():
            mask = cv2.imread(str(S / rel), cv2.IMREAD_UNCHANGED)
            mask[mask == 1] = 0 if case == "lost" and f == at else 2
            ok, buf = cv2.imencode(".png", mask)
            _write(S, rel, buf.tobytes())


def _distances(V: np.ndarray, ref: np.ndarray, at: int) -> tuple[float, float]:
    d = 1000.0 * np.linalg.norm(V - ref, axis=-1).max(axis=-1)
    return float(d[:at].max()), float(d[at:].max())


def reconstruct(work: Path, n_frames: int, at: int) -> None:
    from bodystudio.capture.synth import synth_session
    from bodystudio.errors import BodyStudioError
    from bodystudio.reconstruct.sequence import read_reconstruction, reconstruct_session

    base = work / "rec_base"
    if not (base / "session.json").exists():
        shutil.rmtree(base, ignore_errors=True)
        synth_session(base, n_cameras=4, n_frames=n_frames, motion="walk", subject_seed=7, kinect="v2",
                      resolution=(640, 480), template="6k")
    meshes = {}
    for case in ("two", "swap", "lost"):
        S = work / f"rec_{case}"
        shutil.rmtree(S, ignore_errors=True)
        shutil.copytree(base, S)
        plant(S, n_frames, at, case)
        try:
            doc = reconstruct_session(S, template="2k")
        except BodyStudioError as exc:
            print(f"reconstruct {case}: refused: {exc}")
            continue
        from bodystudio.geometry.mesh import load_mesh

        paths = read_reconstruction(S)[1]
        V = np.stack([load_mesh(paths[f]).vertices for f in range(n_frames)])
        meshes[case] = V
        print(f"reconstruct {case}: exit 0, subject_players {doc.get('subject_players')}")
    for case in ("swap", "lost"):
        if case in meshes:
            before, after = _distances(meshes[case], meshes["two"], at)
            print(f"reconstruct {case}: max vertex distance to the two-person run: frames <{at} {before:.3f} mm, "
                  f">={at} {after:.3f} mm")


def muscle(session: Path, model: Path, work: Path, n_frames: int, at: int) -> None:
    from bodystudio.errors import BodyStudioError
    from bodystudio.muscle.capture import capture_session_arm

    out = {}
    for case in ("two", "swap", "lost"):
        S = symlink_copy(session, work / f"mus_{case}")
        plant(S, n_frames, at, case)
        try:
            cap = capture_session_arm(S, model, frames=n_frames)
        except BodyStudioError as exc:
            print(f"muscle {case}: refused: {exc}")
            continue
        out[case] = np.asarray(cap.vertices)
        print(f"muscle {case}: exit 0, plausibility ok {cap.plausibility.get('ok') if cap.plausibility else None}")
    for case in ("swap", "lost"):
        if case in out:
            before, after = _distances(out[case], out["two"], at)
            print(f"muscle {case}: max vertex distance to the two-person capture: frames <{at} {before:.3f} mm, "
                  f">={at} {after:.3f} mm")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("reconstruct", "muscle"))
    ap.add_argument("paths", nargs="*", type=Path)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--at", type=int, default=None)
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    if a.what == "reconstruct":
        n = a.frames or 8
        reconstruct(a.work, n, a.at if a.at is not None else n // 2)
    else:
        n = a.frames or 60
        muscle(a.paths[0], a.paths[1], a.work, n, a.at if a.at is not None else n // 2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
