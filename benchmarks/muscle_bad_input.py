"""rel6b's audit of the arm-muscle capture's mid-stream faults (docs/muscle.md "Bad input", rel6b).

Usage: PYTHONPATH=. python -m benchmarks.muscle_bad_input SESSION MODEL --work DIR [--frames 20] [--frame 10]

Each fault is planted in frame ``--frame`` of a symlink copy of ``SESSION`` (a real-size arm session, e.g.
/work/musw/seq_501_s0_200; the manifest restamped) and ``bodystudio muscle capture COPY --model MODEL --frames N``
runs as a user runs it. Printed per fault: the exit code, the last stderr line, whether the output folder exists, and
for a capture that was written the largest vertex distance (mm) to the clean copy's capture in the faulty frame and
elsewhere. ``kill``: the clean copy's capture SIGKILLed at its params.json write (tests/reliability/kill_harness.py).

rel7a: bad frames are skipped (``muscle capture --skip-bad-frames``, the default). ``skip1`` (the depth PNG of frame
F truncated), ``skip3`` (F truncated, F+4 the elbow null, F+8 the arm out of the depth window), ``run5`` (the arm
out of the depth window in frames F..F+4) and ``run6`` (F..F+5: refused) are scored against the session's ground truth
on the captured frames, beside the clean capture on the same frames (``eval muscle``'s median / p90 mm), with the
largest vertex distance to the clean capture there and the median error of the 3 frames after the gap.
Usage for these: ``... --faults clean,skip1,skip3,run5,run6 --frames 200 --frame 100``.
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

from benchmarks.subject_swap import symlink_copy


def _restamp(S: Path, rel: str) -> None:
    m = json.loads((S / "session.json").read_text())
    if (S / rel).exists():
        m["files"][rel] = hashlib.sha256((S / rel).read_bytes()).hexdigest()
    (S / "session.json").write_text(json.dumps(m))


def _replace(S: Path, rel: str, data: bytes | None) -> None:
    p = S / rel
    if p.is_symlink() or p.exists():
        p.unlink()
    if data is not None:
        p.write_bytes(data)
        _restamp(S, rel)


def _png(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def plant(S: Path, fault: str, f: int) -> None:
    depth, joints = f"kinect/depth/{f:05d}.png", f"kinect/joints/{f:05d}.json"
    raw = cv2.imread(str(S / depth), cv2.IMREAD_UNCHANGED)
    if fault == "depth_truncated":
        data = (S / depth).read_bytes()
        _replace(S, depth, data[: len(data) // 2])
    elif fault == "depth_size":
        _replace(S, depth, _png(cv2.resize(raw, (raw.shape[1] // 2, raw.shape[0] // 2),
                                           interpolation=cv2.INTER_NEAREST)))
    elif fault == "depth_8bit":
        _replace(S, depth, _png((raw // 256).astype(np.uint8)))
    elif fault == "depth_missing":
        _replace(S, depth, None)
    elif fault == "joints_nan":
        data = json.loads((S / joints).read_text())
        body = data["bodies"][0] if data.get("bodies") else data
        body["positions"][body["names"].index("ElbowLeft")] = [None, None, None]
        _replace(S, joints, json.dumps(data).encode())
    elif fault == "joints_untracked":
        data = json.loads((S / joints).read_text())
        body = data["bodies"][0] if data.get("bodies") else data
        body["tracked"] = [False] * len(body["tracked"])
        _replace(S, joints, json.dumps(data).encode())
    elif fault == "joints_missing":
        _replace(S, joints, None)
    elif fault in ("arm_out", "run5", "run6"):  # the arm leaves the view: no depth reading (the tracker goes on)
        for k in range(f, f + {"arm_out": 3, "run5": 5, "run6": 6}[fault]):
            rel = f"kinect/depth/{k:05d}.png"
            _replace(S, rel, _png(np.zeros_like(cv2.imread(str(S / rel), cv2.IMREAD_UNCHANGED))))
    elif fault == "skip1":
        plant(S, "depth_truncated", f)
    elif fault == "skip3":
        plant(S, "depth_truncated", f)
        plant(S, "joints_nan", f + 4)
        rel = f"kinect/depth/{f + 8:05d}.png"
        _replace(S, rel, _png(np.zeros_like(cv2.imread(str(S / rel), cv2.IMREAD_UNCHANGED))))
    elif fault != "clean":
        raise ValueError(fault)


def _capture(S: Path, model: Path, out: Path, n: int) -> subprocess.CompletedProcess:
    shutil.rmtree(out, ignore_errors=True)
    return subprocess.run([sys.executable, "-m", "bodystudio.cli.main", "muscle", "capture", str(S), "--model",
                           str(model), "--out", str(out), "--frames", str(n)], capture_output=True, text=True)


def _meshes(out: Path) -> np.ndarray:
    from bodystudio.geometry.mesh import load_mesh

    return np.stack([load_mesh(p).vertices for p in sorted((out / "meshes").glob("*.ply"))])


FAULTS = ("clean", "depth_truncated", "depth_size", "depth_8bit", "depth_missing", "joints_nan", "joints_untracked",
          "joints_missing", "arm_out")
SKIPPED = ("skip1", "skip3", "run5", "run6")


def score_on_frames(out: Path, session: Path, frame_ids: list[int] | None = None) -> dict:
    """``eval muscle``'s figures of the capture in ``out`` against ``session``'s truth, on ``frame_ids`` only (None:
    the capture's frames), and the per-frame median error (mm) by frame id."""
    from dataclasses import replace

    from bodystudio.capture.session import open_session
    from bodystudio.muscle.capture import load_arm_capture
    from bodystudio.muscle.evaluate import evaluate_arm_capture, session_ground_truth
    from bodystudio.muscle.synthetic import session_arm_template

    cap = load_arm_capture(out)
    s = open_session(session)
    template = session_arm_template(s)
    if frame_ids is not None:
        keep = [cap.frame_ids.index(f) for f in frame_ids]
        cap = replace(cap, vertices=cap.vertices[keep], frame_ids=list(frame_ids), frame_positions=[
            cap.positions[k] for k in keep], skipped=[])
    scores = evaluate_arm_capture(cap, s, template)
    G = session_ground_truth(s, template, list(cap.frame_ids))[0]
    per_frame = np.median(np.linalg.norm(cap.vertices - G, axis=2)[:, template.arm_mask], axis=1) * 1000.0
    return {"scores": scores, "per_frame": dict(zip(cap.frame_ids, per_frame.tolist(), strict=True)),
            "vertices": dict(zip(cap.frame_ids, cap.vertices, strict=True)), "skipped": cap.skipped}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("session", type=Path)
    ap.add_argument("model", type=Path)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--frame", type=int, default=10)
    ap.add_argument("--faults", default=",".join(FAULTS) + ",kill")
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    clean = None
    for fault in a.faults.split(","):
        S = symlink_copy(a.session, a.work / f"S_{fault}")
        out = a.work / f"out_{fault}"
        if fault == "kill":
            from tests.reliability.kill_harness import run_child

            shutil.rmtree(out, ignore_errors=True)
            r = run_child(["muscle", "capture", str(S), "--model", str(a.model), "--out", str(out), "--frames",
                           str(a.frames)], cwd=a.work, after_match="params.json", timeout=1200)
            left = sorted(p.name for p in a.work.iterdir() if p.name.startswith(".out_kill"))
            print(f"kill: rc {r.returncode}, out exists {out.exists()}, left {left}")
            r = _capture(S, a.model, out, a.frames)
            print(f"kill, rerun: rc {r.returncode}, out exists {out.exists()}; {r.stderr.strip()[-200:]}")
            continue
        plant(S, fault, a.frame)
        r = _capture(S, a.model, out, a.frames)
        last = (r.stderr.strip().splitlines() or [""])[-1]
        line = f"{fault}: rc {r.returncode}, out exists {out.exists()}; {last[:400]}"
        if fault == "clean" and r.returncode == 0 and any(f in SKIPPED for f in a.faults.split(",")):
            clean_run = (out, S)
        if fault in SKIPPED and r.returncode == 0:
            got = score_on_frames(out, S)
            ref = score_on_frames(clean_run[0], clean_run[1], list(got["per_frame"]))
            g, c = got["scores"], ref["scores"]
            d = max(1000.0 * float(np.linalg.norm(got["vertices"][f] - ref["vertices"][f], axis=-1).max())
                    for f in got["per_frame"])
            gone = [x["frame"] for x in got["skipped"]]
            after = [f for f in got["per_frame"] if f > gone[-1]][:3]
            print(f"{fault}: skipped {gone}; good frames median / p90 {g['median_mm']:.3f} / {g['p90_mm']:.3f} mm, "
                  f"clean on them {c['median_mm']:.3f} / {c['p90_mm']:.3f}; jitter {g['jitter_mm']:.3f} / "
                  f"{c['jitter_mm']:.3f}; max vertex distance to clean {d:.2f} mm; frames {after} after the gap "
                  f"{np.mean([got['per_frame'][f] for f in after]):.3f} / clean "
                  f"{np.mean([ref['per_frame'][f] for f in after]):.3f} mm", flush=True)
            continue
        if r.returncode == 0 and out.exists():
            V = _meshes(out)
            if fault == "clean":
                clean = V
            elif clean is not None and len(V) == len(clean):
                d = 1000.0 * np.linalg.norm(V - clean, axis=-1).max(axis=-1)
                line += (f" | max vertex distance to clean: frame {a.frame} {d[a.frame]:.1f} mm, "
                         f"elsewhere {np.delete(d, a.frame).max():.1f} mm")
            elif clean is not None:
                line += f" | {len(V)} meshes, clean {len(clean)}"
            plaus = json.loads((out / "plausibility.json").read_text()) if (out / "plausibility.json").exists() else {}
            line += f" | warnings {plaus.get('warnings')}"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
