"""Scan input: formats, clean-up, units and up-axis detection, one-line errors for bad files."""

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, FileFormatError, InputError
from bodystudio.geometry.mesh import Mesh, save_mesh
from bodystudio.register.scan import load_scan


def _one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_synthetic_scan_loads_as_is(small_scan):
    path, scan, _ = small_scan
    mesh, report = load_scan(path)
    assert report.units == "m" and report.up_axis == "+y" and report.facing_axis == "+z"
    np.testing.assert_allclose(report.to_canonical, np.eye(3))
    assert scan.n_vertices - 20 <= mesh.n_vertices <= scan.n_vertices  # clean-up may drop hole-edge slivers
    assert mesh.vertex_colors is not None
    np.testing.assert_allclose(np.sort(mesh.vertices[:, 1])[[0, -1]], np.sort(scan.vertices[:, 1])[[0, -1]], atol=1e-6)


@pytest.mark.parametrize("suffix", [".stl", ".obj", ".glb"])
def test_millimetre_z_up_scan_is_detected_and_canonicalised(small_scan, tmp_path, suffix):
    _, scan, _ = small_scan
    # Z-up (Blender/STL habit), millimetres, facing -y.
    to_file = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    path = tmp_path / f"scan{suffix}"
    save_mesh(path, Mesh(1000.0 * scan.vertices @ to_file.T, scan.faces, scan.vertex_colors))
    mesh, report = load_scan(path)
    assert report.units == "mm"
    assert report.up_axis == "+z" and report.facing_axis == "-y"
    assert any("mm" in n for n in report.notes)
    # Back in metres, y up, facing +z (same coordinates as the original, vertex order may differ).
    np.testing.assert_allclose(mesh.vertices.min(0), scan.vertices.min(0), atol=1e-4)
    np.testing.assert_allclose(mesh.vertices.max(0), scan.vertices.max(0), atol=1e-4)


@pytest.mark.parametrize("subject", [128, 135, 136])
def test_orientation_of_random_poses_in_every_axis_order(subject):
    """Random poses that fooled the old cues (an arm reaching forward made the body deeper than wide; a
    leg stepping back put the lowest slice behind the shins): every proper axis permutation is undone."""
    from itertools import permutations, product

    from bodystudio.geometry.mesh import vertex_areas
    from bodystudio.register.scan import detect_orientation
    from bodystudio.register.synthetic import synthetic_scan

    scan, _ = synthetic_scan(subject, "random", 6000, 1.0, True)
    area = vertex_areas(scan.vertices, scan.faces)
    for perm, signs in product(permutations(range(3)), product((-1.0, 1.0), repeat=3)):
        P = np.eye(3)[list(perm)] * np.array(signs)[:, None]
        if np.linalg.det(P) < 0:
            continue
        R, _, _ = detect_orientation(scan.vertices @ P.T, area)
        np.testing.assert_allclose(R @ P, np.eye(3), atol=1e-12)


def test_cleanup_removes_debris_and_duplicates(small_scan, tmp_path):
    _, scan, _ = small_scan
    debris = np.array([[2.0, 0, 0], [2.001, 0, 0], [2.0, 0.001, 0]])
    V = np.vstack([scan.vertices, debris, scan.vertices[:1]])
    n = len(scan.vertices)
    F = np.vstack([scan.faces, [[n, n + 1, n + 2]]])
    path = tmp_path / "debris.ply"
    save_mesh(path, Mesh(V, F))
    mesh, report = load_scan(path)
    assert report.removed_vertices >= 4
    assert mesh.vertices[:, 0].max() < 1.5


def test_bad_inputs_give_one_line_errors(tmp_path, small_scan):
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    with pytest.raises(FileFormatError) as e:
        load_scan(empty)
    assert "empty" in _one_line(e)
    text = tmp_path / "notes.obj"
    text.write_text("this is not a mesh\n")
    with pytest.raises(BodyStudioError) as e:
        load_scan(text)
    _one_line(e)
    cloud = tmp_path / "cloud.ply"
    pts = np.random.default_rng(0).normal(size=(500, 3))
    cloud.write_text("ply\nformat ascii 1.0\nelement vertex 500\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n" + "\n".join(" ".join(map(str, p)) for p in pts) + "\n")
    with pytest.raises(FileFormatError) as e:
        load_scan(cloud)
    assert "point cloud" in _one_line(e)
    _, scan, _ = small_scan
    huge = tmp_path / "huge.ply"
    save_mesh(huge, Mesh(scan.vertices * 5.0, scan.faces))  # 8 m tall: no unit makes it an adult
    with pytest.raises(InputError) as e:
        load_scan(huge)
    assert "units" in _one_line(e)
    with pytest.raises(FileFormatError):
        load_scan(tmp_path / "missing.ply")
