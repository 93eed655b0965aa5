"""Synthetic studio sessions: ground truth is self-consistent and the simulated sensors match their models."""

import numpy as np
import pytest

from bodystudio.capture.session import open_session


@pytest.fixture(scope="module")
def session(small_synth_session):
    return open_session(small_synth_session)


def test_layout_and_checksums(session):
    assert session.camera_names == ["cam_00", "cam_01", "cam_02", "cam_03"] and session.frame_ids == [0, 1, 2]
    assert session.source == "synthetic" and session.metadata["motion"] == "arms_raise"
    assert set(session.streams) == {"background", "rgb", "mask", "gt_mask", "kinect_depth", "kinect_rgb",
                                    "kinect_joints", "gt_mesh", "gt_joints", "gt_pose"}
    assert session.verify() == len(session.files)
    assert session.cameras["cam_02"].width == 320 and session.kinect.version == "v1"
    f = session.frame(1)
    assert f.images["cam_00"].shape == (240, 320, 3) and f.kinect_depth_m.shape == (480, 640)
    assert f.kinect_rgb.shape == (480, 640, 3)


def test_ground_truth_mesh_is_the_posed_subject_and_matches_the_masks(session):
    """Rebuild the subject from gt/phenotype.json, pose it with gt/pose: it must be the stored mesh,
    and re-rendering the stored mesh must give the stored masks exactly."""
    from bodystudio.body import Phenotype, build_body, posed_joints
    from bodystudio.capture.render import render

    subject = session.gt_subject
    body = build_body(Phenotype.from_dict(subject["phenotype"]), subject["local"], resolution=subject["template"])
    moved = []
    for frame in session:
        V, _ = body.pose(frame.gt_pose)
        assert np.abs(V - frame.gt_mesh.vertices).max() < 1e-9
        assert np.array_equal(frame.gt_mesh.faces, body.faces)
        heads, tails = posed_joints(body.skeleton, frame.gt_pose)
        assert np.allclose(frame.gt_joints["heads"], heads) and np.allclose(frame.gt_joints["tails"], tails)
        for cam in session.camera_names:
            assert np.array_equal(render(V, body.faces, session.cameras[cam]).mask, frame.gt_masks[cam])
        moved.append(V)
    assert max(np.abs(V - moved[0]).max() for V in moved) > 0.01, "the motion should move the body"


def test_sensor_noise_matches_its_standard_deviation(session):
    """Camera sensor noise: the empty frames scatter around the plate with the configured std (within 10%)."""
    from bodystudio.capture.render import background_plate

    plate = background_plate(session.cameras["cam_01"], session.metadata["seed"]).astype(np.float64)
    frames = np.stack(session.background_frames("cam_01")).astype(np.float64)
    inner = (plate > 10) & (plate < 245)  # clipping at 0/255 shrinks the noise
    std = (frames - plate)[:, inner].std()
    assert abs(std - session.metadata["noise_std"]) < 0.1 * session.metadata["noise_std"]


def test_kinect_depth_and_joints_follow_the_ground_truth(session):
    from bodystudio.body.kinect import kinect_joints
    from bodystudio.capture.render import render

    frame = session.frame(2)
    sensor = session.kinect
    truth = render(frame.gt_mesh.vertices, frame.gt_mesh.faces, sensor.depth).depth.astype(np.float64)
    measured = frame.kinect_depth_m
    both = (truth > 0) & (measured > 0)
    assert both.sum() > 0.5 * (truth > 0).sum()
    err = measured[both] - truth[both]
    sigma = 1.425e-3 * np.median(truth[both]) ** 2  # Khoshelham axial noise at the body's distance
    assert abs(np.median(err)) < sigma and np.median(np.abs(err)) < 3 * sigma
    # tracker joints: ground-truth Kinect joints plus a centimetre of noise and bone-length jitter
    from bodystudio.body import Phenotype, build_body

    subject = session.gt_subject
    skeleton = build_body(Phenotype.from_dict(subject["phenotype"]), subject["local"], resolution="2k").skeleton
    gt = kinect_joints(skeleton, frame.gt_joints["heads"], frame.gt_joints["tails"], "v1")
    tracked = frame.kinect_joints
    assert tracked["names"][0] == "HipCenter" and tracked["positions"].shape == gt.shape
    err = np.linalg.norm(tracked["positions"] - gt, axis=1)
    assert 0.002 < np.median(err) < 0.06


def test_no_noise_is_deterministic_and_clean(tmp_path):
    from bodystudio.capture.render import background_plate
    from bodystudio.capture.synth import synth_session

    kwargs = dict(n_cameras=1, n_frames=1, motion="a_pose", kinect=None, resolution=(64, 48), noise=False,
                  template="2k", n_background=2)
    a = synth_session(tmp_path / "a", **kwargs)
    b = synth_session(tmp_path / "b", **kwargs)
    assert a.files == b.files  # byte-identical
    plate = background_plate(a.cameras["cam_00"], 0)
    assert all(np.array_equal(f, plate) for f in a.background_frames("cam_00"))
    assert "kinect_depth" not in a.streams and a.kinect is None


def test_cli_synth_session_and_bad_input(tmp_path, capsys):
    from bodystudio.cli.main import main

    out = tmp_path / "cli"
    assert main(["synth", "session", str(out), "--cameras", "1", "--frames", "1", "--resolution", "64x48",
                 "--kinect", "none", "--template", "2k", "--motion", "t_pose"]) == 0
    assert open_session(out).verify() > 0
    assert main(["synth", "session", str(tmp_path / "x"), "--resolution", "640by480"]) == 2
    assert main(["synth", "session", str(tmp_path / "x"), "--motion", "moonwalk"]) == 2
    assert main(["synth", "session", str(out)]) == 2
    err = [l for l in capsys.readouterr().err.splitlines() if l.startswith("error:")]  # not the progress bar
    assert len(err) == 3 and "640by480" in err[0] and "moonwalk" in err[1] and str(out) in err[2]
    assert not (tmp_path / "x").exists()
