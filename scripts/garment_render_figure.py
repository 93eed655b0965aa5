"""Figure of docs/garment.md's render section: one frame of a synthetic garment video, the new garment
composited without and with the §7 refinement (perturbed oracle fit), and the true render.

Usage: python scripts/garment_render_figure.py [--out docs]   (about half a minute; writes garment_render.png;
development subject 11, not a benchmark subject)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np


def render_figure(out: Path, subject: int = 11, frame: int = 3) -> None:
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit, refine_and_composite
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment_layer
    from bodystudio.garment.synthetic import synth_garment_session

    with tempfile.TemporaryDirectory() as tmp:
        s = synth_garment_session(Path(tmp) / "s", subject_seed=subject, n_frames=frame + 1, seed=2)
        fit = perturbed_fit(ground_truth_fit(s), seed=0)
        body = fit.body()
        target = s.gt_garment["target"]
        cloth = dress(body, target["name"], target["pattern"], s.gt_garment["texture_size"], target["seed"])
        pose = fit.pose(frame)
        V, _ = body.pose(pose)
        layer = render_garment_layer(V, body.faces, cloth, pose_garment(cloth, body, pose), fit.camera, fit.lighting,
                                     fit.albedo, shadows=True)
        video = s.frame(frame).images["cam_00"]
        plain = refine_and_composite(video, fit.masks[frame], layer, flow=False, rbf=False)
        refined = refine_and_composite(video, fit.masks[frame], layer)
        truth = s.frame(frame).gt_target["cam_00"]
        tiles = [t[60:460, 90:390] for t in (video, plain.image, refined.image, truth)]
        _write(out / "garment_render.png", np.hstack(tiles))


def _write(path: Path, rgb: np.ndarray) -> None:
    ok, data = cv2.imencode(".png", rgb[..., ::-1])
    assert ok
    path.write_bytes(data.tobytes())
    print(f"wrote {path}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    render_figure(parser.parse_args().out)
