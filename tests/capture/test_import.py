"""Importing recordings: the test writes image folders, videos, TUM depth and joints with OpenCV from a
synthetic session, imports them through the real decoding path and compares with the originals."""

import json
import shutil

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodystudio.capture.importer import import_recording, save_easymocap_cameras
from bodystudio.capture.session import open_session
from bodystudio.capture.silhouettes import mask_iou, segment_session
from bodystudio.errors import BodyStudioError, FileFormatError


@pytest.fixture(scope="module")
def src(small_synth_session):
    return open_session(small_synth_session)


def write_images(root, src, skip_first=()):
    for cam in src.camera_names:
        (root / cam).mkdir(parents=True)
        for f in src:
            cv2.imwrite(str(root / cam / f"{f.frame_id:06d}.png"), cv2.cvtColor(f.images[cam], cv2.COLOR_RGB2BGR))
    return root


def write_tum(root, src, scale=5000.0, float_depth=False):
    (root / "depth").mkdir(parents=True)
    (root / "rgb").mkdir()
    depth_lines, rgb_lines = ["# depth maps", "# timestamp filename"], ["# color images"]
    for f in src:
        t = 100.0 + f.frame_id / 15.0
        name = f"{t:.6f}"
        d = f.kinect_depth_m
        if float_depth:
            cv2.imwrite(str(root / "depth" / f"{name}.tiff"), d.astype(np.float32))
            depth_lines.append(f"{t:.6f} depth/{name}.tiff")
        else:
            cv2.imwrite(str(root / "depth" / f"{name}.png"), np.rint(d * scale).astype(np.uint16))
            depth_lines.append(f"{t:.6f} depth/{name}.png")
        tr = t + 0.007  # colour and depth are not simultaneous in TUM recordings
        cv2.imwrite(str(root / "rgb" / f"{tr:.6f}.png"), cv2.cvtColor(f.kinect_rgb, cv2.COLOR_RGB2BGR))
        rgb_lines.append(f"{tr:.6f} rgb/{tr:.6f}.png")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    return root


def write_kinect_calibration(path, src):
    path.write_bytes((src.path / "kinect" / "calibration.json").read_bytes())
    return path


def write_joints_csv(path, src):
    lines = ["frame,joint,x,y,z,tracked"]
    for f in src:
        j = f.kinect_joints
        for n, p, t in zip(j["names"], j["positions"], j["tracked"], strict=True):
            lines.append(f"{f.frame_id},{n},{float(p[0])!r},{float(p[1])!r},{float(p[2])!r},{int(t)}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_image_folders_easymocap_cameras_tum_depth_and_csv_joints(src, tmp_path):
    images = write_images(tmp_path / "images", src)
    save_easymocap_cameras(tmp_path / "calib", src.cameras)
    bgs = tmp_path / "bg"
    for cam in src.camera_names:
        (bgs / cam).mkdir(parents=True)
        for k, b in enumerate(src.background_frames(cam)):
            cv2.imwrite(str(bgs / cam / f"{k}.png"), cv2.cvtColor(b, cv2.COLOR_RGB2BGR))
    tum = write_tum(tmp_path / "tum", src)
    s = import_recording(tmp_path / "out", cameras=tmp_path / "calib", images=images, backgrounds=bgs, tum=tum,
                         kinect_calibration=write_kinect_calibration(tmp_path / "kinect.json", src),
                         joints=write_joints_csv(tmp_path / "joints.csv", src))
    assert s.verify() and s.frame_ids == src.frame_ids and s.camera_names == src.camera_names
    for cam in src.camera_names:
        a, b = s.cameras[cam], src.cameras[cam]
        assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.t, b.t) and np.allclose(a.dist, b.dist)
        assert (a.width, a.height) == (b.width, b.height)
    for f, g in zip(s, src, strict=True):
        for cam in src.camera_names:
            assert np.array_equal(f.images[cam], g.images[cam])
        assert np.abs(f.kinect_depth_m - g.kinect_depth_m).max() <= 0.0006  # 1/5000 m then mm rounding
        assert np.array_equal(f.kinect_rgb, g.kinect_rgb)
        assert np.allclose(f.kinect_joints["positions"], g.kinect_joints["positions"])
        assert f.kinect_joints["names"] == g.kinect_joints["names"]
    assert len(s.background_frames("cam_02")) == len(src.background_frames("cam_02"))


def write_videos(root, src, leading_frames, codec="FFV1"):
    """One video per camera (FFV1 lossless or MJPG); camera ``cam`` starts ``leading_frames[cam]`` frames early."""
    root.mkdir()
    stamps = root / "timestamps"
    stamps.mkdir()
    fourcc = cv2.VideoWriter_fourcc(*codec)
    for cam in src.camera_names:
        w, h = src.cameras[cam].width, src.cameras[cam].height
        writer = cv2.VideoWriter(str(root / f"{cam}.avi"), fourcc, 15.0, (w, h))
        assert writer.isOpened()
        lead = leading_frames.get(cam, 0)
        times = []
        for k in range(lead):
            writer.write(np.zeros((h, w, 3), np.uint8))
            times.append(10.0 + (k - lead) / 15.0 + 0.004)
        for f in src:
            writer.write(cv2.cvtColor(f.images[cam], cv2.COLOR_RGB2BGR))
            times.append(10.0 + f.frame_id / 15.0 + 0.003 * (cam != "cam_00"))
        writer.release()
        (stamps / f"{cam}.txt").write_text("\n".join(f"{t:.6f}" for t in times) + "\n")
    return root


def write_background_videos(root, src, codec="FFV1"):
    root.mkdir()
    for cam in src.camera_names:
        w, h = src.cameras[cam].width, src.cameras[cam].height
        bg = cv2.VideoWriter(str(root / f"{cam}.avi"), cv2.VideoWriter_fourcc(*codec), 15.0, (w, h))
        for b in src.background_frames(cam):
            bg.write(cv2.cvtColor(b, cv2.COLOR_RGB2BGR))
        bg.release()
    return root


def test_videos_synchronised_by_timestamps_then_segmented(src, tmp_path):
    """Lossless (FFV1) videos whose cameras started at different times: timestamps realign them exactly,
    and background subtraction on the imported session still reaches IoU >= 0.98."""
    videos = write_videos(tmp_path / "videos", src, {"cam_01": 2, "cam_03": 1})
    bgs = write_background_videos(tmp_path / "bg", src)
    shutil.copy(src.path / "calibration" / "cameras.json", tmp_path / "cameras.json")
    s = import_recording(tmp_path / "out", cameras=tmp_path / "cameras.json", videos=videos,
                         timestamps=videos / "timestamps", backgrounds=bgs)
    assert s.frame_ids == src.frame_ids  # the leading blank frames were synchronised away
    for f, g in zip(s, src, strict=True):
        for cam in src.camera_names:
            assert np.array_equal(f.images[cam], g.images[cam]), f"{cam} frame {f.frame_id}"
    report = segment_session(s.path)
    ious = [mask_iou(f.masks[c], g.gt_masks[c])
            for f, g in zip(open_session(s.path), src, strict=True) for c in src.camera_names]
    print(f"silhouette IoU after FFV1 video import: mean {np.mean(ious):.4f} min {np.min(ious):.4f}")
    assert report.n_masks == 12 and np.mean(ious) >= 0.98


def test_mjpg_videos_by_frame_index(src, tmp_path):
    """Lossy MJPG decoding path: frames synchronised by index come back within JPEG error of the originals."""
    videos = write_videos(tmp_path / "videos", src, {}, codec="MJPG")
    shutil.copy(src.path / "calibration" / "cameras.json", tmp_path / "cameras.json")
    s = import_recording(tmp_path / "out", cameras=tmp_path / "cameras.json", videos=videos)
    assert s.frame_ids == src.frame_ids
    for f, g in zip(s, src, strict=True):
        for cam in src.camera_names:
            err = np.abs(f.images[cam].astype(float) - g.images[cam]).mean()
            assert err < 4.0, f"{cam} frame {f.frame_id}: MJPG frame differs by {err:.1f} grey levels"
            others = [np.abs(f.images[cam].astype(float) - o.images[cam]).mean()
                      for o in src if o.frame_id != g.frame_id]
            assert err < min(others), "frame matched to the wrong time"


def test_video_frames_by_index_must_agree(src, tmp_path):
    videos = write_videos(tmp_path / "videos", src, {"cam_02": 1})
    shutil.copy(src.path / "calibration" / "cameras.json", tmp_path / "cameras.json")
    with pytest.raises(FileFormatError, match=r"cam_02\.avi: 4 frames but .*cam_00\.avi has 3") as err:
        import_recording(tmp_path / "out", cameras=tmp_path / "cameras.json", videos=videos)
    assert "timestamps" in str(err.value) and not (tmp_path / "out").exists()


@pytest.fixture()
def image_setup(src, tmp_path):
    images = write_images(tmp_path / "images", src)
    shutil.copy(src.path / "calibration" / "cameras.json", tmp_path / "cameras.json")
    return images, tmp_path / "cameras.json"


def test_mismatched_image_size_names_the_file(image_setup, tmp_path):
    images, cams = image_setup
    bad = images / "cam_02" / "000001.png"
    cv2.imwrite(str(bad), np.zeros((120, 160, 3), np.uint8))
    with pytest.raises(FileFormatError,
                       match=r"cam_02/000001\.png: image is 160x120 but the calibration of cam_02 says 320x240"):
        import_recording(tmp_path / "out", cameras=cams, images=images)
    assert not (tmp_path / "out").exists()  # no half-written session


def test_missing_camera_names_the_folder(image_setup, tmp_path):
    images, cams = image_setup
    shutil.rmtree(images / "cam_03")
    with pytest.raises(FileFormatError, match=r"images/cam_03: missing image folder for camera cam_03"):
        import_recording(tmp_path / "out", cameras=cams, images=images)


def test_unreadable_frame_names_the_file(image_setup, tmp_path):
    images, cams = image_setup
    bad = images / "cam_01" / "000002.png"
    bad.write_bytes(bad.read_bytes()[:40])
    with pytest.raises(FileFormatError, match=r"cam_01/000002\.png: unreadable image"):
        import_recording(tmp_path / "out", cameras=cams, images=images)
    assert not (tmp_path / "out").exists()


def test_depth_in_wrong_units(src, image_setup, tmp_path):
    images, cams = image_setup
    calib = write_kinect_calibration(tmp_path / "kinect.json", src)
    mm = write_tum(tmp_path / "tum_mm", src, scale=1000.0)
    with pytest.raises(FileFormatError, match=r"tum_mm/depth/.*\.png: .*millimetres.*--depth-scale 1000"):
        import_recording(tmp_path / "out", cameras=cams, images=images, tum=mm, kinect_calibration=calib)
    s = import_recording(tmp_path / "out", cameras=cams, images=images, tum=mm, kinect_calibration=calib,
                         depth_scale=1000.0)
    assert np.abs(s.frame(0).kinect_depth_m - src.frame(0).kinect_depth_m).max() < 1e-9
    metres = write_tum(tmp_path / "tum_m", src, float_depth=True)
    with pytest.raises(FileFormatError, match=r"\.tiff: depth is stored as floating point .*--depth-scale 1"):
        import_recording(tmp_path / "out2", cameras=cams, images=images, tum=metres, kinect_calibration=calib)


def test_joints_json_folder_and_cli_error(src, image_setup, tmp_path, capsys):
    from bodystudio.cli.main import main

    images, cams = image_setup
    jdir = tmp_path / "joints"
    jdir.mkdir()
    for f in src:
        j = f.kinect_joints
        joints = dict(zip(j["names"], j["positions"].tolist(), strict=True))
        (jdir / f"{f.frame_id:04d}.json").write_text(json.dumps({"joints": joints}))
    assert main(["capture", "import", str(tmp_path / "out"), "--cameras", str(cams), "--images", str(images),
                 "--joints", str(jdir)]) == 0
    s = open_session(tmp_path / "out")
    assert np.allclose(s.frame(2).kinect_joints["positions"], src.frame(2).kinect_joints["positions"])
    (jdir / "0001.json").write_text(json.dumps({"joints": {"Head": [0, 1700.0, 0]}}))
    assert main(["capture", "import", str(tmp_path / "out2"), "--cameras", str(cams), "--images", str(images),
                 "--joints", str(jdir)]) == 2
    err = [l for l in capsys.readouterr().err.splitlines() if l.startswith("error:")]  # not the progress bar
    assert len(err) == 1 and "0001.json" in err[0]
    assert main(["capture", "verify", str(tmp_path / "out")]) == 0


def test_errors_are_body_studio_errors():
    assert issubclass(FileFormatError, BodyStudioError)


def test_truncated_video_names_the_file_and_frame(src, tmp_path):
    videos = write_videos(tmp_path / "videos", src, {})
    shutil.copy(src.path / "calibration" / "cameras.json", tmp_path / "cameras.json")
    bad = videos / "cam_01.avi"
    data = bad.read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    # the frames are counted by decoding (adv5): the cut camera has fewer, refused with the --frames that pairs them
    with pytest.raises(FileFormatError, match=r"cam_01\.avi: (\d frames but .* --frames \d|cannot open the video)"):
        import_recording(tmp_path / "out", cameras=tmp_path / "cameras.json", videos=videos)
    assert not (tmp_path / "out").exists()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 5), st.integers(0, 5), st.floats(0.0, 0.01), st.integers(2, 30))
def test_timestamp_synchronisation_recovers_the_common_frames(lead_a, lead_b, jitter, n):
    """Cameras that start at different times (leading frames) and tick with jitter well below the
    frame period (here up to 15%) are realigned: every common frame is matched, to the right index."""
    from bodystudio.capture.importer import synchronise_by_timestamps

    period = 1 / 15
    rng = np.random.default_rng(n)
    truth = 5.0 + period * np.arange(n)
    times = {"ref": truth + rng.uniform(-jitter, jitter, n)}
    times["a"] = np.r_[truth[0] - period * np.arange(lead_a, 0, -1), truth] + rng.uniform(-jitter, jitter, n + lead_a)
    times["b"] = np.r_[truth[0] - period * np.arange(lead_b, 0, -1), truth][: n + lead_b - 1] + jitter / 2
    plan = synchronise_by_timestamps(times)
    assert [p["ref"] for p in plan] == list(range(n - 1))  # b stopped one frame early
    assert all(p["a"] == p["ref"] + lead_a and p["b"] == p["ref"] + lead_b for p in plan)


def test_existing_masks_and_kinect_sdk_joints(src, image_setup, tmp_path):
    """Silhouettes from another tool (mask folders) and tracker joints in the Kinect SDK's camera space
    (x left, y up, metres from the depth camera) come back as the session's masks and studio-frame joints."""
    from bodystudio.capture.importer import studio_to_kinect_sdk

    images, cams = image_setup
    masks = tmp_path / "masks"
    for cam in src.camera_names:
        (masks / cam).mkdir(parents=True)
        for f in src:
            cv2.imwrite(str(masks / cam / f"{f.frame_id:06d}.png"), f.gt_masks[cam].astype(np.uint8) * 255)
    sensor = src.kinect
    lines = ["frame,joint,x,y,z"]
    for f in src:
        j = f.kinect_joints
        for n, p in zip(j["names"], studio_to_kinect_sdk(j["positions"], sensor), strict=True):
            lines.append(f"{f.frame_id},{n},{float(p[0])!r},{float(p[1])!r},{float(p[2])!r}")
    (tmp_path / "sdk.csv").write_text("\n".join(lines) + "\n")
    s = import_recording(tmp_path / "out", cameras=cams, images=images, masks=masks, joints=tmp_path / "sdk.csv",
                         joints_frame="kinect-sdk",
                         kinect_calibration=write_kinect_calibration(tmp_path / "k.json", src))
    head = s.frame(0).kinect_joints["positions"][s.frame(0).kinect_joints["names"].index("Head")]
    assert head[1] > 1.3  # y up in the studio: the head is high
    for f, g in zip(s, src, strict=True):
        assert np.abs(f.kinect_joints["positions"] - g.kinect_joints["positions"]).max() < 1e-9
        for cam in src.camera_names:
            assert np.array_equal(f.masks[cam], g.gt_masks[cam])
    sdk = studio_to_kinect_sdk(np.array([head]), sensor)[0]
    assert sdk[1] > 0 and sdk[2] > 1.0  # above the sensor's axis (y up) and in front of it


def test_easymocap_text_layout(tmp_path):
    """intri.yml/extri.yml as EasyMocap's own writer lays them out (%YAML:1.0, CRLF, quoted names,
    6-decimal !!opencv-matrix rows); image sizes come from the frames when W_/H_ are absent."""
    from bodystudio.capture.importer import load_studio_cameras
    from bodystudio.geometry.camera import Camera

    cam = Camera.look_at("01", (0.5, 1.2, 3.0), (0, 1, 0), fx=800.0, width=64, height=48,
                         dist=(0.1, -0.05, 0, 0, 0))

    def mat(key, m):
        m = np.atleast_2d(m)
        data = ", ".join(f"{x:.6f}" for x in m.ravel())
        return (f"{key}: !!opencv-matrix\r\n  rows: {m.shape[0]}\r\n  cols: {m.shape[1]}\r\n  dt: d\r\n"
                f"  data: [{data}]\r\n")

    head = '%YAML:1.0\r\n---\r\nnames:\r\n  - "01"\r\n'
    (tmp_path / "intri.yml").write_text(head + mat("K_01", cam.K) + mat("dist_01", cam.dist[None]), newline="")
    rvec = cv2.Rodrigues(cam.R)[0]
    extri = head + mat("R_01", rvec) + mat("Rot_01", cam.R) + mat("T_01", cam.t[:, None])
    (tmp_path / "extri.yml").write_text(extri, newline="")
    rig = load_studio_cameras(tmp_path, image_sizes={"01": (64, 48)})
    got = rig["01"]
    assert np.allclose(got.K, cam.K, atol=1e-6) and np.allclose(got.R, cam.R, atol=1e-5)
    assert np.allclose(got.t, cam.t, atol=1e-6) and np.allclose(got.dist, cam.dist) and got.width == 64
    with pytest.raises(FileFormatError, match=r"intri\.yml: no image size for camera 01"):
        load_studio_cameras(tmp_path / "intri.yml")
    # rotation matrix only (no Rodrigues vector), rounded to 6 decimals: snapped back to a rotation
    extri = head + mat("Rot_01", cam.R) + mat("T_01", cam.t[:, None])
    (tmp_path / "extri.yml").write_text(extri, newline="")
    got = load_studio_cameras(tmp_path, image_sizes={"01": (64, 48)})["01"]
    assert np.allclose(got.R, cam.R, atol=1e-5) and np.allclose(got.R @ got.R.T, np.eye(3), atol=1e-12)
