"""avatar.py's glTF skin reader against arrays written by hand with pygltflib (mutMM).

Each file is built here from known arrays (positions, faces, joints, weights, inverse bind matrices, node
transforms) in the layouts glTF allows (interleaved views, normalized integer weights, no indices, no inverse
bind matrices, several primitives, a matrix or TRS on the mesh node); what ``load_avatar`` reads back is compared
with those arrays and with the transforms applied by hand.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.viewer import avatar as av

V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.5, 2.0, 0.25], [1.0, 2.0, 0.5]])
F = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
J = np.array([[0, 1, 0, 0], [1, 2, 0, 0], [2, 0, 0, 0], [1, 0, 0, 0], [2, 1, 0, 0], [0, 0, 0, 0]], np.uint16)
# the last row sums to 0.5: the reader renormalises every vertex's weights
W = np.array([[0.75, 0.25, 0, 0], [0.5, 0.5, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0], [0.6, 0.4, 0, 0], [0.5, 0, 0, 0]],
             np.float32)
HEADS = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.5, 0.5]])


def _glb(path, *, interleave=False, normalized=False, indices=True, ibm=True, names=("root", None, "tip"),
         mesh_node=None, primitives=1, joints_beyond=False, drop=None, quantized=False):
    import pygltflib as g

    blobs, views, accs = [], [], []

    def add(arr, comp, typ, target=None, stride=None, **acc):
        raw = np.ascontiguousarray(arr).tobytes()
        offset = sum(len(b) for b in blobs)
        blobs.append(raw + b"\0" * (-len(raw) % 4))
        views.append(g.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw), target=target,
                                  byteStride=stride))
        accs.append(g.Accessor(bufferView=len(views) - 1, componentType=comp, count=len(arr), type=typ, **acc))
        return len(accs) - 1

    prims = []
    for _ in range(primitives):
        if interleave:  # positions after 4 padding floats in each 28-byte row: a stride and an accessor offset
            inter = np.c_[np.full((len(V), 4), 7.0, np.float32), V.astype(np.float32)]
            pos = add(inter, 5126, "VEC3", 34962, stride=28, byteOffset=16)
            accs[pos].count = len(V)
        elif quantized:  # normalized int16 positions (KHR_mesh_quantization): V / 4 in [-1, 1]
            pos = add(np.round(V / 4 * 32767).astype(np.int16).repeat(1, 0), 5122, "VEC3", 34962, normalized=True)
        else:
            pos = add(V.astype(np.float32), 5126, "VEC3", 34962)
        idx = add(F.astype(np.uint32).ravel(), 5125, "SCALAR", 34963) if indices else None
        joints = J.copy()
        if joints_beyond:
            joints[0, 0] = 3
        jo = add(joints, 5123, "VEC4", 34962)
        if normalized:
            wt = add(np.round(W * 255).astype(np.uint8), 5121, "VEC4", 34962, normalized=True)
        else:
            wt = add(W, 5126, "VEC4", 34962)
        attrs = g.Attributes(POSITION=pos, JOINTS_0=jo, WEIGHTS_0=wt)
        if drop:
            setattr(attrs, drop, None)
        prims.append(g.Primitive(attributes=attrs, indices=idx))
    ibm_index = None
    if ibm:
        mats = np.tile(np.eye(4), (3, 1, 1))
        mats[:, :3, 3] = -HEADS
        ibm_index = add(mats.transpose(0, 2, 1).astype(np.float32).reshape(3, 16), 5126, "MAT4")
    # joints: root at the origin, its child 1 m up, a grandchild 0.5 m up and 0.5 m forward
    joint_nodes = [g.Node(name=names[0], translation=[0.0, 0.0, 0.0], children=[2]),
                   g.Node(name=names[1], translation=[0.0, 1.0, 0.0], children=[3]),
                   g.Node(name=names[2], translation=[0.0, 0.5, 0.5])]
    node = mesh_node or g.Node(name="body")
    node.mesh, node.skin = 0, 0
    gltf = g.GLTF2(scene=0, scenes=[g.Scene(nodes=[0, 1])], nodes=[node, *joint_nodes],
                   meshes=[g.Mesh(primitives=prims)], skins=[g.Skin(joints=[1, 2, 3], inverseBindMatrices=ibm_index)],
                   accessors=accs, bufferViews=views, buffers=[g.Buffer(byteLength=sum(len(b) for b in blobs))])
    gltf.set_binary_blob(b"".join(blobs))
    gltf.save_binary(str(path))
    return path


def _weights(w=W) -> np.ndarray:
    out = np.zeros((len(V), 3))
    for i in range(len(V)):
        for j, x in zip(J[i], w[i], strict=True):
            out[i, j] += x
    return out / out.sum(1, keepdims=True)


def test_round_trip_of_positions_faces_weights_bones_and_names(tmp_path):
    a = av.load_avatar(_glb(tmp_path / "a.glb"))
    assert np.allclose(a.mesh.vertices, V) and np.array_equal(a.mesh.faces, F)
    q = av.load_avatar(_glb(tmp_path / "q.glb", quantized=True))
    assert np.allclose(q.mesh.vertices, V / 4, atol=1e-4)  # normalized integers are divided by their max
    assert np.allclose(a.weights, _weights(), atol=1e-7)
    assert np.allclose(a.heads, HEADS, atol=1e-6)
    assert a.parents.tolist() == [-1, 0, 1] and a.bone_names == ("root", "joint1", "tip") and a.n_bones == 3
    assert a.parents.dtype.kind == "i" and a.mesh.faces.dtype.kind == "i"  # indices stay integers
    # a bone's tail is its first child's head; the leaf extends its parent's direction by half
    assert np.allclose(a.tails, [[0.0, 1.0, 0.0], [0.0, 1.5, 0.5], [0.0, 1.75, 0.75]], atol=1e-6)
    assert a.dominant_bone.tolist() == [0, 1, 2, 1, 2, 0]


def test_layouts_glTF_allows(tmp_path):
    a = av.load_avatar(_glb(tmp_path / "b.glb", interleave=True, normalized=True, ibm=False))
    assert np.allclose(a.mesh.vertices, V)  # the 28-byte stride read row by row
    assert np.array_equal(a.mesh.faces, F)
    assert np.allclose(a.weights, _weights(np.round(W * 255) / 255), atol=1e-9)  # normalized uint8 / 255
    assert np.allclose(a.heads, HEADS, atol=1e-9)  # from the joint nodes' world transforms
    three = av.load_avatar(_glb(tmp_path / "c.glb", primitives=3))
    n = len(V)
    assert np.allclose(three.mesh.vertices, np.r_[V, V, V])
    assert np.array_equal(three.mesh.faces, np.r_[F, F + n, F + 2 * n])
    assert np.allclose(three.weights, np.r_[_weights(), _weights(), _weights()], atol=1e-7)


def test_no_indices_means_consecutive_triangles(tmp_path):
    import pygltflib as g

    path = _glb(tmp_path / "d.glb", indices=False)
    gltf = g.GLTF2().load(str(path))
    a = av.load_avatar(path)
    assert np.array_equal(a.mesh.faces, [[0, 1, 2], [3, 4, 5]]) and np.allclose(a.mesh.vertices, V)
    gltf = g.GLTF2().load(str(path))
    gltf.nodes[0].skin = None  # a skin nobody uses is not an avatar
    gltf.save_binary(str(tmp_path / "unskinned.glb"))
    assert not av.glb_has_skin(tmp_path / "unskinned.glb")


def test_the_mesh_nodes_matrix_or_trs_moves_the_vertices(tmp_path):
    import pygltflib as g
    from scipy.spatial.transform import Rotation

    M = np.eye(4)
    M[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    M[:3, 3] = [1.0, 2.0, 3.0]
    a = av.load_avatar(_glb(tmp_path / "m.glb", mesh_node=g.Node(matrix=M.T.ravel().tolist())))  # column-major
    assert np.allclose(a.mesh.vertices, V @ M[:3, :3].T + M[:3, 3], atol=1e-6)
    q = Rotation.from_euler("x", 30, degrees=True)
    node = g.Node(rotation=q.as_quat().tolist(), scale=[2.0, 1.0, 0.5], translation=[0.0, -1.0, 4.0])
    a = av.load_avatar(_glb(tmp_path / "t.glb", mesh_node=node))
    expected = (V * [2.0, 1.0, 0.5]) @ q.as_matrix().T + [0.0, -1.0, 4.0]  # T R S
    assert np.allclose(a.mesh.vertices, expected, atol=1e-6)
    bad = g.Node(matrix=[1.0] * 15, translation=[5.0, 0.0, 0.0])  # a matrix of 15 numbers is ignored
    assert np.allclose(av.load_avatar(_glb(tmp_path / "x.glb", mesh_node=bad)).mesh.vertices, V + [5, 0, 0])


def test_refusals_are_one_line(tmp_path):
    with pytest.raises(FileFormatError) as exc:
        av.load_avatar(tmp_path / "none.glb")
    assert str(exc.value) == f"{tmp_path / 'none.glb'}: no such avatar file"
    path = _glb(tmp_path / "j.glb", joints_beyond=True)
    with pytest.raises(FileFormatError) as exc:
        av.load_avatar(path)
    assert str(exc.value) == f"{path}: JOINTS_0 refers to joint 3 of a 3-joint skin"
    for attr in ("POSITION", "JOINTS_0", "WEIGHTS_0"):
        path = _glb(tmp_path / f"d{attr}.glb", drop=attr)
        with pytest.raises(FileFormatError) as exc:
            av.load_avatar(path)
        assert str(exc.value) == f"{path}: skinned primitive lacks POSITION, JOINTS_0 or WEIGHTS_0"
    from bodystudio.geometry.mesh import Mesh, save_mesh

    save_mesh(tmp_path / "plain.glb", Mesh(V, F))
    assert not av.glb_has_skin(tmp_path / "plain.glb") and av.glb_has_skin(tmp_path / "j.glb")
    with pytest.raises(FileFormatError) as exc:
        av.load_avatar(tmp_path / "plain.glb")
    assert str(exc.value) == (f"{tmp_path / 'plain.glb'}: glTF has no skinned mesh; give an avatar written by "
                              "'bodystudio rig'")
    (tmp_path / "junk.glb").write_bytes(b"not a gltf at all")
    assert not av.glb_has_skin(tmp_path / "junk.glb")


def test_as_avatar_from_a_body_a_rig_or_bare_bones():
    a = av.Avatar(None, ("a",), np.array([-1]), np.zeros((1, 3)), np.ones((1, 3)), np.ones((1, 1)))
    assert av.as_avatar(a) is a
    sk = SimpleNamespace(bone_names=["r", "c"], parents=[-1, 0], heads=HEADS[:2], tails=HEADS[1:])
    body = SimpleNamespace(skeleton=sk, weights=[[1.0, 0.0]], vertices=V[:3], faces=F[:1])
    b = av.as_avatar(body)
    assert b.bone_names == ("r", "c") and np.array_equal(b.tails, HEADS[1:]) and np.array_equal(b.mesh.faces, F[:1])
    assert np.array_equal(b.heads, HEADS[:2])
    assert b.parents.tolist() == [-1, 0] and np.array_equal(b.weights, [[1.0, 0.0]])
    R = np.tile(np.eye(3), (3, 1, 1))
    R[2] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # bone 2's y axis points along +z
    rig = SimpleNamespace(heads=HEADS.tolist(), parents=[-1, 0, 1], bind_rotations=R, bone_lengths=[1.0, 0.5, 2.0],
                          mesh="m", bone_names=["a", "b", "c"], weights=[[1, 0, 0]])
    r = av.as_avatar(rig)
    assert np.allclose(r.tails, HEADS + [[0, 1.0, 0], [0, 0.5, 0], [0, 0, 2.0]]) and r.heads.dtype == np.float64
    assert (r.mesh, r.bone_names, r.parents.tolist(), r.weights.tolist()) == ("m", ("a", "b", "c"), [-1, 0, 1],
                                                                             [[1, 0, 0]])
    plain = av.as_avatar(SimpleNamespace(heads=HEADS, parents=[-1, 0, 1], mesh="m", bone_names="abc",
                                         weights=[[1, 0, 0]]))  # no bind rotations at all
    half = av.as_avatar(SimpleNamespace(heads=[[0, 0, 0], [0, 1, 0]], parents=[-1, 0], mesh="m", bone_names="ab",
                                        weights=[[1, 0]], bind_rotations=R[:2]))  # rotations without lengths
    assert half.heads.dtype == np.float64 and np.allclose(half.tails, [[0, 1, 0], [0, 1.5, 0]])
    assert np.allclose(plain.tails, [[0.0, 1.0, 0.0], [0.0, 1.5, 0.5], [0.0, 1.75, 0.75]])
    bare = av.as_avatar(SimpleNamespace(heads=HEADS, parents=[-1, 0, 1], mesh="m", bone_names=["a", "b", "c"],
                                        weights=[[1, 0, 0]], bind_rotations=R, bone_lengths=None))
    assert np.allclose(bare.tails, [[0.0, 1.0, 0.0], [0.0, 1.5, 0.5], [0.0, 1.75, 0.75]])
    forest = av._tails_from_children(np.array([[0.0, 0, 0], [1.0, 0, 0]]), np.array([-1, -1]))
    assert np.array_equal(forest, [[0.0, 0, 0], [1.0, 0, 0]])  # a lone root keeps a zero-length bone
    leaf = av._tails_from_children(np.array([[0.0, 0, 0], [0.0, 1, 0]]), np.array([-1, 0]))
    assert np.array_equal(leaf[1], [0.0, 1.5, 0.0])  # a leaf whose parent is bone 0 extends it too


def test_gltf_with_an_external_buffer_and_without_it(tmp_path):
    import pygltflib as g

    glb = _glb(tmp_path / "e.glb")
    gltf = g.GLTF2().load(str(glb))
    gltf.convert_buffers(g.BufferFormat.BINFILE)
    gltf.save(str(tmp_path / "e.gltf"))
    a = av.load_avatar(tmp_path / "e.gltf")
    assert np.allclose(a.mesh.vertices, V) and np.allclose(a.weights, _weights(), atol=1e-7)
    (bin_file,) = [p for p in tmp_path.iterdir() if p.suffix == ".bin"]
    bin_file.unlink()
    with pytest.raises(FileFormatError) as exc:
        av.load_avatar(tmp_path / "e.gltf")
    assert str(exc.value) == (f"{tmp_path / 'e.gltf'}: cannot read its buffer {bin_file.name!r}; keep the .bin file "
                              "beside the .gltf")
    (tmp_path / "junk.glb").write_bytes(b"not a gltf at all")
    with pytest.raises(FileFormatError) as exc:
        av.load_avatar(tmp_path / "junk.glb")
    assert str(exc.value) == (f"{tmp_path / 'junk.glb'}: cannot read glTF (OSError: Unable to load binary gltf file. "
                              "Header does not appear to be valid glb format.)")
