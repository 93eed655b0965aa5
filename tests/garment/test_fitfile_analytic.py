"""The garment fit folder (``garment/fitfile.py``): a round trip that keeps every field, its checks and refusals.

A small fit made in memory (two frames, three bones, 6 x 5 masks): what ``save_garment_fit`` writes is read
back field by field, fit.json's keys are the documented ones, every refusal of ``GarmentFit`` and
``load_garment_fit`` is checked by its text (issue 17: the module was never mutated).
"""

import json

import cv2
import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.garment import fitfile as ff
from bodystudio.garment.lighting import Lighting
from bodystudio.geometry.camera import Camera

BONES = ("pelvis", "spine_01", "thigh_l")


def _fit(**changes):
    rng = np.random.default_rng(3)
    masks = np.zeros((2, 6, 5), bool)
    masks[0, 1:4, 2:4] = True
    masks[1, 2:, :2] = True
    args = dict(
        source="/videos/walk.mp4", fps=25.0, frame_ids=np.array([3, 12]),
        camera=Camera.look_at("front", (0.2, 1.1, 3.0), (0, 0.9, 0), fx=420.0, width=5, height=6),
        template="2k", bone_names=BONES, phenotype={"gender": 0.8, "height": 0.6}, local={"belly-decr-incr": 0.2},
        stature_m=1.73, rotations=rng.normal(0, 0.3, (2, 3, 3)), translations=rng.normal(0, 0.5, (2, 3)),
        silhouette_iou=np.array([0.912345678, 0.79999]), masks=masks,
        lighting=Lighting(np.array([[0.3, 0.8, 0.5]]), np.array([[0.7, 0.65, 0.6]]), np.array([0.2, 0.21, 0.22])),
        albedo=rng.uniform(0, 1, (7, 3)), timings_ms={"pose": 12.5, "shape": 3.0},
        source_fingerprint="video:abc123", warnings=("frame 12 was not fitted",))
    args.update(changes)
    return ff.GarmentFit(**args)


def test_round_trip_keeps_every_field(tmp_path):
    fit = _fit()
    doc = ff.save_garment_fit(tmp_path / "fit", fit, command="bodystudio garment fit v.mp4")
    back = ff.load_garment_fit(tmp_path / "fit")
    assert back.source == fit.source and back.fps == 25.0 and back.template == "2k"
    assert back.frame_ids.dtype == np.int64 and np.array_equal(back.frame_ids, [3, 12])
    assert back.bone_names == BONES and back.phenotype == fit.phenotype and back.local == fit.local
    assert back.stature_m == 1.73
    assert np.array_equal(back.rotations, fit.rotations) and np.array_equal(back.translations, fit.translations)
    assert back.rotations.dtype == np.float64
    assert np.array_equal(back.masks, fit.masks)
    assert np.array_equal(back.silhouette_iou, [0.91235, 0.79999])  # rounded to 5 decimals
    assert back.albedo.dtype == np.float64 and np.array_equal(back.albedo, fit.albedo.astype(np.float32))
    assert np.allclose(back.lighting.directions, fit.lighting.directions, atol=1e-15)
    assert np.array_equal(back.lighting.colors, fit.lighting.colors)
    assert np.array_equal(back.lighting.ambient, fit.lighting.ambient)
    assert back.camera.name == "front" and back.camera.to_dict() == fit.camera.to_dict()
    assert back.timings_ms == fit.timings_ms and back.warnings == fit.warnings
    assert back.source_fingerprint == "video:abc123"
    assert doc["run"]["command"] == "bodystudio garment fit v.mp4"


def test_fit_json_holds_the_documented_keys(tmp_path):
    fit = _fit()
    ff.save_garment_fit(tmp_path, fit)
    doc = json.loads((tmp_path / "fit.json").read_text())
    assert doc["format"] == "bodystudio-garment-fit" and doc["version"] == 1
    assert doc["source"] == "/videos/walk.mp4" and doc["fps"] == 25.0 and doc["frame_ids"] == [3, 12]
    assert doc["template"] == "2k" and doc["bone_names"] == list(BONES)
    assert doc["phenotype"] == fit.phenotype and doc["local"] == fit.local and doc["stature_m"] == 1.73
    assert doc["camera"] == {"name": "front", **fit.camera.to_dict()}
    assert doc["lighting"] == fit.lighting.to_dict() and doc["albedo"] is True
    assert doc["silhouette_iou"] == [0.91235, 0.79999] and doc["min_frame_iou"] == 0.80
    assert doc["timings_ms"] == fit.timings_ms and doc["warnings"] == ["frame 12 was not fitted"]
    assert doc["source_fingerprint"] == "video:abc123"
    assert doc["run"]["command"] == "bodystudio garment fit"
    assert set(doc["run"]["files"]) == {"poses.npz", "albedo.npy", "masks/00003.png", "masks/00012.png"}
    with np.load(tmp_path / "poses.npz") as z:
        assert set(z.files) == {"rotations", "translations"}
        assert np.array_equal(z["rotations"], fit.rotations) and np.array_equal(z["translations"], fit.translations)
    assert np.load(tmp_path / "albedo.npy").dtype == np.float32
    png = cv2.imread(str(tmp_path / "masks" / "00012.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint8 and png.shape == (6, 5) and set(np.unique(png)) == {0, 255}
    assert np.array_equal(png == 255, fit.masks[1])


def test_a_fit_without_albedo_or_lighting(tmp_path):
    fit = _fit(albedo=None, lighting=None, source_fingerprint=None, warnings=())
    ff.save_garment_fit(tmp_path, fit)
    doc = json.loads((tmp_path / "fit.json").read_text())
    assert doc["albedo"] is False and doc["lighting"] is None and doc["source_fingerprint"] is None
    assert not (tmp_path / "albedo.npy").exists()
    back = ff.load_garment_fit(tmp_path)
    assert back.albedo is None and back.lighting is None and back.source_fingerprint is None
    assert back.warnings == ()


def test_older_fit_json_defaults(tmp_path):
    ff.save_garment_fit(tmp_path, _fit())
    doc = json.loads((tmp_path / "fit.json").read_text())
    for key in ("timings_ms", "warnings", "source_fingerprint"):
        del doc[key]
    del doc["camera"]["name"]
    (tmp_path / "fit.json").write_text(json.dumps(doc))
    back = ff.load_garment_fit(tmp_path)
    assert back.timings_ms == {} and back.warnings == () and back.source_fingerprint is None
    assert back.camera.name == "cam_00"


def test_masks_are_thresholded_at_half(tmp_path):
    ff.save_garment_fit(tmp_path, _fit())
    gray = np.array([[0, 127, 128, 200, 255]] * 6, np.uint8)
    cv2.imwrite(str(tmp_path / "masks" / "00003.png"), gray)
    back = ff.load_garment_fit(tmp_path)
    assert np.array_equal(back.masks[0], np.array([[False, False, True, True, True]] * 6))


def test_pose_body_and_fitted_frames():
    fit = _fit(silhouette_iou=np.array([0.80, 0.7999]))
    p = fit.pose(1)
    assert np.array_equal(p.rotations, fit.rotations[1]) and np.array_equal(p.translation, fit.translations[1])
    assert np.array_equal(fit.fitted, [True, False])  # 0.80 itself is fitted
    assert ff.MIN_FRAME_IOU == 0.80


def test_body_is_the_fitted_shape_at_the_template_resolution():
    from bodystudio.body import build_body
    from bodystudio.body.phenotype import Phenotype

    fit = _fit(phenotype={"gender": 0.9, "weight": 0.2}, local={"upperarm-fat-decr-incr": 0.5})
    body = fit.body()
    want = build_body(Phenotype(gender=0.9, weight=0.2), {"upperarm-fat-decr-incr": 0.5}, resolution="2k")
    assert body.resolution == "2k" and np.array_equal(body.vertices, want.vertices)


@pytest.mark.parametrize("changes,message", [
    ({"frame_ids": np.zeros(0, int), "rotations": np.zeros((0, 3, 3)), "translations": np.zeros((0, 3)),
      "silhouette_iou": np.zeros(0), "masks": np.zeros((0, 6, 5), bool)}, "a garment fit needs at least one frame"),
    ({"rotations": np.zeros((2, 4, 3))},
     "garment fit: rotations (2, 4, 3) / translations (2, 3) do not match 2 frames of 3 bones"),
    ({"rotations": np.zeros((3, 3, 3))},
     "garment fit: rotations (3, 3, 3) / translations (2, 3) do not match 2 frames of 3 bones"),
    ({"translations": np.zeros((2, 2))},
     "garment fit: rotations (2, 3, 3) / translations (2, 2) do not match 2 frames of 3 bones"),
    ({"translations": np.zeros((1, 3))},
     "garment fit: rotations (2, 3, 3) / translations (1, 3) do not match 2 frames of 3 bones"),
    ({"silhouette_iou": np.ones(3)}, "garment fit: one silhouette IoU and one mask per frame are needed"),
    ({"masks": np.zeros((3, 6, 5), bool)}, "garment fit: one silhouette IoU and one mask per frame are needed"),
    ({"stature_m": 0.49}, "garment fit: stature 0.49 m or pose values are not plausible"),
    ({"stature_m": 2.51}, "garment fit: stature 2.51 m or pose values are not plausible"),
    ({"rotations": np.full((2, 3, 3), np.nan)}, "garment fit: stature 1.73 m or pose values are not plausible"),
    ({"translations": np.array([[0, 0, 0], [0, np.inf, 0]], float)},
     "garment fit: stature 1.73 m or pose values are not plausible"),
])
def test_garment_fit_refusals(changes, message):
    with pytest.raises(InputError) as e:
        _fit(**changes)
    assert str(e.value) == message


def test_stature_bounds_are_inclusive():
    assert _fit(stature_m=0.5).stature_m == 0.5 and _fit(stature_m=2.5).stature_m == 2.5


def test_png_of_a_mask():
    mask = np.array([[True, False], [False, True]])
    img = cv2.imdecode(np.frombuffer(ff._png(mask), np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(img, [[255, 0], [0, 255]]) and img.dtype == np.uint8


def test_png_encoding_failure_is_one_line(monkeypatch):
    monkeypatch.setattr(cv2, "imencode", lambda *a: (False, None))
    with pytest.raises(InputError, match="^could not encode a fit mask as PNG$"):
        ff._png(np.zeros((2, 2), bool))


# --- load refusals ------------------------------------------------------------------------------

def _saved(tmp_path, **changes):
    folder = tmp_path / "fit"
    ff.save_garment_fit(folder, _fit(**changes))
    return folder


def _edit(folder, **changes):
    doc = json.loads((folder / "fit.json").read_text())
    doc.update(changes)
    (folder / "fit.json").write_text(json.dumps(doc))


def _refused(folder, message):
    with pytest.raises(FileFormatError) as e:
        ff.load_garment_fit(folder)
    assert str(e.value) == message
    return str(e.value)


def test_load_refuses_a_folder_without_a_fit(tmp_path):
    (tmp_path / "empty").mkdir()
    _refused(tmp_path / "empty", f"{tmp_path / 'empty' / 'fit.json'}: not found; run 'bodystudio garment fit "
                                 f"VIDEO --out {tmp_path / 'empty'}' first")


def test_load_refuses_what_the_run_folder_check_refuses(tmp_path, monkeypatch):
    import bodystudio.runfolder as rf

    folder = _saved(tmp_path)
    seen = []

    def check(layout):
        seen.append((layout.root, layout.manifest))
        return "fit: being written by pid 7 (bodystudio garment fit); wait for it"

    monkeypatch.setattr(rf, "check_readable", check)
    _refused(folder, "fit: being written by pid 7 (bodystudio garment fit); wait for it")
    assert seen == [(folder, "fit.json")]


def test_load_refuses_other_formats_and_versions(tmp_path):
    folder = _saved(tmp_path)
    fix = f"rerun 'bodystudio garment fit ... --out {folder}'"
    _edit(folder, format="bodystudio-muscle-fit")
    _refused(folder, f"{folder / 'fit.json'}: not a garment fit (format 'bodystudio-muscle-fit'); {fix}")
    _edit(folder, format="bodystudio-garment-fit", version=2)
    _refused(folder, f"{folder / 'fit.json'}: garment fit version 2, this release reads 1; {fix}")


@pytest.mark.parametrize("fps,ok", [(1.0, True), (240.0, True), (0.99, False), (240.5, False), ("NaN", False)])
def test_load_checks_the_frame_rate(tmp_path, fps, ok):
    folder = _saved(tmp_path)
    _edit(folder, fps=float(fps))
    if ok:
        assert ff.load_garment_fit(folder).fps == float(fps)
    else:
        _refused(folder, f"{folder}: damaged garment fit (ValueError: fps {float(fps)!r} is not a frame rate in "
                         f"1..240); rerun 'bodystudio garment fit ... --out {folder}'")


def test_load_refuses_a_missing_mask(tmp_path):
    folder = _saved(tmp_path)
    (folder / "masks" / "00012.png").unlink()
    _refused(folder, f"{folder / 'masks' / '00012.png'}: missing or unreadable; "
                     f"rerun 'bodystudio garment fit ... --out {folder}'")


@pytest.mark.parametrize("albedo,shape", [(np.zeros((7, 4)), "(7, 4)"), (np.zeros(7), "(7,)"),
                                          (np.full((7, 3), np.nan), "(7, 3)")])
def test_load_refuses_a_bad_albedo(tmp_path, albedo, shape):
    folder = _saved(tmp_path)
    np.save(folder / "albedo.npy", albedo)
    _refused(folder, f"{folder}: damaged garment fit (ValueError: albedo.npy of shape {shape} is not per-vertex RGB "
                     f"or not finite); rerun 'bodystudio garment fit ... --out {folder}'")


def test_load_reports_damage_in_one_line(tmp_path):
    folder = _saved(tmp_path)
    fix = f"rerun 'bodystudio garment fit ... --out {folder}'"
    doc = json.loads((folder / "fit.json").read_text())
    del doc["template"]
    (folder / "fit.json").write_text(json.dumps(doc))
    _refused(folder, f"{folder}: damaged garment fit (KeyError: 'template'); {fix}")
    _edit(folder, template="2k", stature_m=9.0)  # GarmentFit's own check, reported as damage
    _refused(folder, f"{folder}: damaged garment fit (InputError: garment fit: stature 9.0 m or pose values are not "
                     f"plausible); {fix}")
    _edit(folder, stature_m=1.7)
    (folder / "poses.npz").write_bytes(b"not a zip")
    with pytest.raises(FileFormatError) as e:
        ff.load_garment_fit(folder)
    msg = str(e.value)
    assert msg.startswith(f"{folder}: damaged garment fit (") and msg.endswith(f"); {fix}") and "\n" not in msg


def test_load_reason_is_the_first_line_cut_at_120_characters(tmp_path, monkeypatch):
    folder = _saved(tmp_path)
    fix = f"rerun 'bodystudio garment fit ... --out {folder}'"

    def long_error(*args, **kwargs):
        raise ValueError("x" * 200 + "\nsecond line")

    monkeypatch.setattr(np, "load", long_error)
    _refused(folder, f"{folder}: damaged garment fit (ValueError: {'x' * 120}); {fix}")

    def empty_error(*args, **kwargs):
        raise OSError()

    monkeypatch.setattr(np, "load", empty_error)
    _refused(folder, f"{folder}: damaged garment fit (OSError: ); {fix}")


# --- survivors of the first mutation run --------------------------------------------------------------

def test_fit_folder_lock_and_staging_are_dot_files_named_by_the_folder(tmp_path):
    from bodystudio.runfolder import OutputLockedError, RunLayout, interrupted_message

    folder = _saved(tmp_path)
    doc = json.loads((folder / "fit.json").read_text())
    assert doc["run"]["producer"] == {"stage": "garment", "kind": "fit"}
    assert sorted(p.name for p in folder.iterdir()) == ["albedo.npy", "fit.json", "masks", "poses.npz"]
    # a writer of another host holds .lock: a second save is refused, naming the folder and the lock
    (folder / ".lock").write_text(json.dumps({"pid": 7, "host": "elsewhere", "command": "bodystudio garment fit",
                                              "since": "2026-01-01T00:00:00Z"}) + "\n")
    with pytest.raises(OutputLockedError) as e:
        ff.save_garment_fit(folder, _fit())
    assert str(e.value) == (f"{folder}: being written by pid 7 on elsewhere (bodystudio garment fit, since "
                            f"2026-01-01T00:00:00Z); wait for it to finish (if that process is gone, delete "
                            f"{folder / '.lock'})")
    (folder / ".lock").unlink()
    # a committed but unfinished write (.staging/commit.json): the load names the folder to recover
    (folder / ".staging").mkdir()
    (folder / ".staging" / "commit.json").write_text("{}")
    with pytest.raises(OutputLockedError) as e:
        ff.load_garment_fit(folder)
    assert str(e.value) == interrupted_message(RunLayout(folder, "fit.json", ".", str(folder)))
    assert f"bodystudio recover {folder}`" in str(e.value)


def test_load_converts_poses_and_qualities_to_float(tmp_path):
    folder = _saved(tmp_path)
    fit = _fit()
    np.savez(folder / "poses.npz", rotations=fit.rotations.astype(np.float32),
             translations=fit.translations.astype(np.float32))
    _edit(folder, silhouette_iou=[1, 0])
    back = ff.load_garment_fit(folder)
    assert back.rotations.dtype == np.float64 and back.translations.dtype == np.float64
    assert np.array_equal(back.rotations, fit.rotations.astype(np.float32))
    assert back.silhouette_iou.dtype == np.float64 and np.array_equal(back.fitted, [True, False])


def test_load_names_fit_json_for_a_malformed_lighting(tmp_path):
    folder = _saved(tmp_path)
    _edit(folder, lighting={"directions": [[0, 1, 0]]})
    with pytest.raises(FileFormatError) as e:
        ff.load_garment_fit(folder)
    assert str(e.value).startswith(f"{folder / 'fit.json'}: ")
