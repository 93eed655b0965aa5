"""Well-formed but wrong inputs a real studio produces, planted into a synthetic session folder (for the
plausibility tests and benchmarks/plausibility_faults.py; docs/plausibility.md).

Each function rewrites files of an existing session in place and records their new sha256 in the session
manifest: the fault is in the data, not in the file, so every reader accepts it as the studio would.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np


def restamp(session: str | Path, rel: str) -> None:
    """Record the current sha256 of ``session/rel`` in the session manifest."""
    S = Path(session)
    manifest = json.loads((S / "session.json").read_text())
    manifest["files"][rel] = hashlib.sha256((S / rel).read_bytes()).hexdigest()
    (S / "session.json").write_text(json.dumps(manifest))


def bump_camera(session: str | Path, camera: str = "cam_02", deg: float = 3.0, shift_m: float = 0.05) -> None:
    """The camera moved after calibration: its calibrated pose is ``deg`` (about y) and ``shift_m`` (x) off."""
    from scipy.spatial.transform import Rotation

    S, rel = Path(session), "calibration/cameras.json"
    data = json.loads((S / rel).read_text())
    cam = data["cameras"][camera]
    dR = Rotation.from_rotvec(np.deg2rad(deg) * np.array([0.0, 1.0, 0.0])).as_matrix()
    cam["R"] = (dR @ np.asarray(cam["R"])).tolist()
    cam["t"] = (dR @ np.asarray(cam["t"]) + np.array([shift_m, 0.0, 0.0])).tolist()
    (S / rel).write_text(json.dumps(data))
    restamp(S, rel)


def swap_masks(session: str | Path, a: str = "cam_01", b: str = "cam_03") -> None:
    """Two cameras' mask files exchanged (a copy script that sorted the folders differently)."""
    S = Path(session)
    for p in sorted((S / a / "mask").glob("*.png")):
        q = S / b / "mask" / p.name
        pa, pb = p.read_bytes(), q.read_bytes()
        p.write_bytes(pb)
        q.write_bytes(pa)
        restamp(S, f"{a}/mask/{p.name}")
        restamp(S, f"{b}/mask/{p.name}")


def scale_depth(session: str | Path, factor: float = 10.0) -> None:
    """The Kinect depth imported with the wrong --depth-scale: every reading ``factor`` x too far."""
    import cv2

    S = Path(session)
    for p in sorted((S / "kinect" / "depth").glob("*.png")):
        D = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)
        cv2.imwrite(str(p), np.clip(D * factor, 0, 65535).astype(np.uint16))
        restamp(S, f"kinect/depth/{p.name}")


def shift_colour_camera(session: str | Path, px: float = 10.0) -> None:
    """Kinect depth and colour misregistered by ``px`` pixels: the colour camera's principal point in
    kinect/calibration.json is off (a calibration of another unit, or a resized colour stream)."""
    S, rel = Path(session), "kinect/calibration.json"
    doc = json.loads((S / rel).read_text())
    doc["color"]["K"][0][2] += px
    (S / rel).write_text(json.dumps(doc))
    restamp(S, rel)


LEG_JOINTS = ("KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight", "FootLeft", "FootRight")


def legs_untracked(session: str | Path) -> None:
    """The legs out of the Kinect's view in every frame: the SDK reports knees, ankles and feet as inferred."""
    S = Path(session)
    for path in sorted((S / "kinect" / "joints").glob("*.json")):
        doc = json.loads(path.read_text())
        for body in [doc, *(doc.get("bodies") or [])]:
            if "tracked" in body:
                body["tracked"] = [bool(t) and n not in LEG_JOINTS
                                   for t, n in zip(body["tracked"], body.get("names", doc["names"]), strict=True)]
        path.write_text(json.dumps(doc))
        restamp(S, f"kinect/joints/{path.name}")


# --- realistic segmentation noise (benchmarks/reconstruct_mask_noise.py): clean sessions, noisy masks ---------

def rewrite_masks(session: str | Path, change, seed: int = 7) -> None:
    """Realistic segmentation noise: ``change(mask, camera, frame_index, rng)`` applied to every mask of the
    session (the ``mask_*`` functions below), each restamped."""
    import cv2

    S = Path(session)
    rng = np.random.default_rng(seed)
    for p in sorted(S.glob("cam_*/mask/*.png")):
        m = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 0
        out = change(m, p.parent.parent.name, int(p.stem), rng)
        cv2.imwrite(str(p), (out > 0).astype(np.uint8) * 255)
        restamp(S, str(p.relative_to(S)))


def mask_jitter(m, cam, frame, rng):
    """The outline moved by a smooth random field of 1-3 px standard deviation (zero mean: the segmentation's
    edge noise, not a bias), added to the mask's signed distance."""
    import cv2

    inside = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, 5)
    outside = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 5)
    field = cv2.GaussianBlur(rng.normal(size=m.shape).astype(np.float32), (0, 0), 3.0)
    field *= float(rng.uniform(1.0, 3.0)) / max(float(field.std()), 1e-6)
    return (inside - outside + field) > 0


def mask_shadow(m, cam, frame, rng):
    """A floor shadow merged into the mask: an ellipse under the feet, 1.5x the body's width."""
    import cv2

    ys, xs = np.nonzero(m)
    if len(ys) == 0:
        return m
    w = xs.max() - xs.min()
    out = m.astype(np.uint8).copy()
    cv2.ellipse(out, (int(xs.mean()), int(ys.max())), (int(0.75 * w), max(int(0.04 * (ys.max() - ys.min())), 2)),
                0, 0, 360, 1, -1)
    return out > 0


def mask_holes(m, cam, frame, rng):
    """6-12 small holes (radius 2-4 px) punched in the mask."""
    import cv2

    ys, xs = np.nonzero(m)
    out = m.astype(np.uint8).copy()
    centres = rng.choice(len(ys), size=min(int(rng.integers(6, 13)), len(ys)), replace=False) if len(ys) else []
    for i in centres:
        cv2.circle(out, (int(xs[i]), int(ys[i])), int(rng.integers(2, 5)), 0, -1)
    return out > 0


def mask_limb_lost(m, cam, frame, rng):
    """In the first frame, cam_00's arm lost by the background subtraction: the mask's outer fifth on one side
    at arm height."""
    if frame != 0 or cam != "cam_00":
        return m
    ys, xs = np.nonzero(m)
    if not len(ys):
        return m
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    out = m.copy()
    out[int(y0 + 0.15 * (y1 - y0)):int(y0 + 0.55 * (y1 - y0)), int(x1 - 0.2 * (x1 - x0)):] = False
    return out


def mask_all_noise(m, cam, frame, rng):
    """Jitter, a shadow, holes and the lost limb together."""
    return mask_limb_lost(mask_holes(mask_shadow(mask_jitter(m, cam, frame, rng), cam, frame, rng), cam, frame, rng),
                          cam, frame, rng)
