"""``capture import --joints`` given in the other frame than ``--joints-frame`` says (adversarial pass 4).

A Kinect SDK export (camera space: x left, y up, metres from the depth camera) imported with the default
``--joints-frame studio``, or studio-frame joints with ``--joints-frame kinect-sdk``, was stored with exit 0: the
person ~0 m from the depth camera and 1000+ px outside its image, which every later stage fitted to. With a Kinect
calibration the importer now checks where the depth camera sees the joints and refuses in one line naming the file
and the ``--joints-frame`` to pass; nothing is written."""

from __future__ import annotations

import json

import pytest

from bodystudio.capture.importer import studio_to_kinect_sdk
from bodystudio.capture.session import open_session
from tests.reliability.conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def recording(small_synth_session, tmp_path_factory):
    """The studio session's first two frames as an import source: images, the Kinect calibration, and the tracker's
    joints in both frames (studio.json, sdk.json)."""
    import shutil

    src = open_session(small_synth_session)
    root = tmp_path_factory.mktemp("adv4jf")
    for cam in src.camera_names:
        (root / "images" / cam).mkdir(parents=True)
        for f in src.frame_ids[:2]:
            shutil.copy(src.path / cam / "rgb" / f"{f:05d}.png", root / "images" / cam / f"{f:05d}.png")
    shutil.copy(src.path / "kinect" / "calibration.json", root / "kinect.json")
    frames = [src.frame(f).kinect_joints for f in src.frame_ids[:2]]
    names = frames[0]["names"]
    for name, convert in (("studio", lambda P: P), ("sdk", lambda P: studio_to_kinect_sdk(P, src.kinect))):
        (root / f"{name}.json").write_text(json.dumps(
            {"names": names, "frames": [convert(j["positions"]).tolist() for j in frames]}))
    return src, root


@pytest.mark.parametrize("given, flag, phrase", [
    ("sdk", [], "pass --joints-frame kinect-sdk"),
    ("studio", ["--joints-frame", "kinect-sdk"], "pass --joints-frame studio")], ids=["sdk_as_studio", "studio_as_sdk"])
def test_joints_in_the_other_frame_are_refused(recording, tmp_path, capfd, given, flag, phrase):
    src, root = recording
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", src.path / "calibration" / "cameras.json",
                            "--images", root / "images", "--kinect-calibration", root / "kinect.json",
                            "--joints", root / f"{given}.json", *flag], capfd)
    assert_clean_error(result, 2, phrase)
    assert f"{root / (given + '.json')}: read as --joints-frame" in result.stderr and not out.exists()


@pytest.mark.parametrize("given, flag", [("studio", []), ("sdk", ["--joints-frame", "kinect-sdk"])])
def test_joints_in_the_frame_given_import(recording, tmp_path, capfd, given, flag):
    src, root = recording
    out = tmp_path / "S"
    result = run_inprocess(["capture", "import", out, "--cameras", src.path / "calibration" / "cameras.json",
                            "--images", root / "images", "--kinect-calibration", root / "kinect.json",
                            "--joints", root / f"{given}.json", *flag], capfd)
    assert_clean_error(result, 0, "")
    want = src.frame(src.frame_ids[1]).kinect_joints["positions"]
    assert open_session(out).frame(1).kinect_joints["positions"] == pytest.approx(want, abs=1e-9)
