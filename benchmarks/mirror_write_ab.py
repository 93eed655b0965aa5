"""A/B of ``mirror run``'s write step (CPU ms, ``time.process_time``): main's PNG settings (Huffman-only deflate,
libpng's adaptive filters) against MIR12j's (``run.PNG_FRAME_PARAMS`` / ``PNG_MASK_PARAMS``), alternating frame by
frame (the order swapped every frame) on a run's output frames and masks; the rest of the step is the same (three
atomic file writes and the H.264 pipe). Also checks that both settings give the same pixels back.

Usage: ``PYTHONPATH=. python benchmarks/mirror_write_ab.py [RUN_FOLDER]`` (default ``/work/mirrun/S43/mirror/run``, a
``mirror run`` of session 43).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bodystudio.fileio import Mp4Writer, atomic_write
from bodystudio.mirror.run import _png

MAIN_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]


def png_main(image: np.ndarray) -> bytes:
    """The run's PNG encoder before MIR12j."""
    return cv2.imencode(".png", image if image.ndim == 2 else image[..., ::-1], MAIN_PARAMS)[1].tobytes()


def main(run_dir: Path) -> None:
    names = sorted(p.name for p in (run_dir / "frames").glob("*.png"))
    frames = [cv2.imread(str(run_dir / "frames" / n))[..., ::-1].copy() for n in names]
    masks = [[cv2.imread(str(run_dir / "masks" / sub / n), cv2.IMREAD_UNCHANGED) > 127 for n in names]
             for sub in ("foreground", "warped")]
    ms = {"main": [], "mir12j": []}
    size = dict.fromkeys(ms, 0)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        writers = {k: Mp4Writer(out / f"{k}.mp4", (frames[0].shape[1], frames[0].shape[0]), 30.0) for k in ms}
        for k, frame in enumerate(frames):
            order = (("main", png_main), ("mir12j", _png))
            for name, encode in order if k % 2 else order[::-1]:
                c = time.process_time()
                images = (frame, masks[0][k].astype(np.uint8) * 255, masks[1][k].astype(np.uint8) * 255)
                for j, image in enumerate(images):
                    data = encode(image)
                    with atomic_write(out / f"{name}_{j}_{k}.png", "wb") as f:
                        f.write(data)
                    size[name] += len(data)
                writers[name].write(frame)
                ms[name].append((time.process_time() - c) * 1e3)
                back = cv2.imread(str(out / f"{name}_0_{k}.png"))[..., ::-1]
                assert np.array_equal(back, frame), f"{name}: frame {k} changed"
        for w in writers.values():
            w.close()
    for name, values in ms.items():
        print(f"write step {name:7s} median {np.median(values):6.2f} ms CPU (mean {np.mean(values):6.2f}), "
              f"{size[name] / len(frames) / 1e3:6.1f} kB a frame (frame + 2 masks), {len(frames)} frames")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("/work/mirrun/S43/mirror/run"))
