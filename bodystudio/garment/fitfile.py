"""The garment fit folder: what ``bodystudio garment fit`` writes and ``garment render`` / ``eval garment`` read.

Layout (one unit, committed by :class:`bodystudio.runfolder.RunWriter`: lock, staging, manifest last)::

    DIR/fit.json        format, version, source video/session, fps, frame ids, template, bone names,
                        phenotype + local modifiers, stature, camera, lighting, per-frame quality,
                        ms per step, warnings
    DIR/poses.npz       rotations (n_frames, n_bones, 3) axis-angle, translations (n_frames, 3)
    DIR/albedo.npy      (n_vertices, 3) linear RGB per body vertex, or absent when not estimated
    DIR/masks/NNNNN.png the person mask the fit used, per frame (for the refinement and the report)

The fit is only as good as its silhouettes: ``silhouette_iou`` per frame (projected fitted body vs the
person mask) is kept so that later steps and the evaluation can refuse frames that were not fitted.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bodystudio.errors import FileFormatError, InputError

FIT_JSON = "fit.json"
FIT_FORMAT = "bodystudio-garment-fit"
FIT_VERSION = 1
#: A frame whose fitted silhouette overlaps the person mask less than this is marked unfitted.
MIN_FRAME_IOU = 0.80


@dataclass(frozen=True, eq=False)
class GarmentFit:
    """A monocular fit (§4 of Garment Replacement): camera, body shape, per-frame pose, appearance.

    ``rotations`` (n, B, 3) and ``translations`` (n, 3) are :class:`bodystudio.body.pose.Pose` per frame;
    ``masks`` (n, H, W) bool are the person masks the fit used; ``albedo`` (V, 3) or None; ``lighting``
    a :class:`bodystudio.garment.lighting.Lighting` or None; ``silhouette_iou`` (n,) the fit's quality.
    """

    source: str
    fps: float
    frame_ids: np.ndarray
    camera: object  # bodystudio.geometry.camera.Camera
    template: str
    bone_names: tuple[str, ...]
    phenotype: dict
    local: dict
    stature_m: float
    rotations: np.ndarray
    translations: np.ndarray
    silhouette_iou: np.ndarray
    masks: np.ndarray
    lighting: object | None = None  # bodystudio.garment.lighting.Lighting
    albedo: np.ndarray | None = None
    timings_ms: dict = field(default_factory=dict)
    # the source recording's identity (garment.person.source_fingerprint: "session:..." or "video:..."); None:
    # unknown (a fit written before it existed, or made in memory)
    source_fingerprint: str | None = None
    warnings: tuple[str, ...] = ()

    def __post_init__(self):
        n = len(self.frame_ids)
        if n == 0:
            raise InputError("a garment fit needs at least one frame")
        if self.rotations.shape != (n, len(self.bone_names), 3) or self.translations.shape != (n, 3):
            raise InputError(f"garment fit: rotations {self.rotations.shape} / translations {self.translations.shape} "
                             f"do not match {n} frames of {len(self.bone_names)} bones")
        if self.silhouette_iou.shape != (n,) or self.masks.shape[0] != n:
            raise InputError("garment fit: one silhouette IoU and one mask per frame are needed")
        if not (0.5 <= self.stature_m <= 2.5 and np.isfinite(self.rotations).all()
                and np.isfinite(self.translations).all()):
            raise InputError(f"garment fit: stature {self.stature_m} m or pose values are not plausible")

    def pose(self, i: int):
        """The :class:`Pose` of the ``i``-th fitted frame (an index into ``frame_ids``)."""
        from bodystudio.body.pose import Pose

        return Pose(self.rotations[i], self.translations[i])

    def body(self):
        """The fitted :class:`BodyModel` (shape only; pose it with :meth:`pose`)."""
        from bodystudio.body import build_body
        from bodystudio.body.phenotype import Phenotype

        return build_body(Phenotype.from_dict(self.phenotype), self.local, resolution=self.template)

    @property
    def fitted(self) -> np.ndarray:
        """(n,) bool: frames whose silhouette IoU reaches :data:`MIN_FRAME_IOU`."""
        return self.silhouette_iou >= MIN_FRAME_IOU


def _png(mask: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    if not ok:
        raise InputError("could not encode a fit mask as PNG")
    return buf.tobytes()


def save_garment_fit(folder: str | os.PathLike, fit: GarmentFit, command: str = "bodystudio garment fit") -> dict:
    """Write ``fit`` into ``folder`` as one committed unit (replacing an earlier fit there); returns fit.json."""
    from bodystudio.runfolder import RunLayout, RunWriter

    folder = Path(folder)
    layout = RunLayout(folder, FIT_JSON, ".", str(folder))
    with RunWriter(layout, command, {"stage": "garment", "kind": "fit"}) as w:
        buf = io.BytesIO()
        np.savez_compressed(buf, rotations=fit.rotations, translations=fit.translations)
        w.write_bytes("poses.npz", buf.getvalue())
        if fit.albedo is not None:
            buf = io.BytesIO()
            np.save(buf, np.asarray(fit.albedo, np.float32))
            w.write_bytes("albedo.npy", buf.getvalue())
        for fid, mask in zip(fit.frame_ids, fit.masks, strict=True):
            w.write_bytes(f"masks/{int(fid):05d}.png", _png(mask))
        doc = {"format": FIT_FORMAT, "version": FIT_VERSION, "source": fit.source, "fps": float(fit.fps),
               "frame_ids": [int(i) for i in fit.frame_ids], "template": fit.template,
               "bone_names": list(fit.bone_names), "phenotype": fit.phenotype, "local": fit.local,
               "stature_m": float(fit.stature_m), "camera": {"name": fit.camera.name, **fit.camera.to_dict()},
               "lighting": None if fit.lighting is None else fit.lighting.to_dict(),
               "albedo": fit.albedo is not None,
               "silhouette_iou": [round(float(v), 5) for v in fit.silhouette_iou],
               "min_frame_iou": MIN_FRAME_IOU, "timings_ms": fit.timings_ms, "warnings": list(fit.warnings),
               "source_fingerprint": fit.source_fingerprint}
        return w.commit(doc)


def load_garment_fit(folder: str | os.PathLike) -> GarmentFit:
    """Read a fit folder; a missing, unfinished or corrupt one raises a one-line error naming the fix."""
    from bodystudio.fileio import read_image
    from bodystudio.garment.lighting import Lighting
    from bodystudio.geometry.camera import Camera
    from bodystudio.runfolder import RunLayout, check_readable

    folder = Path(folder)
    path = folder / FIT_JSON
    layout = RunLayout(folder, FIT_JSON, ".", str(folder))
    problem = check_readable(layout)
    if problem:
        raise FileFormatError(problem)
    if not path.is_file():
        raise FileFormatError(f"{path}: not found; run 'bodystudio garment fit VIDEO --out {folder}' first")
    fix = f"rerun 'bodystudio garment fit ... --out {folder}'"
    try:
        doc = json.loads(path.read_text())
        if doc.get("format") != FIT_FORMAT:
            raise FileFormatError(f"{path}: not a garment fit (format {doc.get('format')!r}); {fix}")
        if doc.get("version") != FIT_VERSION:
            raise FileFormatError(f"{path}: garment fit version {doc.get('version')!r}, this release reads "
                                  f"{FIT_VERSION}; {fix}")
        with np.load(folder / "poses.npz") as z:
            rotations, translations = np.asarray(z["rotations"], float), np.asarray(z["translations"], float)
        albedo = np.load(folder / "albedo.npy").astype(np.float64) if doc["albedo"] else None
        if albedo is not None and (albedo.ndim != 2 or albedo.shape[1] != 3 or not np.all(np.isfinite(albedo))):
            raise ValueError(f"albedo.npy of shape {albedo.shape} is not per-vertex RGB or not finite")
        frame_ids = np.asarray(doc["frame_ids"], dtype=np.int64)
        if not 1.0 <= float(doc["fps"]) <= 240.0:  # NaN too: the render's video writer would fail obscurely
            raise ValueError(f"fps {doc['fps']!r} is not a frame rate in 1..240")
        masks = []
        for fid in frame_ids:
            mask_path = folder / "masks" / f"{int(fid):05d}.png"
            if not mask_path.is_file():  # cv2.imread would print its own warning on stderr
                raise FileFormatError(f"{mask_path}: missing or unreadable; {fix}")
            masks.append(read_image(mask_path, cv2.IMREAD_GRAYSCALE) > 127)
        # the shape is checked here, naming the fit: later, building the body said only "phenotype gender=nan
        # is out of range", with no file to fix
        from bodystudio.body.phenotype import Phenotype

        Phenotype.from_dict(dict(doc["phenotype"]))
        bad = [f"{k}={v}" for k, v in dict(doc["local"]).items() if not -1.0 <= float(v) <= 1.0]
        if bad:
            raise ValueError(f"local modifier {bad[0]} is not in [-1, 1]")
        try:
            lighting = None if doc["lighting"] is None else Lighting.from_dict(doc["lighting"], str(path))
        except FileFormatError as exc:  # names fit.json and what is wrong; the fix is the fit's, as for the rest
            raise FileFormatError(f"{exc}; {fix}") from None
        cam_doc = doc["camera"]
        camera = Camera.from_dict(str(cam_doc.get("name", "cam_00")), cam_doc)
        return GarmentFit(source=str(doc["source"]), fps=float(doc["fps"]), frame_ids=frame_ids,
                          camera=camera, template=str(doc["template"]),
                          bone_names=tuple(doc["bone_names"]), phenotype=dict(doc["phenotype"]),
                          local=dict(doc["local"]), stature_m=float(doc["stature_m"]), rotations=rotations,
                          translations=translations, silhouette_iou=np.asarray(doc["silhouette_iou"], float),
                          masks=np.stack(masks), lighting=lighting, albedo=albedo,
                          timings_ms=dict(doc.get("timings_ms", {})), warnings=tuple(doc.get("warnings", ())),
                          source_fingerprint=doc.get("source_fingerprint"))
    except FileFormatError:
        raise
    except (OSError, ValueError, KeyError, TypeError, InputError, json.JSONDecodeError) as exc:
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''}"
        raise FileFormatError(f"{folder}: damaged garment fit ({reason}); {fix}") from None
