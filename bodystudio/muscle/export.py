"""Arm sequences out of bodystudio: one glTF binary with morph-target animation, and a PLY sequence (issue 11, §3.6).

The paper's output (§3 of Arm-Muscle Capture) is a mesh per frame in one topology. A glTF viewer plays
such a sequence as *morph targets*: the base mesh is the first frame, target ``k`` holds frame ``k``'s
displacement from it, and one animation channel drives the mesh's morph weights with the one-hot
vector of frame ``k`` at time ``k / fps``. LINEAR interpolation between two keys blends frames ``k``
and ``k+1`` (weights sum to one), which is what Blender's importer (shape keys + an action) and
three.js's ``AnimationMixer`` play. Target names (``frame_00000`` ...) go in ``mesh.extras.targetNames``,
where both read them.

Sizes: each target stores float32 positions and normals, 24 bytes per vertex and frame (200 frames of
a 1.5K-vertex arm: 7 MB) plus the weights track, ``T^2`` floats (200 frames: 160 KB).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import atomic_write, check_output_file
from bodystudio.geometry.mesh import Mesh, save_mesh, vertex_normals

DEFAULT_FPS = 30.0
#: a limit that keeps the weights track (T^2 floats) under 16 MB; split longer sequences
MAX_FRAMES = 2000


@dataclass(frozen=True)
class MorphSequence:
    """A morph-target animation read back from a .glb: base mesh, per-frame targets and the weights track."""

    base: np.ndarray  # (n, 3) base positions (frame 0)
    faces: np.ndarray  # (m, 3)
    targets: np.ndarray  # (T, n, 3) position displacement of each target from the base
    times: np.ndarray  # (K,) key times of the weights track, s
    weights: np.ndarray  # (K, T) morph weights at each key
    target_names: tuple[str, ...]

    def frame_vertices(self, key: int) -> np.ndarray:
        """Positions a player shows at key ``key``: base + sum of weighted targets."""
        return self.base + np.tensordot(self.weights[key], self.targets, axes=1)


def _validate_sequence(frames: np.ndarray, faces: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    frames = np.asarray(frames, dtype=np.float64)
    faces = np.asarray(faces)
    if frames.ndim != 3 or frames.shape[2] != 3 or len(frames) < 1:
        raise InputError(f"an arm sequence is (frames, vertices, 3) positions; got shape {frames.shape}")
    if len(frames) > MAX_FRAMES:
        raise InputError(f"{len(frames)} frames: a morph-target .glb holds at most {MAX_FRAMES}; split the sequence")
    if not np.isfinite(frames).all():
        raise InputError("the arm sequence has non-finite vertex positions; refusing to export it")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.size == 0:
        raise InputError(f"faces must be (m, 3) triangles; got shape {faces.shape}")
    if faces.min() < 0 or faces.max() >= frames.shape[1]:
        raise InputError(f"faces index vertices 0..{faces.max()} but the sequence has {frames.shape[1]} vertices")
    if not (np.isfinite(fps) and 0 < fps <= 1000):
        raise InputError(f"fps {fps}: must be in (0, 1000]")
    return frames, faces.astype(np.int64)


def one_hot_weights_track(n_frames: int, fps: float = DEFAULT_FPS,
                          positions: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Key times ``k / fps`` and the one-hot weights of frame ``k`` at key ``k``: ``((T,), (T, T))``. ``positions``:
    each frame's number in the recording when frames were skipped (rel7a): its key at ``position / fps``, so the
    animation keeps the recording's timing (a player blends the two frames around a gap)."""
    k = np.arange(n_frames) if positions is None else np.asarray(positions)
    return k.astype(np.float32) / np.float32(fps), np.eye(n_frames, dtype=np.float32)


def write_morph_glb(path: str | Path, frames: np.ndarray, faces: np.ndarray, fps: float = DEFAULT_FPS,
                    colors: np.ndarray | None = None, name: str = "arm", normals: bool = True,
                    positions: list[int] | None = None) -> None:
    """Write a sequence of meshes in one topology as a glTF 2.0 binary with morph-target animation (atomically).

    ``frames`` (T, n, 3) metres, y-up (glTF's frame); ``faces`` (m, 3); ``colors`` optional (n, 3) uint8
    vertex colours of the base mesh. ``normals`` adds per-target normal displacements (correct shading
    of the bulges in players that use them; doubles the size). ``positions``: each frame's number in the recording
    (increasing) when frames were skipped: its key time and target name (:func:`one_hot_weights_track`).
    """
    import pygltflib as g

    frames, faces = _validate_sequence(frames, faces, fps)
    T, n = frames.shape[:2]
    base = frames[0]
    blob = bytearray()
    views, accessors = [], []

    def add(data: np.ndarray, component: int, kind: str, target: int | None, minmax: bool = False,
            normalized: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        raw = np.ascontiguousarray(data).tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(raw), target=target))
        blob.extend(raw)
        acc = g.Accessor(bufferView=len(views) - 1, componentType=component, count=len(data), type=kind,
                         normalized=normalized or None)
        if minmax:  # required by glTF for POSITION (also of morph targets) and animation inputs
            m = data.reshape(len(data), -1)
            acc.min = m.min(0).astype(float).tolist()
            acc.max = m.max(0).astype(float).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    base32 = base.astype(np.float32)
    n_base = vertex_normals(base, faces)
    attrs = g.Attributes(POSITION=add(base32, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True))
    if normals:
        attrs.NORMAL = add(n_base.astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER)
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3):
            raise InputError(f"colors must be ({n}, 3) uint8; got shape {colors.shape}")
        attrs.COLOR_0 = add(np.c_[colors, np.full(n, 255)].astype(np.uint8), g.UNSIGNED_BYTE, g.VEC4,
                            g.ARRAY_BUFFER, normalized=True)
    targets = []
    for k in range(T):
        # float32 displacement of the float64 frame from the float32 base: the player's sum is exact to 1e-7 m
        target = {"POSITION": add((frames[k] - base32).astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER,
                                  minmax=True)}
        if normals:
            target["NORMAL"] = add((vertex_normals(frames[k], faces) - n_base).astype(np.float32), g.FLOAT,
                                   g.VEC3, g.ARRAY_BUFFER)
        targets.append(target)
    indices = add(faces.astype(np.uint32).ravel(), g.UNSIGNED_INT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER)
    numbers = _frame_positions(positions, T)
    times, weights = one_hot_weights_track(T, fps, numbers)
    t_acc = add(times, g.FLOAT, g.SCALAR, None, minmax=True)
    w_acc = add(weights.ravel(), g.FLOAT, g.SCALAR, None)
    names = [f"frame_{k:05d}" for k in numbers]
    prim = g.Primitive(attributes=attrs, indices=indices, material=0, targets=targets)
    gltf = g.GLTF2(
        asset=g.Asset(version="2.0", generator="bodystudio muscle"),
        scene=0, scenes=[g.Scene(nodes=[0])], nodes=[g.Node(name=name, mesh=0)],
        meshes=[g.Mesh(name=name, primitives=[prim], weights=weights[0].astype(float).tolist(),
                       extras={"targetNames": names})],
        materials=[g.Material(name="skin", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[0.85, 0.68, 0.58, 1.0], metallicFactor=0.0, roughnessFactor=0.8),
            doubleSided=True)],
        animations=[g.Animation(name=f"{name}_sequence", samplers=[
            g.AnimationSampler(input=t_acc, output=w_acc, interpolation=g.ANIM_LINEAR)],
            channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))])],
        accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))])
    gltf.set_binary_blob(bytes(blob))
    data = b"".join(gltf.save_to_bytes())
    with atomic_write(path, "wb") as f:
        f.write(data)


def _accessor_array(gltf, index: int) -> np.ndarray:
    import pygltflib as g

    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = {g.FLOAT: np.float32, g.UNSIGNED_INT: np.uint32, g.UNSIGNED_SHORT: np.uint16,
             g.UNSIGNED_BYTE: np.uint8}[acc.componentType]
    width = {g.SCALAR: 1, g.VEC2: 2, g.VEC3: 3, g.VEC4: 4, g.MAT4: 16}[acc.type]
    blob = gltf.binary_blob()
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    a = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=start)
    return a.reshape(acc.count, width) if width > 1 else a


def read_morph_glb(path: str | Path) -> MorphSequence:
    """Read a .glb written by :func:`write_morph_glb` back (pygltflib): base, targets, weights track."""
    import warnings

    import pygltflib as g

    path = Path(path)
    try:
        with warnings.catch_warnings():  # pygltflib warns (then fails) on a wrong binary version
            warnings.simplefilter("ignore")
            gltf = g.GLTF2().load_binary(str(path))
        prim = gltf.meshes[0].primitives[0]
        base = _accessor_array(gltf, prim.attributes.POSITION).astype(np.float64)
        faces = _accessor_array(gltf, prim.indices).reshape(-1, 3).astype(np.int64)
        targets = np.stack([_accessor_array(gltf, t["POSITION"]) for t in prim.targets]).astype(np.float64)
        sampler = gltf.animations[0].samplers[0]
        times = _accessor_array(gltf, sampler.input).astype(np.float64)
        weights = _accessor_array(gltf, sampler.output).astype(np.float64).reshape(len(times), len(targets))
        names = tuple((gltf.meshes[0].extras or {}).get("targetNames", ()))
    except FileNotFoundError:
        raise FileFormatError(f"{path}: not found") from None
    except Exception as exc:  # pygltflib raises assorted errors on junk
        raise FileFormatError(f"{path}: not a morph-target arm sequence .glb ({type(exc).__name__}: {exc}); "
                              "re-export it with bodystudio muscle capture") from None
    return MorphSequence(base, faces, targets, times, weights, names)


def _frame_positions(positions, n_frames: int) -> list[int]:
    if positions is None:
        return list(range(n_frames))
    out = [int(p) for p in positions]
    if len(out) != n_frames or any(b <= a for a, b in zip(out, out[1:], strict=False)) or (out and out[0] < 0):
        raise InputError(f"frame positions {out[:5]}...: one increasing number >= 0 per frame ({n_frames})")
    return out


def write_ply_sequence(folder: str | Path, frames: np.ndarray, faces: np.ndarray,
                       positions: list[int] | None = None) -> list[Path]:
    """Write frame ``k`` as ``folder/NNNNN.ply`` (one topology, atomically per file); returns the paths.
    ``positions``: each frame's number in the recording when frames were skipped (rel7a): the file of a skipped frame
    is absent, so a mesh is never taken for its neighbour's frame.

    Whole-sequence atomicity is the caller's: write into a staging folder and rename it.
    """
    frames, faces = _validate_sequence(frames, faces, DEFAULT_FPS)
    folder = Path(folder)
    paths = []
    for k, V in zip(_frame_positions(positions, len(frames)), frames, strict=True):
        p = folder / f"{k:05d}.ply"
        save_mesh(p, Mesh(V, faces))
        paths.append(p)
    return paths


def check_new_output(path: str | Path, what: str = "output") -> Path:
    """Refuse (InputError, one line) an output path that exists or cannot be written (:func:`check_output_file`).

    Called before any work starts, so a bad ``--out`` costs nothing and leaves nothing behind.
    """
    path = Path(path)
    if path.exists() or path.is_symlink():
        raise InputError(f"{path}: {what} already exists; choose a new path or remove it")
    return check_output_file(path, what)


def _remove_dead_staging(out: Path) -> None:
    """Remove the staging folders beside ``out`` of processes that no longer run (a SIGKILLed capture's
    ``.NAME.staging-PID`` stayed for ever, rel6b); a running writer's is left alone."""
    import glob

    from bodystudio.runfolder import process_alive

    for old in out.parent.glob(f".{glob.escape(out.name)}.staging-*"):
        pid = old.name.rpartition("-")[2]
        if pid.isascii() and pid.isdigit() and int(pid) != os.getpid() and not process_alive(int(pid)):
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged_output_folder(out: str | Path, what: str = "output folder") -> Iterator[Path]:
    """Yield an empty staging folder beside ``out``; on success rename it to ``out`` (the commit point).

    The whole output appears at once or not at all: an exception removes the staging folder, and a
    process killed before the rename leaves only a hidden ``.NAME.staging-PID`` folder, never a
    half-written ``out`` that a reader could take for a result.
    """
    out = check_new_output(out, what)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_dead_staging(out)
    staging = out.parent / f".{out.name}.staging-{os.getpid()}"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    try:
        yield staging
        try:
            os.rename(staging, out)
        except OSError as exc:
            raise InputError(f"{out}: could not commit the output ({exc.strerror}); another writer may have "
                             "created it meanwhile") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
