"""Rig exchange: COLMAP text models and EasyMocap YAML round trips."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodystudio.calib.io import load_colmap_model, load_easymocap_yaml, save_colmap_model, save_easymocap_yaml
from bodystudio.errors import FileFormatError
from bodystudio.geometry.camera import Camera, CameraRig, ring_rig


def _assert_same(a: CameraRig, b: CameraRig, tol: float) -> None:
    assert a.names == b.names
    for ca, cb in zip(a, b, strict=True):
        np.testing.assert_allclose(cb.K, ca.K, atol=tol, rtol=0)
        np.testing.assert_allclose(cb.dist, ca.dist, atol=tol, rtol=0)
        np.testing.assert_allclose(cb.R, ca.R, atol=tol, rtol=0)
        np.testing.assert_allclose(cb.t, ca.t, atol=tol, rtol=0)
        assert (cb.width, cb.height) == (ca.width, ca.height)


def _with_k3(rig: CameraRig, k3: float) -> CameraRig:
    return CameraRig({c.name: Camera(c.name, c.K, np.r_[c.dist[:4], k3], c.R, c.t, c.width, c.height) for c in rig})


def test_colmap_round_trip(tmp_path):
    rig = ring_rig(10)
    save_colmap_model(tmp_path / "model", rig)
    assert (tmp_path / "model" / "cameras.txt").read_text().count("OPENCV") == 10
    _assert_same(rig, load_colmap_model(tmp_path / "model"), 1e-9)
    rig3 = _with_k3(rig, 0.013)  # k3 needs COLMAP's FULL_OPENCV model
    save_colmap_model(tmp_path / "model", rig3)
    assert "FULL_OPENCV" in (tmp_path / "model" / "cameras.txt").read_text()
    _assert_same(rig3, load_colmap_model(tmp_path / "model"), 1e-9)


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=3, max_size=3), st.floats(200, 3000), st.floats(-0.3, 0.3))
def test_colmap_round_trip_any_pose(tmp_path_factory, eye, f, k1):
    cam = Camera.look_at("c", eye if np.linalg.norm(np.subtract(eye, [0, 1, 0.1])) > 0.1 else [2, 1, 2],
                         [0, 1, 0.1], fx=f, fy=f * 1.01, dist=(k1, 0.01, 1e-4, -2e-4, 0.0))
    folder = tmp_path_factory.mktemp("colmap")
    rig = CameraRig({"c": cam})
    save_colmap_model(folder, rig)
    _assert_same(rig, load_colmap_model(folder), 1e-9)


def test_easymocap_round_trip(tmp_path):
    rig = _with_k3(ring_rig(3), 0.004)
    save_easymocap_yaml(tmp_path, rig)
    text = (tmp_path / "extri.yml").read_text()
    assert "Rot_cam_00" in text and "R_cam_00" in text and "T_cam_00" in text
    assert "names" in (tmp_path / "intri.yml").read_text()
    _assert_same(rig, load_easymocap_yaml(tmp_path), 1e-12)


def test_missing_files_are_one_line_errors(tmp_path):
    with pytest.raises(FileFormatError, match="intri.yml"):
        load_easymocap_yaml(tmp_path)
    with pytest.raises(FileFormatError, match="no COLMAP model"):
        load_colmap_model(tmp_path)
