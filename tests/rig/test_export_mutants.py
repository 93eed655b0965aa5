"""rig/export.py against independent references (issue 17, branch mutDD): a five-bone stand-in avatar on an
icosphere written to glb and read back with pygltflib (accessors decoded from their componentType / type, not
from what we wrote) and trimesh, posed the glTF way (node TRS hierarchy x inverse bind matrices) and compared
with the avatar's own skinning; the BVH parsed and posed by forward kinematics with hand-built Z, X, Y matrices;
``skin_arrays`` on hand-computed rows; ``bake_vertex_colors`` against a per-pixel loop; the rig description,
``write_rig`` and every refusal of ``check_rig_pair`` word for word.
"""

import io
import json
from functools import cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.errors import FileFormatError
from bodystudio.rig import export as ex
from bodystudio.rig.avatar import Avatar
from bodystudio.runfolder import RunLayout, RunWriter

NAMES = ("root", "spine", "head", "arm", "hand")
PARENTS = np.array([-1, 0, 1, 1, 3])
COMPONENT = {5121: (np.uint8, 1), 5123: (np.uint16, 2), 5125: (np.uint32, 4), 5126: (np.float32, 4)}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _mesh():
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=1)
    V = np.asarray(s.vertices, float) * [0.3, 0.9, 0.2] + [0.1, 1.0, -0.05]
    return V, np.asarray(s.faces, np.int64)


@cache
def _avatar(colors: bool = True, shift: float = 0.0) -> Avatar:
    rng = np.random.default_rng(5)
    V, F = _mesh()
    V = V + shift
    B = len(NAMES)
    bind = Rotation.random(B, random_state=7).as_matrix()
    rest = Rotation.random(B, random_state=8).as_matrix()
    heads = rng.normal(size=(B, 3)) * 0.3 + [0.0, 1.0, 0.0]
    W = rng.random((len(V), B)) ** 2
    for row in W:  # at most 4 influences per vertex (the glb stores 4); some rows fewer
        row[rng.permutation(B)[: 1 + rng.integers(0, 3)]] = 0.0
    W /= W.sum(1, keepdims=True)
    col = rng.integers(0, 256, size=(len(V), 3)).astype(np.uint8) if colors else None
    return Avatar(V, F, col, NAMES, PARENTS, None, bind, rest, np.array([0.1, 0.2, 0.15, 0.25, 0.05]), W,
                  np.array([0.02, -0.01, 0.03]), {"fit_err_mm_median": 1.5, "scan": "s.ply"}, loaded_heads=heads)


def _read(path_or_bytes):
    import pygltflib

    if isinstance(path_or_bytes, bytes):
        g = pygltflib.GLTF2.load_from_bytes(path_or_bytes)
    else:
        g = pygltflib.GLTF2().load(str(path_or_bytes))
    return g, g.binary_blob()


def _accessor(g, blob, i):
    """Decode accessor ``i`` from its own componentType, type, count and offsets."""
    a = g.accessors[i]
    dtype, size = COMPONENT[a.componentType]
    width = WIDTH[a.type]
    v = g.bufferViews[a.bufferView]
    assert v.byteLength == a.count * width * size
    start = (v.byteOffset or 0) + (a.byteOffset or 0)
    return np.frombuffer(blob, dtype, a.count * width, start).reshape(a.count, width)


def _glb(texture: bool = False, colors: bool = True):
    """Written anew in every test: mutmut's forked mutants inherit cached results, which would hide a mutant."""
    return ex.glb_bytes(_avatar(colors), texture)


def _glb_json(data: bytes) -> dict:
    """The JSON chunk of a GLB, read by the container format's own layout (12-byte header, chunk length + type)."""
    import struct

    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data)
    chunk_length, chunk_type = struct.unpack_from("<I4s", data, 12)
    assert chunk_type == b"JSON"
    return json.loads(data[20: 20 + chunk_length])


def _normals(V, F):
    """Area-weighted unit vertex normals by a loop over the faces."""
    N = np.zeros_like(V)
    for f in F:
        n = np.cross(V[f[1]] - V[f[0]], V[f[2]] - V[f[0]])
        for k in f:
            N[k] += n
    return N / np.linalg.norm(N, axis=1, keepdims=True)


def _node_worlds(g, local_rotations=None):
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    world = {}

    def node_world(i):
        if i not in world:
            n = g.nodes[i]
            L = np.eye(4)
            L[:3, :3] = (Rotation.from_quat(n.rotation).as_matrix() if local_rotations is None
                         else local_rotations[i])
            L[:3, 3] = n.translation
            world[i] = node_world(parent[i]) @ L if i in parent else L
        return world[i]

    return np.stack([node_world(j) for j in g.skins[0].joints])


def test_skin_arrays_hand_computed_rows():
    W = np.array([[0.1, 0.2, 0.3, 0.35, 0.05],  # five influences: the smallest dropped, the rest renormalised
                  [5e-7, 0.0, 0.0, 1.0, 2e-6],  # 5e-7 is below 1e-6: dropped, joint slot 0
                  [0.0, 0.0, 1.0, 0.0, 0.0]])
    idx, w = ex.skin_arrays(W)
    assert idx.dtype == np.uint16 and w.dtype == np.float32 and idx.shape == w.shape == (3, 4)
    np.testing.assert_array_equal(idx[0], [3, 2, 1, 0])
    np.testing.assert_allclose(w[0], np.array([0.35, 0.3, 0.2, 0.1]) / 0.95, atol=1e-7)
    np.testing.assert_array_equal(idx[1], [3, 4, 0, 0])
    np.testing.assert_allclose(w[1], [1 / (1 + 2e-6), 2e-6 / (1 + 2e-6), 0, 0], atol=1e-7)
    assert w[1, 1] > 0 and w[1, 2] == 0 and w[1, 3] == 0
    np.testing.assert_array_equal(idx[2], [2, 0, 0, 0])
    np.testing.assert_array_equal(w[2], [1, 0, 0, 0])
    # k other than 4
    idx3, w3 = ex.skin_arrays(W, k=3)
    assert idx3.shape == (3, 3)
    np.testing.assert_allclose(w3[0], np.array([0.35, 0.3, 0.2]) / 0.85, atol=1e-7)


def test_skin_arrays_of_two_bones_pad_to_four_slots():
    idx, w = ex.skin_arrays(np.array([[0.25, 0.75], [1.0, 0.0]]))
    assert idx.shape == w.shape == (2, 4)
    np.testing.assert_array_equal(idx, [[1, 0, 0, 0], [0, 0, 0, 0]])
    np.testing.assert_array_equal(w, np.array([[0.75, 0.25, 0, 0], [1, 0, 0, 0]], np.float32))
    idx, w = ex.skin_arrays(np.array([[0.5, 0.2, 0.3]]), k=5)
    np.testing.assert_array_equal(idx, [[0, 2, 1, 0, 0]])
    np.testing.assert_allclose(w, [[0.5, 0.3, 0.2, 0, 0]], atol=1e-7)


def test_skin_arrays_float32_rows_sum_exactly_one_with_the_fix_on_the_first_slot():
    rng = np.random.default_rng(1)
    W = rng.random((400, 4))
    W /= 3.0 * W.sum(1, keepdims=True)  # rows summing to 1/3: the float32 renormalisation leaves round-off
    idx, w = ex.skin_arrays(W)
    ref = np.take_along_axis(W, np.argsort(-W, axis=1), axis=1).astype(np.float32)
    ref /= ref.sum(1, keepdims=True)
    # within one float32 step of 1 (glTF's tolerance), and more often exactly 1 than the plain normalisation
    assert np.abs(w.sum(1, dtype=np.float32) - 1.0).max() <= 1.2e-7
    assert (w.sum(1, dtype=np.float32) != 1).sum() < (ref.sum(1, dtype=np.float32) != 1).sum()
    # only the first (largest) slot carries the float32 fix; the others are the plain normalised weights
    np.testing.assert_array_equal(w[:, 1:], ref[:, 1:])
    fix = np.float32(1.0) - ref.sum(1, dtype=np.float32)
    assert np.any(fix != 0), "no row needed the float32 fix: pick other weights"
    np.testing.assert_array_equal(w[:, 0], ref[:, 0] + fix)


def _bake_reference(uv, faces, colors, size):
    px = np.c_[uv[:, 0] * size, (1.0 - uv[:, 1]) * size]
    img = np.zeros((size, size, 3))
    mask = np.zeros((size, size), bool)
    for f in faces:
        P = px[f]
        M = np.array([[P[0, 0] - P[2, 0], P[1, 0] - P[2, 0]], [P[0, 1] - P[2, 1], P[1, 1] - P[2, 1]]])
        for yy in range(size):
            for xx in range(size):
                lam = np.linalg.solve(M, [xx + 0.5 - P[2, 0], yy + 0.5 - P[2, 1]])
                bary = [lam[0], lam[1], 1.0 - lam[0] - lam[1]]
                if min(bary) >= -0.02:
                    img[yy, xx] = sum(b * colors[k].astype(float) for b, k in zip(bary, f, strict=True))
                    mask[yy, xx] = True
    for _ in range(4):
        new_img, new_mask = img.copy(), mask.copy()
        for yy in range(size):
            for xx in range(size):
                if mask[yy, xx]:
                    continue
                nb = [((yy + dy) % size, (xx + dx) % size) for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1))]
                nb = [p for p in nb if mask[p]]
                if nb:
                    new_img[yy, xx] = np.mean([img[p] for p in nb], axis=0)
                    new_mask[yy, xx] = True
        img, mask = new_img, new_mask
    return np.clip(np.round(img), 0, 255)


def test_bake_vertex_colors_matches_a_per_pixel_loop():
    # a chart in the middle, one over the image's top-right corner (clamped), one degenerate (skipped)
    uv = np.array([[0.30, 0.30], [0.62, 0.36], [0.41, 0.66], [0.80, 0.70], [1.10, 1.05], [0.95, 0.88],
                   [0.1, 0.1], [0.2, 0.2], [0.3, 0.3]])
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    colors = np.array([[250, 0, 10], [0, 240, 30], [20, 40, 200], [200, 200, 0], [0, 100, 255], [90, 10, 60],
                       [255, 255, 255], [255, 255, 255], [255, 255, 255]], np.uint8)
    size = 24
    got = ex.bake_vertex_colors(uv, faces, colors, size=size)
    assert got.shape == (size, size, 3) and got.dtype == np.uint8
    want = _bake_reference(uv, faces[:2], colors, size)
    assert np.abs(got.astype(float) - want).max() <= 1.0
    assert (got == 0).all(axis=2).sum() > 50  # far from the charts nothing is painted
    assert ex.TEXTURE_SIZE == 1024  # the default size: the textured glb's image is checked at 1024 x 1024


def test_bake_clips_the_colours_extrapolated_past_an_edge():
    # pixel centres half a pixel above edge AB lie 1 % outside the triangle (inside the 2 % tolerance): the colour
    # extrapolated there from C = 255 and A = B = 0 is -2.55, clipped to 0 (not wrapped round to 253)
    size = 32
    px = np.array([[4.0, 7.7], [28.0, 7.7], [4.0, 27.7]])
    uv = np.c_[px[:, 0] / size, 1.0 - px[:, 1] / size]
    colors = np.array([[0, 0, 0], [0, 0, 0], [255, 255, 255]], np.uint8)
    got = ex.bake_vertex_colors(uv, np.array([[0, 1, 2]]), colors, size=size)
    assert (got[7, 5:20] == 0).all()
    assert abs(int(got[17, 6, 0]) - round(255 * (17.5 - 7.7) / 20)) <= 1


def test_uv_atlas_maps_back_onto_the_input_triangles():
    V, F = _mesh()
    vmap, F2, uv = ex.uv_atlas(V, F)
    assert vmap.dtype == np.int64 and F2.dtype == np.int64 and uv.dtype == np.float64
    assert len(F2) == len(F) and uv.shape == (len(vmap), 2)
    assert uv.min() >= 0.0 and uv.max() <= 1.0 and set(vmap) == set(range(len(V)))
    np.testing.assert_allclose(np.sort(V[vmap[F2]].sum(1), 0), np.sort(V[F].sum(1), 0))
    assert sorted(map(tuple, np.sort(vmap[F2], axis=1))) == sorted(map(tuple, np.sort(F, axis=1)))


def test_glb_fields_read_back_with_pygltflib():
    av = _avatar()
    data, vmap = _glb()
    assert vmap is None and ex.glb_bytes(av) == (data, None)  # no texture by default
    raw = _glb_json(data)
    assert raw["asset"] == {"version": "2.0", "generator": "bodystudio rig"}
    assert raw["buffers"] == [{"byteLength": max(v["byteOffset"] + v["byteLength"] for v in raw["bufferViews"])}]
    g, blob = _read(data)
    assert g.asset.version == "2.0" and g.asset.generator == "bodystudio rig"
    prim = g.meshes[0].primitives[0]
    assert g.meshes[0].name == "scan" and prim.material == 0 and len(g.meshes) == 1
    P = _accessor(g, blob, prim.attributes.POSITION)
    np.testing.assert_array_equal(P, av.vertices.astype(np.float32))
    acc = g.accessors[prim.attributes.POSITION]
    np.testing.assert_array_equal(acc.min, av.vertices.astype(np.float32).min(0))
    np.testing.assert_array_equal(acc.max, av.vertices.astype(np.float32).max(0))
    np.testing.assert_allclose(_accessor(g, blob, prim.attributes.NORMAL), _normals(av.vertices, av.faces), atol=1e-6)
    J = _accessor(g, blob, prim.attributes.JOINTS_0)
    W = _accessor(g, blob, prim.attributes.WEIGHTS_0)
    dense = np.zeros_like(av.weights)
    for i in range(len(J)):
        for k in range(4):
            dense[i, J[i, k]] += W[i, k]
    np.testing.assert_allclose(dense, av.weights, atol=1e-6)
    C = _accessor(g, blob, prim.attributes.COLOR_0)
    np.testing.assert_array_equal(C[:, :3], av.vertex_colors)
    assert (C[:, 3] == 255).all() and g.accessors[prim.attributes.COLOR_0].normalized is True
    for name in ("POSITION", "NORMAL", "JOINTS_0", "WEIGHTS_0"):
        assert not g.accessors[getattr(prim.attributes, name)].normalized
    assert prim.attributes.TEXCOORD_0 is None
    np.testing.assert_array_equal(_accessor(g, blob, prim.indices).reshape(-1, 3), av.faces)
    assert not g.accessors[prim.indices].min and not g.accessors[prim.attributes.NORMAL].max
    ibm = _accessor(g, blob, g.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    bind = np.tile(np.eye(4), (5, 1, 1))
    bind[:, :3, :3], bind[:, :3, 3] = av.bind_rotations, av.heads
    np.testing.assert_allclose(ibm @ bind, np.tile(np.eye(4), (5, 1, 1)), atol=1e-6)
    targets = {a: g.bufferViews[g.accessors[a].bufferView].target for a in
               (prim.attributes.POSITION, prim.attributes.NORMAL, prim.attributes.JOINTS_0, prim.attributes.WEIGHTS_0,
                prim.attributes.COLOR_0)}
    assert set(targets.values()) == {34962}
    assert g.bufferViews[g.accessors[prim.indices].bufferView].target == 34963
    assert g.bufferViews[g.accessors[g.skins[0].inverseBindMatrices].bufferView].target is None
    assert all((v.byteOffset or 0) % 4 == 0 and v.buffer == 0 for v in g.bufferViews)
    assert g.buffers[0].byteLength == max(v.byteOffset + v.byteLength for v in g.bufferViews)
    assert len(g.buffers) == 1
    mat = g.materials[0]
    assert mat.name == "scan" and mat.pbrMetallicRoughness.metallicFactor == 0.0
    assert mat.pbrMetallicRoughness.roughnessFactor == 0.9 and mat.pbrMetallicRoughness.baseColorTexture is None
    assert g.textures == [] and g.images == [] and g.samplers == []
    # nodes: one per bone in order, then the mesh node; the scene holds the root and the mesh node
    assert [n.name for n in g.nodes] == list(NAMES) + ["avatar"]
    assert [n.children or None for n in g.nodes[:5]] == [[1], [2, 3], None, [4], None]
    assert g.nodes[5].mesh == 0 and g.nodes[5].skin == 0 and not g.nodes[5].children
    assert g.scene == 0 and g.scenes[0].nodes == [0, 5]
    skin = g.skins[0]
    assert skin.joints == [0, 1, 2, 3, 4] and skin.skeleton == 0 and skin.name == "rig"
    # the node hierarchy at rest rebuilds the bind frames (translation and rotation of every bone)
    np.testing.assert_allclose(_node_worlds(g), bind, atol=1e-6)
    for n in g.nodes[:5]:
        assert np.isclose(np.linalg.norm(n.rotation), 1.0)


def test_glb_skin_poses_like_the_avatar_and_trimesh_reads_it(tmp_path):
    import trimesh

    av = _avatar()
    path = tmp_path / "a.glb"
    assert ex.write_glb(path, av) is None
    assert path.read_bytes() == _glb()[0]
    g, blob = _read(path)
    prim = g.meshes[0].primitives[0]
    V = _accessor(g, blob, prim.attributes.POSITION).astype(float)
    J = _accessor(g, blob, prim.attributes.JOINTS_0)
    W = _accessor(g, blob, prim.attributes.WEIGHTS_0).astype(float)
    ibm = _accessor(g, blob, g.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    rng = np.random.default_rng(2)
    pose = Pose(rng.normal(size=(5, 3)) * 0.5, np.array([0.3, -0.2, 0.1]))
    local = av.local_node_rotations(pose)
    worlds = _node_worlds(g, local)
    worlds[:, :3, 3] += (pose.translation - av.bind_translation)  # the glb's root node stays at the bind place
    mats = worlds @ ibm
    Vh = np.c_[V, np.ones(len(V))]
    posed = sum(W[:, k, None] * np.einsum("nij,nj->ni", mats[J[:, k]], Vh) for k in range(4))[:, :3]
    ours, _ = av.posed(pose)
    assert np.abs(posed - ours).max() < 1e-4
    scene = trimesh.load(path)
    (mesh,) = scene.geometry.values()
    assert len(mesh.vertices) == len(av.vertices) and len(mesh.faces) == len(av.faces)


def _textured():
    return ex.glb_bytes(_avatar(), True)


def test_textured_glb_splits_vertices_and_bakes_the_colours():
    from PIL import Image

    av = _avatar()
    data, vmap = _textured()
    assert vmap is not None and len(vmap) > len(av.vertices) and vmap.max() == len(av.vertices) - 1
    g, blob = _read(data)
    prim = g.meshes[0].primitives[0]
    assert prim.attributes.COLOR_0 is None
    P = _accessor(g, blob, prim.attributes.POSITION)
    np.testing.assert_array_equal(P, av.vertices[vmap].astype(np.float32))
    # normals of the avatar's own (unsplit) surface, not of the split one
    np.testing.assert_allclose(_accessor(g, blob, prim.attributes.NORMAL), _normals(av.vertices, av.faces)[vmap],
                               atol=1e-6)
    J = _accessor(g, blob, prim.attributes.JOINTS_0)
    W = _accessor(g, blob, prim.attributes.WEIGHTS_0)
    dense = np.zeros((len(vmap), 5))
    for k in range(4):
        np.add.at(dense, (np.arange(len(vmap)), J[:, k]), W[:, k])
    np.testing.assert_allclose(dense, av.weights[vmap], atol=1e-6)
    F = _accessor(g, blob, prim.indices).reshape(-1, 3).astype(np.int64)
    assert sorted(map(tuple, np.sort(vmap[F], 1))) == sorted(map(tuple, np.sort(av.faces, 1)))
    T = _accessor(g, blob, prim.attributes.TEXCOORD_0).astype(float)
    assert g.accessors[prim.attributes.TEXCOORD_0].type == "VEC2"
    for name in ("POSITION", "NORMAL", "JOINTS_0", "WEIGHTS_0", "TEXCOORD_0"):
        assert g.bufferViews[g.accessors[getattr(prim.attributes, name)].bufferView].target == 34962
    view = g.bufferViews[g.images[0].bufferView]
    assert view.target is None and view.byteOffset % 4 == 0 and g.images[0].mimeType == "image/png"
    img = np.asarray(Image.open(io.BytesIO(blob[view.byteOffset: view.byteOffset + view.byteLength])))
    assert img.shape == (1024, 1024, 3)
    # glTF's v runs down the image: the baked layout is uv = (s, 1 - t)
    # (the float32 coordinates read back move a handful of pixel values by one)
    diff = np.abs(img.astype(int) - ex.bake_vertex_colors(np.c_[T[:, 0], 1.0 - T[:, 1]], F, av.vertex_colors[vmap]))
    assert diff.max() <= 1 and (diff > 0).sum() < 100
    # each vertex's colour is found at its texture coordinate (s, t) in the image, rows from the top
    px = np.clip((T * 1024).astype(int), 0, 1023)
    assert np.median(np.abs(img[px[:, 1], px[:, 0]].astype(float) - av.vertex_colors[vmap])) <= 8
    assert g.samplers[0].magFilter == 9729 and g.samplers[0].minFilter == 9729
    assert g.textures[0].source == 0 and g.textures[0].sampler == 0
    pbr = g.materials[0].pbrMetallicRoughness
    assert pbr.baseColorTexture.index == 0 and pbr.metallicFactor == 0.0 and pbr.roughnessFactor == 0.9
    assert g.materials[0].name == "scan" and len(g.materials) == 1
    assert g.buffers[0].byteLength == view.byteOffset + view.byteLength


def test_texture_without_colours_writes_the_mesh_as_it_is():
    data, vmap = _glb(texture=True, colors=False)
    assert vmap is None
    g, blob = _read(data)
    prim = g.meshes[0].primitives[0]
    assert prim.attributes.COLOR_0 is None and prim.attributes.TEXCOORD_0 is None and g.images == []
    assert g.accessors[prim.attributes.POSITION].count == len(_avatar().vertices)


def _euler_zxy(z, x, y):
    cz, sz, cx, sx, cy, sy = (f(np.radians(a)) for a in (z, x, y) for f in (np.cos, np.sin))
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    return Rz @ Rx @ Ry


def _parse_bvh(text):
    """Joints (name, parent, offset, channels, end site) and frames of a BVH file, by its grammar."""
    tokens = text.split()
    joints, stack, i = [], [], 0
    assert tokens[0] == "HIERARCHY"
    i = 1
    while tokens[i] != "MOTION":
        t = tokens[i]
        if t in ("ROOT", "JOINT"):
            assert (t == "ROOT") == (not stack)
            joints.append({"name": tokens[i + 1], "parent": stack[-1] if stack else -1, "end": None})
            assert tokens[i + 2] == "{" and tokens[i + 3] == "OFFSET"
            joints[-1]["offset"] = np.array([float(v) for v in tokens[i + 4: i + 7]])
            assert tokens[i + 7] == "CHANNELS"
            n = int(tokens[i + 8])
            joints[-1]["channels"] = tokens[i + 9: i + 9 + n]
            stack.append(len(joints) - 1)
            i += 9 + n
        elif t == "End":
            assert tokens[i + 1: i + 4] == ["Site", "{", "OFFSET"] and tokens[i + 7] == "}"
            joints[stack[-1]]["end"] = np.array([float(v) for v in tokens[i + 4: i + 7]])
            i += 8
        elif t == "}":
            stack.pop()
            i += 1
        else:
            raise AssertionError(f"unexpected token {t!r}")
    assert not stack
    assert tokens[i + 1] == "Frames:" and tokens[i + 3: i + 5] == ["Frame", "Time:"]
    n_frames, frame_time = int(tokens[i + 2]), float(tokens[i + 5])
    values = np.array([float(v) for v in tokens[i + 6:]]).reshape(n_frames, -1) if n_frames else np.zeros((0, 0))
    return joints, frame_time, values


def _bvh_posed(joints, frame):
    """World head positions and rotations of one frame (BVH joints have identity rest orientation)."""
    pos, rot, k = {}, {}, 0
    for j, jt in enumerate(joints):
        ch = jt["channels"]
        vals = dict(zip(ch, frame[k: k + len(ch)], strict=True))
        k += len(ch)
        L = _euler_zxy(vals["Zrotation"], vals["Xrotation"], vals["Yrotation"])
        p = jt["parent"]
        if p < 0:
            pos[j] = np.array([vals["Xposition"], vals["Yposition"], vals["Zposition"]])
            rot[j] = L
        else:
            pos[j] = pos[p] + rot[p] @ jt["offset"]
            rot[j] = rot[p] @ L
    assert k == len(frame)
    return pos, rot


def test_bvh_posed_by_its_own_channels_follows_the_avatar(tmp_path):
    av = _avatar()
    rng = np.random.default_rng(4)
    poses = [Pose(rng.normal(size=(5, 3)) * 0.6, np.array([0.4, 0.1, -0.3])), Pose.rest(5),
             Pose(rng.normal(size=(5, 3)) * 0.3, np.zeros(3))]
    path = tmp_path / "m.bvh"
    ex.write_bvh(path, av, poses, fps=25.0)
    text = path.read_text()
    assert text.endswith("}\nMOTION\nFrames: 3\nFrame Time: 0.040000\n" + text.split("Frame Time: 0.040000\n")[1])
    assert text.endswith("\n") and not text.endswith("\n\n")
    joints, frame_time, values = _parse_bvh(text)
    assert frame_time == 0.04 and values.shape == (3, 6 + 3 * 4)
    assert [j["name"] for j in joints] == ["root", "spine", "head", "arm", "hand"]
    assert [j["parent"] for j in joints] == [-1, 0, 1, 1, 3]
    assert joints[0]["channels"] == ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]
    assert all(j["channels"] == ["Zrotation", "Xrotation", "Yrotation"] for j in joints[1:])
    h = av.heads
    np.testing.assert_allclose(joints[0]["offset"], h[0], atol=1e-6)
    for j in range(1, 5):
        np.testing.assert_allclose(joints[j]["offset"], h[j] - h[PARENTS[j]], atol=1e-6)
    assert [j["end"] is not None for j in joints] == [False, False, True, False, True]
    for pose, frame in zip(poses, values, strict=True):
        pos, rot = _bvh_posed(joints, frame)
        S = av.skinning_transforms(pose)
        _, heads = av.posed(pose)
        for j in range(5):
            np.testing.assert_allclose(pos[j], heads[j], atol=2e-5)
            np.testing.assert_allclose(rot[j], S[j, :3, :3], atol=2e-5)
            if joints[j]["end"] is not None:  # the bone's tail, moved by its skinning transform
                tail = h[j] + av.bind_rotations[j][:, 1] * av.bone_lengths[j]
                np.testing.assert_allclose(joints[j]["end"], tail - h[j], atol=1e-6)
                np.testing.assert_allclose(pos[j] + rot[j] @ joints[j]["end"], S[j, :3, :3] @ tail + S[j, :3, 3],
                                           atol=2e-5)
    lines = text.splitlines()
    assert lines[:4] == ["HIERARCHY", "ROOT root", "{", f"  OFFSET {h[0][0]:.6f} {h[0][1]:.6f} {h[0][2]:.6f}"]
    assert lines[5:7] == ["  JOINT spine", "  {"] and "      End Site" in lines and "      {" in lines
    assert lines[lines.index("MOTION") + 3] == " ".join(f"{v:.5f}" for v in values[0])


def test_bvh_of_two_roots_and_no_poses(tmp_path):
    av = _avatar()
    two = Avatar(av.vertices, av.faces, None, NAMES, np.array([-1, 0, -1, 2, 3]), None, av.bind_rotations,
                 av.rest_rotations, av.bone_lengths, av.weights, av.bind_translation, loaded_heads=av.heads)
    path = tmp_path / "two.bvh"
    ex.write_bvh(path, two, [])
    text = path.read_text()
    assert text.count("ROOT ") == 2 and "ROOT head" in text.splitlines()
    assert text.endswith("MOTION\nFrames: 0\nFrame Time: 0.033333\n")
    ex.write_bvh(path, two, [Pose.rest(5)])
    joints, _, values = _parse_bvh(path.read_text())
    assert values.shape == (1, 2 * 6 + 3 * 3)
    # the second root (after root and spine) at its head, moved by the pose's translation less the bind one
    np.testing.assert_allclose(values[0, 9:12], av.heads[2] - av.bind_translation, atol=1e-5)


def test_rig_description_field_by_field(tmp_path):
    av = _avatar()
    d = ex.rig_description(av)
    want = {"format": "bodystudio-rig", "version": 1, "bones": list(NAMES), "parents": [-1, 0, 1, 1, 3],
            "bind_heads_m": av.heads.tolist(), "bind_rotations": av.bind_rotations.tolist(),
            "rest_rotations": av.rest_rotations.tolist(), "bone_lengths_m": [0.1, 0.2, 0.15, 0.25, 0.05],
            "bind_translation_m": [0.02, -0.01, 0.03], "n_vertices": 42, "max_influences": 4,
            "fit_err_mm_median": 1.5, "scan": "s.ply"}
    assert d == want
    d = ex.rig_description(av, [3, 1, 1, 0])
    assert d == {**want, "n_vertices": 4, "n_avatar_vertices": 42, "vertex_source": [3, 1, 1, 0]}
    path = tmp_path / "a.rig.json"
    ex.write_rig_json(path, av)
    assert json.loads(path.read_text()) == want


def test_rig_paths_and_layout(tmp_path):
    glb = tmp_path / "sub" / "A.glb"
    assert ex.rig_json_path(glb) == tmp_path / "sub" / "A.rig.json"
    assert ex.rig_json_path(str(glb)) == tmp_path / "sub" / "A.rig.json"
    layout = ex.rig_layout(str(glb))
    assert layout == RunLayout(tmp_path / "sub", "A.rig.json", ".A.glb.", str(glb))
    assert layout.lock == tmp_path / "sub" / ".A.glb.lock"


def _written(tmp_path, texture=False, bvh=True, poses=None):
    glb = tmp_path / "A.glb"
    with RunWriter(ex.rig_layout(glb), "test rig") as w:
        manifest = ex.write_rig(w, str(glb), _avatar(), texture=texture, bvh=tmp_path / "m.bvh" if bvh else None,
                                poses=poses)
    return glb, manifest


def test_write_rig_commits_the_glb_bvh_and_description(tmp_path):
    poses = [Pose.rest(5)]
    glb, manifest = _written(tmp_path, poses=poses)
    assert glb.read_bytes() == _glb()[0]
    ex.write_bvh(tmp_path / "ref.bvh", _avatar(), poses)
    assert (tmp_path / "m.bvh").read_text() == (tmp_path / "ref.bvh").read_text()
    on_disk = json.loads((tmp_path / "A.rig.json").read_text())
    assert on_disk == json.loads(json.dumps(manifest))
    run = manifest.pop("run")
    assert manifest == ex.rig_description(_avatar())
    assert set(run["files"]) == {"A.glb", "m.bvh"}
    assert ex.check_rig_pair(glb) == on_disk
    assert ex.check_rig_pair(glb, 12345) == on_disk  # a run block decides; the count is for old rig.json files


def test_write_rig_textured_without_bvh_records_the_vertex_map(tmp_path):
    glb, manifest = _written(tmp_path, texture=True, bvh=False)
    assert not (tmp_path / "m.bvh").exists()
    g, blob = _read(glb)
    P = _accessor(g, blob, g.meshes[0].primitives[0].attributes.POSITION)
    vmap = np.array(manifest["vertex_source"])
    assert manifest["n_vertices"] == len(vmap) == len(P) > 42 and manifest["n_avatar_vertices"] == 42
    np.testing.assert_array_equal(P, _avatar().vertices[vmap].astype(np.float32))
    assert set(manifest["run"]["files"]) == {"A.glb"}


def test_write_rig_without_texture_by_default(tmp_path):
    glb = tmp_path / "A.glb"
    with RunWriter(ex.rig_layout(glb), "test rig") as w:
        manifest = ex.write_rig(w, glb, _avatar())
    assert glb.read_bytes() == _glb()[0] and "vertex_source" not in manifest
    assert set(manifest["run"]["files"]) == {"A.glb"}


def test_write_rig_bvh_without_poses_has_no_frames(tmp_path):
    _written(tmp_path, poses=None)
    assert (tmp_path / "m.bvh").read_text().endswith("Frames: 0\nFrame Time: 0.033333\n")


def test_check_rig_pair_refusals_word_for_word(tmp_path):
    glb = tmp_path / "A.glb"
    glb.write_bytes(_glb()[0])
    assert ex.check_rig_pair(glb) is None  # no rig.json beside it
    rig = tmp_path / "A.rig.json"
    for bad in ([1, 2], {"format": "x"}):
        rig.write_text(json.dumps(bad))
        with pytest.raises(FileFormatError) as e:
            ex.check_rig_pair(glb)
        assert str(e.value) == f"{rig}: not a bodystudio rig description; re-run `bodystudio rig`"
    old = {"bones": list(NAMES), "n_vertices": 42}
    rig.write_text(json.dumps(old))
    assert ex.check_rig_pair(glb) == old and ex.check_rig_pair(glb, 42) == old
    with pytest.raises(FileFormatError) as e:
        ex.check_rig_pair(glb, 41)
    assert str(e.value) == (f"{rig}: describes 42 vertices but {glb} has 41; the two are from different runs, "
                            "re-run `bodystudio rig`")
    rig.write_text(json.dumps({"bones": [], "n_vertices": None}))
    assert ex.check_rig_pair(glb, 41) == {"bones": [], "n_vertices": None}
    rig.write_text(json.dumps({"bones": []}))
    assert ex.check_rig_pair(glb, 41) == {"bones": []}
    # a run block that lists another avatar only
    from bodystudio.runfolder import sha256_file

    other = tmp_path / "B.glb"
    other.write_bytes(b"x")
    rig.write_text(json.dumps({"bones": [], "run": {"run_id": "r1", "files": {"B.glb": sha256_file(other)}}}))
    with pytest.raises(FileFormatError) as e:
        ex.check_rig_pair(glb, 42)
    assert str(e.value) == f"{rig}: describes another avatar than A.glb; re-run `bodystudio rig`"
    rig.write_text(json.dumps({"bones": [], "run": {"run_id": "r1", "files": {"A.glb": "0" * 64}}}))
    with pytest.raises(FileFormatError, match="does not belong to run r1"):
        ex.check_rig_pair(glb)
    rig.write_text(json.dumps({"bones": [], "run": {"run_id": "r1", "files": {"A.glb": sha256_file(glb)}},
                               "n_vertices": 7}))
    assert ex.check_rig_pair(glb, 42)["n_vertices"] == 7
    # only the glb is checked: the BVH the run also wrote may be gone or replaced
    rig.write_text(json.dumps({"bones": [], "run": {"run_id": "r1", "files": {"A.glb": sha256_file(glb),
                                                                              "m.bvh": "0" * 64}}}))
    assert ex.check_rig_pair(glb)["bones"] == []
    rig.write_text("{not json")
    with pytest.raises(FileFormatError) as e:
        ex.check_rig_pair(glb)
    assert str(e.value).startswith(f"{rig}: not a valid rig description (")
