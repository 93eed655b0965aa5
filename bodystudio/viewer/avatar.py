"""Rigged avatars for viewing: a skinned glTF (.glb) read into mesh, skeleton and per-vertex bone weights.

Reads the glTF 2.0 skin of the first skinned mesh: ``JOINTS_0``/``WEIGHTS_0`` give the weights,
the joint nodes' rest transforms (the inverse of ``inverseBindMatrices``, or the node hierarchy when
absent) give the bone heads; a bone's tail is its first child's head (leaf bones extend their parent's
direction by half its length).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from bodystudio.errors import FileFormatError
from bodystudio.geometry.mesh import Mesh

_COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
                     5126: np.float32}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


@dataclass(frozen=True, eq=False)
class Avatar:
    """A skinned mesh in its rest pose: vertices (n, 3), faces, bone names, heads/tails (B, 3), weights (n, B)."""

    mesh: Mesh
    bone_names: tuple[str, ...]
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    weights: np.ndarray

    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    @cached_property
    def dominant_bone(self) -> np.ndarray:
        return np.argmax(self.weights, axis=1)


def avatar_from_body(body) -> Avatar:
    """An :class:`Avatar` from a :class:`bodystudio.body.BodyModel` (rest pose)."""
    sk = body.skeleton
    return Avatar(Mesh(body.vertices, body.faces), tuple(sk.bone_names), np.asarray(sk.parents), sk.heads, sk.tails,
                  np.asarray(body.weights))


def as_avatar(obj) -> Avatar:
    """A viewer :class:`Avatar` from a BodyModel, the rig stage's avatar, or an Avatar (duck-typed).

    Bone tails come from ``skeleton.tails``, else from ``bind_rotations`` (y runs head -> tail) and
    ``bone_lengths``, else from the children's heads.
    """
    if isinstance(obj, Avatar):
        return obj
    if hasattr(obj, "skeleton") and hasattr(obj, "weights"):
        return avatar_from_body(obj)
    heads = np.asarray(obj.heads, dtype=np.float64)
    parents = np.asarray(obj.parents)
    if getattr(obj, "bind_rotations", None) is not None and getattr(obj, "bone_lengths", None) is not None:
        tails = heads + np.asarray(obj.bind_rotations)[:, :, 1] * np.asarray(obj.bone_lengths)[:, None]
    else:
        tails = _tails_from_children(heads, parents)
    return Avatar(obj.mesh, tuple(obj.bone_names), parents, heads, tails, np.asarray(obj.weights))


def _tails_from_children(heads: np.ndarray, parents: np.ndarray) -> np.ndarray:
    tails = heads.copy()
    for k in range(len(heads)):
        children = np.flatnonzero(parents == k)
        if len(children):
            tails[k] = heads[children[0]]
        elif parents[k] >= 0:
            tails[k] = heads[k] + 0.5 * (heads[k] - heads[parents[k]])
    return tails


def glb_has_skin(path: str | Path) -> bool:
    """Whether a .glb/.gltf file holds a skinned mesh (False for plain meshes or unreadable files)."""
    try:
        gltf = _load_gltf(Path(path))
    except FileFormatError:
        return False
    return bool(gltf.skins) and any(n.skin is not None and n.mesh is not None for n in gltf.nodes)


def _load_gltf(path: Path):
    import warnings

    import pygltflib

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pygltflib warns, then fails, on files that are not glTF
            gltf = pygltflib.GLTF2().load(str(path))
            if gltf is not None and any(b.uri is not None for b in gltf.buffers):
                gltf.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)  # external .bin files and data URIs
    except Exception as exc:  # pygltflib raises many types for broken files
        raise FileFormatError(f"{path}: cannot read glTF ({type(exc).__name__}: {exc})") from None
    if gltf is None:
        raise FileFormatError(f"{path}: cannot read glTF (empty or not glTF); give a .glb or .gltf file")
    if gltf.buffers and gltf.binary_blob() is None:
        uri = gltf.buffers[0].uri
        raise FileFormatError(f"{path}: cannot read its buffer {uri!r}; keep the .bin file beside the .gltf")
    return gltf


def _accessor(gltf, index: int) -> np.ndarray:
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    data = gltf.binary_blob()
    dtype = np.dtype(_COMPONENT_DTYPES[acc.componentType])
    size = _TYPE_SIZES[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    stride = view.byteStride or dtype.itemsize * size
    if stride == dtype.itemsize * size:
        arr = np.frombuffer(data, dtype=dtype, count=acc.count * size, offset=start).reshape(acc.count, size)
    else:
        rows = [np.frombuffer(data, dtype=dtype, count=size, offset=start + i * stride) for i in range(acc.count)]
        arr = np.stack(rows)
    if acc.normalized and np.issubdtype(dtype, np.integer):
        arr = arr.astype(np.float64) / np.iinfo(dtype).max
    return arr


def _node_matrix(node) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    if node.matrix is not None and len(node.matrix) == 16:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # glTF stores column-major
    M = np.eye(4)
    if node.rotation is not None:
        M[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()  # glTF quaternions are (x, y, z, w)
    if node.scale is not None:
        M[:3, :3] = M[:3, :3] @ np.diag(node.scale)
    if node.translation is not None:
        M[:3, 3] = node.translation
    return M


def _world_matrices(gltf) -> list[np.ndarray]:
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    cache: dict[int, np.ndarray] = {}

    def world(i: int) -> np.ndarray:
        if i not in cache:
            local = _node_matrix(gltf.nodes[i])
            cache[i] = world(parent[i]) @ local if i in parent else local
        return cache[i]

    return [world(i) for i in range(len(gltf.nodes))]


def load_avatar(path: str | Path) -> Avatar:
    """Read a skinned .glb/.gltf; a file without a skin, or whose ``.rig.json`` is from another run, raises a
    one-line FileFormatError."""
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such avatar file")
    gltf = _load_gltf(path)
    skinned = [n for n in gltf.nodes if n.skin is not None and n.mesh is not None]
    if not skinned:
        raise FileFormatError(f"{path}: glTF has no skinned mesh; give an avatar written by 'bodystudio rig'")
    node = skinned[0]
    skin = gltf.skins[node.skin]
    world = _world_matrices(gltf)
    M_node = world[gltf.nodes.index(node)]
    Vs, Fs, Ws = [], [], []
    offset = 0
    B = len(skin.joints)
    for prim in gltf.meshes[node.mesh].primitives:
        attrs = prim.attributes
        if attrs.POSITION is None or attrs.JOINTS_0 is None or attrs.WEIGHTS_0 is None:
            raise FileFormatError(f"{path}: skinned primitive lacks POSITION, JOINTS_0 or WEIGHTS_0")
        V = _accessor(gltf, attrs.POSITION).astype(np.float64)
        if prim.indices is None:
            F = np.arange(len(V)).reshape(-1, 3)
        else:
            F = _accessor(gltf, prim.indices).astype(np.int64).reshape(-1, 3)
        J = _accessor(gltf, attrs.JOINTS_0).astype(np.int64)
        Wt = _accessor(gltf, attrs.WEIGHTS_0).astype(np.float64)
        if J.max(initial=0) >= B:
            raise FileFormatError(f"{path}: JOINTS_0 refers to joint {J.max()} of a {B}-joint skin")
        W = np.zeros((len(V), B))
        np.add.at(W, (np.repeat(np.arange(len(V)), J.shape[1]), J.ravel()), Wt.ravel())
        Vs.append(V @ M_node[:3, :3].T + M_node[:3, 3])
        Fs.append(F + offset)
        Ws.append(W)
        offset += len(V)
    V, F, W = np.vstack(Vs), np.vstack(Fs), np.vstack(Ws)
    W /= np.maximum(W.sum(1, keepdims=True), 1e-12)
    # An avatar from `bodystudio rig` is shown only when its rig.json (if any) belongs to it.
    from bodystudio.rig.export import check_rig_pair

    check_rig_pair(path, len(V))
    if skin.inverseBindMatrices is not None:
        ibm = _accessor(gltf, skin.inverseBindMatrices).astype(np.float64).reshape(-1, 4, 4).transpose(0, 2, 1)
        heads = np.linalg.inv(ibm)[:, :3, 3]
    else:
        heads = np.array([world[j][:3, 3] for j in skin.joints])
    joint_index = {j: k for k, j in enumerate(skin.joints)}
    parents = np.full(B, -1, dtype=np.int64)
    for k, j in enumerate(skin.joints):
        for c in gltf.nodes[j].children or []:
            if c in joint_index:
                parents[joint_index[c]] = k
    tails = _tails_from_children(heads, parents)
    names = tuple(gltf.nodes[j].name or f"joint{k}" for k, j in enumerate(skin.joints))
    return Avatar(Mesh(V, F), names, parents, heads, tails, W)
