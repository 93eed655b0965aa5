"""Avatar export (issue 6 §8): glTF 2.0 binary with a skin, a BVH pose sequence, a JSON rig description.

glTF: one node per bone (local TRS from the bind frames; the root bone a scene root), inverse bind
matrices ``inv([R_bind_j | h_j])``, a skinned mesh with JOINTS_0/WEIGHTS_0 (4 influences) and either
vertex colours (COLOR_0) or, with ``texture=True``, an xatlas UV atlas with the colours baked into a PNG.
"""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.errors import FileFormatError
from bodystudio.fileio import atomic_write, read_json, write_json
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.rig.avatar import Avatar
from bodystudio.runfolder import RunLayout, RunWriter, check_readable, verify_run_files

log = logging.getLogger(__name__)

TEXTURE_SIZE = 1024


def _local_bind_transforms(avatar: Avatar) -> tuple[np.ndarray, np.ndarray]:
    """Per-bone local translation (in the parent's bind frame) and local bind rotation."""
    h, R = avatar.heads, avatar.bind_rotations
    t = np.empty_like(h)
    rot = np.empty_like(R)
    for j, p in enumerate(avatar.parents):
        if p < 0:
            t[j], rot[j] = h[j], R[j]
        else:
            t[j] = R[p].T @ (h[j] - h[p])
            rot[j] = R[p].T @ R[j]
    return t, rot


def skin_arrays(weights: np.ndarray, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """JOINTS_0 (uint16) and WEIGHTS_0 (float32, rows summing to 1 in float32) from dense weights; always ``k``
    columns (a rig of fewer bones gets zero-weight slots: the accessors are declared VEC4)."""
    if weights.shape[1] < k:
        weights = np.pad(weights, ((0, 0), (0, k - weights.shape[1])))
    idx = np.argsort(-weights, axis=1)[:, :k]
    w = np.take_along_axis(weights, idx, axis=1).astype(np.float32)
    w[w < 1e-6] = 0.0
    w /= w.sum(1, keepdims=True)
    w[:, 0] += np.float32(1.0) - w.sum(1, dtype=np.float32)  # float32 sums exactly 1 within rounding
    idx = idx.astype(np.uint16)
    # Unused slots: weight 0 and joint 0 (the glTF convention).
    idx[w == 0] = 0
    return idx, w


def bake_vertex_colors(uv: np.ndarray, faces: np.ndarray, colors: np.ndarray, size: int = TEXTURE_SIZE) -> np.ndarray:
    """Rasterise per-vertex colours into a ``(size, size, 3)`` texture over a UV layout, with seam padding."""
    from numba import njit

    @njit(cache=True)
    def _raster(px, faces, col, img, mask):
        n = img.shape[0]
        for f in range(faces.shape[0]):
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            x0, y0, x1, y1, x2, y2 = px[a, 0], px[a, 1], px[b, 0], px[b, 1], px[c, 0], px[c, 1]
            det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
            if abs(det) < 1e-12:
                continue
            lo_x = max(int(np.floor(min(x0, x1, x2))), 0)
            hi_x = min(int(np.ceil(max(x0, x1, x2))), n - 1)
            lo_y = max(int(np.floor(min(y0, y1, y2))), 0)
            hi_y = min(int(np.ceil(max(y0, y1, y2))), n - 1)
            for yy in range(lo_y, hi_y + 1):
                for xx in range(lo_x, hi_x + 1):
                    X, Y = xx + 0.5, yy + 0.5
                    l0 = ((y1 - y2) * (X - x2) + (x2 - x1) * (Y - y2)) / det
                    l1 = ((y2 - y0) * (X - x2) + (x0 - x2) * (Y - y2)) / det
                    l2 = 1.0 - l0 - l1
                    if l0 >= -0.02 and l1 >= -0.02 and l2 >= -0.02:
                        for k in range(3):
                            img[yy, xx, k] = l0 * col[a, k] + l1 * col[b, k] + l2 * col[c, k]
                        mask[yy, xx] = True

    px = np.c_[uv[:, 0] * size, (1.0 - uv[:, 1]) * size]
    img = np.zeros((size, size, 3))
    mask = np.zeros((size, size), np.bool_)
    _raster(px, faces.astype(np.int64), colors.astype(np.float64), img, mask)
    for _ in range(4):  # dilate charts so bilinear filtering at seams reads chart colours
        grown = mask.copy()
        acc = np.zeros_like(img)
        cnt = np.zeros((size, size))
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            m = np.roll(mask, (dy, dx), axis=(0, 1))
            acc += np.roll(img, (dy, dx), axis=(0, 1)) * m[..., None]
            cnt += m
        new = ~mask & (cnt > 0)
        img[new] = acc[new] / cnt[new, None]
        grown |= new
        mask = grown
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def uv_atlas(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xatlas UV atlas: ``(vertex map into the input, new faces, uv (k, 2) in [0, 1])``."""
    import xatlas

    vmapping, indices, uvs = xatlas.parametrize(vertices.astype(np.float32), faces.astype(np.uint32))
    return vmapping.astype(np.int64), indices.astype(np.int64), uvs.astype(np.float64)


def write_glb(path: str | Path, avatar: Avatar, texture: bool = False) -> np.ndarray | None:
    """Write the avatar as a skinned glTF 2.0 binary (atomically); returns :func:`glb_bytes`' vertex map."""
    data, vertex_source = glb_bytes(avatar, texture)
    with atomic_write(path, "wb") as f:
        f.write(data)
    return vertex_source


def glb_bytes(avatar: Avatar, texture: bool = False) -> tuple[bytes, np.ndarray | None]:
    """The avatar as a skinned glTF 2.0 binary, and for each glb vertex its avatar vertex (None: the same).

    The UV atlas of ``texture=True`` splits vertices along the seams; the map lets readers (and
    :func:`rig_description`) describe the exported vertices and score the rig on the avatar's own.
    """
    import pygltflib as g

    V, F = avatar.vertices, avatar.faces
    N = vertex_normals(V, F)
    joints, weights = skin_arrays(avatar.weights)
    colors = avatar.vertex_colors
    uv = image_png = vmap = None
    if texture and colors is not None:
        vmap, F, uv = uv_atlas(V, F)
        image = bake_vertex_colors(uv, F, colors[vmap])
        V, N, joints, weights = V[vmap], N[vmap], joints[vmap], weights[vmap]
        colors = None
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(image).save(buf, format="PNG")
        image_png = buf.getvalue()
    blob = bytearray()
    views, accessors = [], []

    def add(data: np.ndarray, component: int, kind: str, target: int | None, normalized: bool = False,
            minmax: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        raw = np.ascontiguousarray(data).tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw), target=target))
        blob.extend(raw)
        count = len(data)
        acc = g.Accessor(bufferView=len(views) - 1, componentType=component, count=count, type=kind,
                         normalized=normalized or None)
        if minmax:
            acc.min = data.min(0).astype(float).tolist()
            acc.max = data.max(0).astype(float).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    attrs = g.Attributes(POSITION=add(V.astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True),
                         NORMAL=add(N.astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER),
                         JOINTS_0=add(joints, g.UNSIGNED_SHORT, g.VEC4, g.ARRAY_BUFFER),
                         WEIGHTS_0=add(weights, g.FLOAT, g.VEC4, g.ARRAY_BUFFER))
    if colors is not None:
        attrs.COLOR_0 = add(np.c_[colors, np.full(len(colors), 255)].astype(np.uint8), g.UNSIGNED_BYTE, g.VEC4,
                            g.ARRAY_BUFFER, normalized=True)
    if uv is not None:
        attrs.TEXCOORD_0 = add(np.c_[uv[:, 0], 1.0 - uv[:, 1]].astype(np.float32), g.FLOAT, g.VEC2, g.ARRAY_BUFFER)
    indices = add(F.astype(np.uint32).ravel(), g.UNSIGNED_INT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER)
    ibm = np.linalg.inv(avatar.bind_frames)
    ibm_acc = add(np.transpose(ibm, (0, 2, 1)).reshape(-1, 16).astype(np.float32), g.FLOAT, g.MAT4, None)
    materials, textures, images, samplers = [], [], [], []
    if image_png is not None:
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(image_png)))
        blob.extend(image_png)
        images.append(g.Image(bufferView=len(views) - 1, mimeType="image/png"))
        samplers.append(g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR))
        textures.append(g.Texture(source=0, sampler=0))
        materials.append(g.Material(name="scan", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorTexture=g.TextureInfo(index=0), metallicFactor=0.0, roughnessFactor=0.9)))
    else:
        materials.append(g.Material(name="scan", pbrMetallicRoughness=g.PbrMetallicRoughness(
            metallicFactor=0.0, roughnessFactor=0.9)))
    prim = g.Primitive(attributes=attrs, indices=indices, material=0)
    t, rot = _local_bind_transforms(avatar)
    B = avatar.n_bones
    nodes = []
    for j in range(B):
        q = Rotation.from_matrix(rot[j]).as_quat()  # x, y, z, w as glTF
        children = [int(c) for c in np.flatnonzero(avatar.parents == j)]
        nodes.append(g.Node(name=avatar.bone_names[j], translation=t[j].tolist(), rotation=q.tolist(),
                            children=children or None))
    nodes.append(g.Node(name="avatar", mesh=0, skin=0))
    roots = [int(j) for j in np.flatnonzero(avatar.parents < 0)]
    gltf = g.GLTF2(
        asset=g.Asset(version="2.0", generator="bodystudio rig"),
        scene=0, scenes=[g.Scene(nodes=roots + [B])], nodes=nodes,
        meshes=[g.Mesh(name="scan", primitives=[prim])],
        skins=[g.Skin(name="rig", joints=list(range(B)), inverseBindMatrices=ibm_acc, skeleton=roots[0])],
        accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))],
        materials=materials, textures=textures or [], images=images or [], samplers=samplers or [])
    gltf.set_binary_blob(bytes(blob))
    return b"".join(gltf.save_to_bytes()), vmap


def write_bvh(path: str | Path, avatar: Avatar, poses: list[Pose], fps: float = 30.0) -> None:
    """BVH motion of ``poses`` on the avatar's skeleton (offsets from the bind heads, ZXY Euler degrees).

    BVH joints have identity rest orientation, so each frame's rotation of joint ``j`` is its world
    rotation change from the bind pose relative to its parent's: ``D_p^T D_j`` with ``D = G R_bind^T``.
    """
    h = avatar.heads
    children = [np.flatnonzero(avatar.parents == j) for j in range(avatar.n_bones)]
    order: list[int] = []
    lines = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        p = avatar.parents[j]
        off = h[j] if p < 0 else h[j] - h[p]
        kind = "ROOT" if p < 0 else "JOINT"
        lines.append(f"{pad}{kind} {avatar.bone_names[j]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        chans = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if p < 0 else \
            "3 Zrotation Xrotation Yrotation"
        lines.append(f"{pad}  CHANNELS {chans}")
        order.append(j)
        for c in children[j]:
            emit(int(c), depth + 1)
        if len(children[j]) == 0:
            tail = avatar.bind_rotations[j][:, 1] * avatar.bone_lengths[j]
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET {tail[0]:.6f} {tail[1]:.6f} {tail[2]:.6f}")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    for r in np.flatnonzero(avatar.parents < 0):
        emit(int(r), 0)
    lines += ["MOTION", f"Frames: {len(poses)}", f"Frame Time: {1.0 / fps:.6f}"]
    for pose in poses:
        D = avatar.global_rotations(pose) @ np.transpose(avatar.bind_rotations, (0, 2, 1))
        vals = []
        for j in order:
            p = avatar.parents[j]
            local = D[j] if p < 0 else D[p].T @ D[j]
            if p < 0:
                vals += list(h[j] + pose.translation - avatar.bind_translation)
            vals += list(Rotation.from_matrix(local).as_euler("ZXY", degrees=True))
        lines.append(" ".join(f"{v:.5f}" for v in vals))
    with atomic_write(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def rig_description(avatar: Avatar, vertex_source: np.ndarray | None = None) -> dict:
    """JSON-ready rig description: bones, parents, bind heads and frames, rest frames, lengths, provenance.

    ``n_vertices`` is the exported glb's vertex count; with a UV atlas (``vertex_source`` from
    :func:`glb_bytes`) the description also lists each glb vertex's avatar vertex.
    """
    out = {"format": "bodystudio-rig", "version": 1, "bones": list(avatar.bone_names),
           "parents": avatar.parents.tolist(), "bind_heads_m": avatar.heads.tolist(),
           "bind_rotations": avatar.bind_rotations.tolist(), "rest_rotations": avatar.rest_rotations.tolist(),
           "bone_lengths_m": avatar.bone_lengths.tolist(), "bind_translation_m": avatar.bind_translation.tolist(),
           "n_vertices": int(len(avatar.vertices)), "max_influences": 4, **avatar.metadata}
    if vertex_source is not None:
        out["n_vertices"] = int(len(vertex_source))
        out["n_avatar_vertices"] = int(len(avatar.vertices))
        out["vertex_source"] = np.asarray(vertex_source, dtype=np.int64).tolist()
    return out


def write_rig_json(path: str | Path, avatar: Avatar) -> None:
    write_json(path, rig_description(avatar))


# ---------------------------------------------------------------------------------------------- whole rig

def rig_json_path(glb: str | Path) -> Path:
    return Path(glb).with_suffix(".rig.json")


def rig_layout(glb: str | Path) -> RunLayout:
    """Lock ``.A.glb.lock``, staging ``.A.glb.staging`` and manifest ``A.rig.json`` of the avatar ``A.glb``."""
    glb = Path(glb)
    return RunLayout(glb.parent, rig_json_path(glb).name, f".{glb.name}.", str(glb))


def write_rig(writer: RunWriter, glb: str | Path, avatar: Avatar, texture: bool = False,
              bvh: str | Path | None = None, poses: list[Pose] | None = None) -> dict:
    """Stage ``A.glb`` (and a BVH of ``poses``) in ``writer`` (a :class:`RunWriter` on :func:`rig_layout`)
    and commit them with ``A.rig.json`` last, which records their sha256 and the run id."""
    glb = Path(glb)
    data, vertex_source = glb_bytes(avatar, texture)
    writer.write_bytes(glb.name, data)
    if bvh is not None:
        write_bvh(writer.path_for(Path(bvh).absolute()), avatar, poses or [])
    return writer.commit(rig_description(avatar, vertex_source))


def check_rig_pair(glb: str | Path, n_glb_vertices: int | None = None) -> dict | None:
    """The ``A.rig.json`` of ``A.glb`` when the two belong together (None without a rig.json).

    Refused with one line: a ``bodystudio rig`` writing them now, an interrupted commit (run ``bodystudio
    recover A.glb``), or a pair from different runs (sha256 of the glb differs from the one rig.json
    records; for rig.json files without checksums, a vertex count that differs from the glb's).
    """
    glb = Path(glb)
    layout = rig_layout(glb)
    check_readable(layout)
    path = layout.manifest_path
    if not path.is_file():
        return None
    meta = read_json(path, "rig description")
    if not isinstance(meta, dict) or "bones" not in meta:
        raise FileFormatError(f"{path}: not a bodystudio rig description; re-run `bodystudio rig`")
    if "run" in meta:
        verify_run_files(layout, meta["run"], only=(glb.name,))
        if glb.name not in meta["run"].get("files", {}):
            raise FileFormatError(f"{path}: describes another avatar than {glb.name}; re-run `bodystudio rig`")
    elif n_glb_vertices is not None and meta.get("n_vertices") not in (None, n_glb_vertices):
        raise FileFormatError(f"{path}: describes {meta['n_vertices']} vertices but {glb} has {n_glb_vertices}; "
                              "the two are from different runs, re-run `bodystudio rig`")
    return meta
