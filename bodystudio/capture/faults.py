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
