"""The arm capture's self-check (bodystudio/muscle/plausibility.py) on clean and planted-fault sessions: the figures
its thresholds come from (docs/plausibility.md, "muscle capture").

2k left-arm model from ``training_dataset("2k")`` (ten men, BMI 20-28); 12-frame Kinect v2 elbow-flexion sessions at
1 m: clean subjects 501, 620, 5, 7; the out-of-range held-out subjects 611-614 (``bench_muscle.OUT_OF_RANGE``);
faults planted with ``synth_arm_session`` / ``capture.faults``: the right arm's session captured with ``--side left``,
depth scaled 1.1x / 0.9x / 10x, the sensor 1.5 m / 2.5 m away. Each case is captured with ``accept_implausible=True``
(a case refused before the capture shows its session figures only: the capture cannot run on it).

    python -m benchmarks.muscle_plausibility [--frames 12] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np


def cases(work: Path, n_frames: int) -> dict:
    from benchmarks.bench_muscle import OUT_OF_RANGE, out_of_range_subject
    from bodystudio.capture.faults import scale_depth
    from bodystudio.muscle.synthetic import synth_arm_session

    def session(name, **kw):
        path = work / name
        if not path.exists():
            synth_arm_session(path, n_frames=n_frames, resolution="2k", **kw)
        return path

    out = {f"clean {s}": (session(f"clean{s}", subject_seed=s), None) for s in (501, 620, 5, 7)}
    for k, label in enumerate(OUT_OF_RANGE):
        out[f"out of range {611 + k} ({label})"] = (session(f"oor{k}", subject=out_of_range_subject(611 + k, label)),
                                                     None)
    out["right arm, --side left"] = (session("right", subject_seed=501, side="right"), "left")
    for factor in (1.1, 0.9, 10.0):
        path = work / f"scale{factor:g}"
        if not path.exists():
            shutil.copytree(out["clean 501"][0], path)
            scale_depth(path, factor)
        out[f"depth {factor:g}x"] = (path, None)
    for distance in (1.5, 2.5):
        out[f"Kinect at {distance:g} m"] = (session(f"far{distance:g}", subject_seed=501, distance_m=distance), None)
    return out


def measure(path: Path, side: str | None, model_path: Path) -> dict:
    from bodystudio.capture.session import open_session
    from bodystudio.errors import BodyStudioError
    from bodystudio.muscle.capture import capture_session_arm, session_arm_choice
    from bodystudio.muscle.plausibility import capture_verdict, session_checks

    try:
        capture = capture_session_arm(path, model_path, side=side, accept_implausible=True)
        return capture.plausibility
    except BodyStudioError as exc:  # the capture itself cannot run: the session figures and their verdict
        session = open_session(path)
        chosen = session_arm_choice(session, None, side)[1]
        verdict = capture_verdict(session_checks(session, session.frame_ids, chosen), chosen, path)
        verdict["capture_error"] = str(exc)
        return verdict


def row(name: str, v: dict) -> list[str]:
    f = v["figures"]

    def num(x, fmt="{:.2f}"):
        return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else fmt.format(x)

    dist = f.get("arm_distance_m", {})
    shape = f.get("shape") or {}
    outside = max((s["outside"] for s in shape.values()), default=None)
    joints = f.get("tracker_joint_residual_mm") or {}
    verdict = ("refused: " + v["problems"][0][:60] if v["problems"] else
               "warning: " + v["warnings"][0][:60] if v["warnings"] else "ok")
    return [name, num(f.get("depth_to_tracker_ratio"), "{:.3f}"),
            " / ".join(f"{dist[s]:.2f}" for s in ("left", "right") if s in dist),
            num(f.get("sampling_mm"), "{:.1f}"),
            " / ".join(num((f.get(r) or {}).get("residual_mm"), "{:.1f}") for r in ("upperarm", "forearm")),
            num(f.get("points_explained"), "{:.3f}"), num(max(joints.values()) if joints else None, "{:.0f}"),
            num(outside, "{:.3f}"), verdict]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--work", type=Path, default=None, help="keep the sessions and model here")
    args = parser.parse_args(argv)
    from benchmarks.timing import markdown_table
    from bodystudio.body import build_body
    from bodystudio.muscle.arm import arm_template
    from bodystudio.muscle.model import learn_arm_model, save_arm_model
    from bodystudio.muscle.synthetic import training_dataset

    work = args.work or Path(tempfile.mkdtemp(prefix="muscle_plaus_"))
    work.mkdir(parents=True, exist_ok=True)
    model_path = work / "model_2k_left.npz"
    if not model_path.is_file():
        samples, _ = training_dataset("2k")
        save_arm_model(model_path, learn_arm_model(samples, arm_template(build_body(resolution="2k"), "left")))
    rows, verdicts = [], {}
    for name, (path, side) in cases(work, args.frames).items():
        verdicts[name] = measure(path, side, model_path)
        rows.append(row(name, verdicts[name]))
        print(" | ".join(rows[-1]), flush=True)
    (work / "verdicts.json").write_text(json.dumps(verdicts, indent=1))
    print(markdown_table(["case", "depth / tracker", "arm distance L / R (m)", "sampling (mm)",
                          "residual upper / fore (mm)", "points explained", "joint residual max (mm)",
                          "shape outside (span)", "verdict"], rows))


if __name__ == "__main__":
    main()
