"""bodystudio.geometry.mesh against references independent of it (issue 17, mutation testing): normals and
barycentric areas of hand-made triangles in closed form, the quad split written out, every refusal of the
mesh readers word for word, and files written by hand (ASCII PLY / OBJ) or read back by trimesh itself."""

import numpy as np
import pytest
import trimesh

from bodystudio.errors import FileFormatError
from bodystudio.geometry.mesh import (
    Mesh,
    checked_mesh_arrays,
    face_normals,
    load_mesh,
    quads_to_triangles,
    save_mesh,
    vertex_areas,
    vertex_normals,
)

# two triangles sharing the edge 0-2: a 2 x 1 right triangle in z = 0 and a 1 x 1 one in x = 0 (folded up)
V2 = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
F2 = np.array([[0, 1, 2], [0, 2, 3]])


def test_mesh_stores_contiguous_float64_vertices_and_int64_faces():
    V = np.asfortranarray(np.arange(12, dtype=np.float32).reshape(4, 3))
    m = Mesh(V, np.array([[0, 1, 2]], dtype=np.int32))
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    assert m.vertices.flags.c_contiguous and m.faces.flags.c_contiguous
    np.testing.assert_array_equal(m.vertices, V)
    assert m.n_vertices == 4 and m.n_faces == 1


@pytest.mark.parametrize("V, F, message", [
    (np.zeros((4, 2)), [[0, 1, 2]], "vertices must be (n, 3), got (4, 2)"),
    (np.zeros(3), [[0, 1, 2]], "vertices must be (n, 3), got (3,)"),
    (np.zeros((4, 3)), [[0, 1, 2, 3]], "faces must be (m, 3) triangles, got (1, 4)"),
    (np.zeros((4, 3)), [0, 1, 2], "faces must be (m, 3) triangles, got (3,)"),
])
def test_mesh_refuses_other_shapes(V, F, message):
    with pytest.raises(ValueError) as err:
        Mesh(V, F)
    assert str(err.value) == message


def test_with_vertices_keeps_topology_colours_and_a_copy_of_the_metadata():
    colors = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12]], dtype=np.uint8)
    m = Mesh(V2, F2, colors, {"source": "a"})
    moved = m.with_vertices(V2 + 1.0)
    np.testing.assert_array_equal(moved.vertices, V2 + 1.0)
    np.testing.assert_array_equal(moved.faces, F2)
    assert moved.vertex_colors is colors
    assert moved.metadata == {"source": "a"} and moved.metadata is not m.metadata


def test_face_normals_are_unit_and_counter_clockwise_and_zero_for_a_degenerate_face():
    V = np.r_[V2, [[5.0, 5.0, 5.0]]]
    F = np.r_[F2, [[4, 4, 1]]]
    N = face_normals(V, F)
    np.testing.assert_allclose(N, [[0, 0, 1], [1, 0, 0], [0, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(face_normals(0.01 * V + 2.0, F), N, atol=1e-12)  # small faces, off the origin
    np.testing.assert_allclose(face_normals(V2, F2[:, ::-1]), [[0, 0, -1], [-1, 0, 0]], atol=1e-15)
    tilted = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 4.0, 5.0]])
    np.testing.assert_allclose(face_normals(tilted, np.array([[0, 1, 2]])), [[0, -5, 4] / np.sqrt(41)],
                               atol=1e-15)


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (0.01, 0.0), (0.01, 3.0)])
def test_vertex_normals_weigh_each_face_by_its_area(scale, offset):
    N = vertex_normals(scale * V2 + offset, F2)  # small faces: normalised, not left short; away from the origin
    # the shared vertices 0 and 2: 2 x (area 1, +z) + (area 0.5, +x), normalised
    shared = np.array([1.0, 0.0, 2.0]) / np.sqrt(5.0)
    np.testing.assert_allclose(N, [shared, [0, 0, 1], shared, [1, 0, 0]], atol=1e-15)
    isolated = vertex_normals(np.r_[V2, [[9.0, 9.0, 9.0]]], F2)
    np.testing.assert_array_equal(isolated[4], [0.0, 0.0, 0.0])  # no face: zero, not NaN


def test_vertex_areas_are_a_third_of_the_incident_triangles():
    np.testing.assert_allclose(vertex_areas(V2, F2), [0.5, 1 / 3, 0.5, 1 / 6], atol=1e-15)
    np.testing.assert_allclose(vertex_areas(V2.astype(np.float32), F2.astype(np.int32)),
                               [0.5, 1 / 3, 0.5, 1 / 6], atol=1e-7)


def test_quads_split_along_the_first_diagonal_keeping_the_dtype():
    Q = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [3, 2, 8, 9]], dtype=np.int32)
    T = quads_to_triangles(Q)
    assert T.dtype == np.int32
    assert T.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], [3, 2, 8], [3, 8, 9]]
    assert quads_to_triangles([[0, 1, 2, 3]]).tolist() == [[0, 1, 2], [0, 2, 3]]


def test_checked_mesh_arrays_returns_float64_and_int64_and_takes_no_faces():
    V, F = checked_mesh_arrays("m.ply", np.ones((3, 3), dtype=np.float32), np.array([[0, 1, 2]], dtype=np.int32))
    assert V.dtype == np.float64 and F.dtype == np.int64
    V, F = checked_mesh_arrays("m.ply", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), dtype=np.int64))
    assert V.dtype == np.float64 and F.shape == (0, 3)
    checked_mesh_arrays("m.ply", np.zeros((3, 3)), [[0, 1, 2], [2, 1, 0]])  # indices 0 and n - 1 are valid


@pytest.mark.parametrize("V, F, message", [
    (np.zeros((4, 2)), [[0, 1, 2]], "m.ply: vertices must have 3 coordinates each, got shape (4, 2); fix the file"),
    (np.zeros(3), [[0, 1, 2]], "m.ply: vertices must have 3 coordinates each, got shape (3,); fix the file"),
    (np.array([["a", "b", "c"]] * 3), [[0, 1, 2]],
     "m.ply: vertices must have 3 coordinates each, got shape (3, 3); fix the file"),
    (np.zeros((4, 3)), [[0, 1, 2, 3]],
     "m.ply: faces must be triangles of vertex indices, got shape (1, 4); fix the file"),
    (np.zeros((4, 3)), [0, 1, 2], "m.ply: faces must be triangles of vertex indices, got shape (3,); fix the file"),
    (np.zeros((4, 3)), [[0.0, 1.0, 2.0]],
     "m.ply: faces must be triangles of vertex indices, got shape (1, 3); fix the file"),
    ([[np.nan, np.nan, 0], [0, 0, np.inf], [0, 0, 0]], [[0, 1, 2]], "m.ply: 2 vertices are NaN or infinite"),
    (np.zeros((3, 3)), [[0, 1, 3]],
     "m.ply: face indices span [0, 3] but the file has 3 vertices; the face list is corrupt"),
    (np.zeros((3, 3)), [[-1, 1, 2]],
     "m.ply: face indices span [-1, 2] but the file has 3 vertices; the face list is corrupt"),
])
def test_checked_mesh_arrays_refusals(V, F, message):
    with pytest.raises(FileFormatError) as err:
        checked_mesh_arrays("m.ply", V, F)
    assert str(err.value) == message


PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element face 2
property list uchar int vertex_indices
end_header
0 0 0 10 20 30
2 0 0 40 50 60
0 1 0 70 80 90
0 1 0 100 110 120
3 0 1 2
3 0 2 3
"""


def test_load_mesh_reads_a_hand_written_ply_with_colours_and_keeps_duplicate_vertices(tmp_path):
    path = tmp_path / "hand.PLY"  # the suffix in capitals
    path.write_text(PLY)
    m = load_mesh(path)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 1, 0]])  # not merged
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(m.vertex_colors, [[10, 20, 30], [40, 50, 60], [70, 80, 90], [100, 110, 120]])
    assert m.vertex_colors.dtype == np.uint8 and m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    obj = tmp_path / "plain.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    m = load_mesh(str(obj))
    assert m.vertex_colors is None
    np.testing.assert_array_equal(m.faces, [[0, 1, 2]])


def test_load_mesh_concatenates_a_scene(tmp_path):
    a = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    b = trimesh.Trimesh([[0, 0, 2], [1, 0, 2], [0, 1, 2], [1, 1, 2]], [[0, 1, 2], [1, 3, 2]], process=False)
    path = tmp_path / "scene.glb"
    trimesh.Scene({"a": a, "b": b}).export(path)
    m = load_mesh(path)
    assert m.n_vertices == 7 and m.n_faces == 3


def test_load_mesh_refusals(tmp_path):
    cases = []
    missing = tmp_path / "none.ply"
    cases.append((missing, f"{missing}: no such mesh file"))
    odd = tmp_path / "mesh.xyz"
    odd.write_text("0 0 0\n")
    cases.append((odd, f"{odd}: unsupported mesh format; use one of .ply, .obj, .glb, .gltf, .stl, .off"))
    cloud = tmp_path / "cloud.ply"
    cloud.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n0 0 0\n1 1 1\n")
    cases.append((cloud, f"{cloud}: contains no triangles (a point cloud or empty file?); give a triangle mesh"))
    for path, message in cases:
        with pytest.raises(FileFormatError) as err:
            load_mesh(path)
        assert str(err.value) == message
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    try:  # trimesh's own complaint, named in the message
        trimesh.load(broken, process=False, force="mesh")
    except Exception as exc:  # noqa: BLE001
        expected = f"{broken}: cannot read mesh ({type(exc).__name__}: {exc})"
    with pytest.raises(FileFormatError) as err:
        load_mesh(broken)
    assert str(err.value) == expected
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 nan\nf 1 2 3\n")
    with pytest.raises(FileFormatError) as err:
        load_mesh(bad)
    assert str(err.value) == f"{bad}: 1 vertices are NaN or infinite"


@pytest.mark.parametrize("suffix", [".ply", ".OBJ", ".stl", ".off", ".glb"])
def test_save_mesh_writes_what_trimesh_reads_back(tmp_path, suffix):
    colors = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90], [100, 110, 120]], dtype=np.uint8)
    V = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])  # a duplicate vertex
    path = tmp_path / f"out{suffix}"
    save_mesh(path, Mesh(V, F2, colors))
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temp file left
    back = trimesh.load(path, process=False, force="mesh")
    if suffix == ".stl":  # STL stores triangle soup
        np.testing.assert_allclose(back.vertices[back.faces], V[F2], atol=1e-6)
        return
    np.testing.assert_allclose(back.vertices, V, atol=1e-6)
    np.testing.assert_array_equal(back.faces, F2)
    if suffix == ".ply":
        np.testing.assert_array_equal(np.asarray(back.visual.vertex_colors)[:, :3], colors)
        assert path.read_bytes().startswith(b"ply\nformat binary_little_endian")


def test_save_mesh_refuses_an_unknown_suffix(tmp_path):
    path = tmp_path / "out.xyz"
    with pytest.raises(FileFormatError) as err:
        save_mesh(path, Mesh(V2, F2))
    assert str(err.value) == f"{path}: unsupported mesh format; use one of .ply, .obj, .glb, .gltf, .stl, .off"
    assert not path.exists()
