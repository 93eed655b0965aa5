"""Figures of docs/garment.md: the four garments on one body, and a synthetic garment session's frame.

Usage: python scripts/garment_figures.py [--out docs]   (about a minute; writes garment_dress.png and
garment_synth.png; the synthetic session goes to a temporary folder)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np


def dress_figure(out: Path) -> None:
    from bodystudio.body import build_body
    from bodystudio.garment.garments import dress
    from bodystudio.garment.lighting import Lighting
    from bodystudio.garment.render import render_garment
    from bodystudio.geometry.camera import Camera

    body = build_body(resolution="6k")
    cam = Camera.look_at("front", (0.3, 1.0, 3.0), (0, 0.9, 0), fx=520, width=300, height=480)
    light = Lighting.single((0.5, 0.8, 0.6), 0.8, 0.25)
    tiles = []
    for name, pattern in (("tights", "checks"), ("skirt", "print"), ("tshirt", "stripes"), ("longsleeve", "checks")):
        g = dress(body, name, pattern)
        tiles.append(render_garment(body.vertices, body.faces, g, g.vertices, cam, light, shadows=True).image)
    _write(out / "garment_dress.png", np.hstack(tiles))


def synth_figure(out: Path) -> None:
    from bodystudio.garment.synthetic import synth_garment_session

    with tempfile.TemporaryDirectory() as tmp:
        s = synth_garment_session(Path(tmp) / "s", subject_seed=3, n_frames=12, resolution=(300, 400))
        f = s.frame(11)
        layers = f.gt_layers["cam_00"].astype(np.uint8) * 120
        _write(out / "garment_synth.png", np.hstack([f.images["cam_00"], f.gt_target["cam_00"],
                                                     np.dstack([layers] * 3)]))


def _write(path: Path, rgb: np.ndarray) -> None:
    from bodystudio.fileio import atomic_path

    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
            raise OSError(f"cannot write {path}")
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    args = parser.parse_args()
    dress_figure(args.out)
    synth_figure(args.out)


if __name__ == "__main__":
    main()
