"""MakeHuman hm08 base mesh and morph targets, read with numpy from the CC0 assets.

The base mesh (``3dobjs/base.obj``) holds the body surface (group ``body``, the first 13 380 vertices)
followed by helper geometry: clothes helpers, eyes, teeth and the ``joint-*`` cubes whose centres
define the skeleton. Targets move all 19 158 vertices, so the joint cubes follow every shape change.
Coordinates are converted from MakeHuman decimetres to metres; the axes already match ours (y up,
the body faces +z).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from bodystudio.body.assets import DM_TO_M, compiled_targets_path, makehuman_data_dir
from bodystudio.errors import AssetError


@dataclass(frozen=True, eq=False)
class MakeHumanBase:
    """The hm08 base mesh with its helper geometry, in metres."""

    vertices: np.ndarray  # (19158, 3) every vertex, helpers included
    body_quads: np.ndarray  # (13378, 4) faces of the body group
    n_body: int  # body vertices are 0 .. n_body-1
    groups: dict  # group name -> vertex indices (joint cubes, helpers)
    mirror: np.ndarray  # (n,) index of each vertex's left/right mirror partner
    data_dir: Path

    @cached_property
    def joint_cubes(self) -> dict[str, np.ndarray]:
        return {k: v for k, v in self.groups.items() if k.startswith("joint-")}


def _parse_obj(path: Path, texcoords: bool = False):
    """Vertices and ``(group, vertex ids)`` faces of an OBJ; with ``texcoords`` also the ``vt`` table and
    each face's texture-coordinate ids (``(group, vertex ids, vt ids)`` faces)."""
    verts: list[list[float]] = []
    uvs: list[list[float]] = []
    faces: list[tuple] = []
    group = ""
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                if line.startswith("v "):
                    verts.append([float(x) for x in line.split()[1:4]])
                elif line.startswith("vt ") and texcoords:
                    uvs.append([float(x) for x in line.split()[1:3]])
                elif line.startswith("g "):
                    group = line.split(maxsplit=1)[1].strip()
                elif line.startswith("f "):
                    corners = line.split()[1:]
                    ids = [int(t.split("/")[0]) - 1 for t in corners]
                    if texcoords:
                        faces.append((group, ids, [int(t.split("/")[1]) - 1 for t in corners]))
                    else:
                        faces.append((group, ids))
    except (OSError, ValueError, IndexError) as exc:
        raise AssetError(f"{path}: cannot parse the MakeHuman base mesh ({exc}); delete the asset cache and rerun "
                         "'make setup'") from None
    if texcoords:
        return np.array(verts, dtype=np.float64), faces, np.array(uvs, dtype=np.float64).reshape(-1, 2)
    return np.array(verts, dtype=np.float64), faces


@lru_cache(maxsize=2)
def load_base(data_dir: Path | None = None) -> MakeHumanBase:
    """Read ``3dobjs/base.obj`` and ``mesh_metadata/hm08.mirror`` from the MakeHuman data folder."""
    data_dir = Path(data_dir) if data_dir is not None else makehuman_data_dir()
    V, faces = _parse_obj(data_dir / "3dobjs" / "base.obj")
    body = np.array([f for g, f in faces if g == "body"], dtype=np.int64)
    if body.size == 0 or body.shape[1] != 4:
        raise AssetError(f"{data_dir / '3dobjs/base.obj'}: no quad 'body' group; "
                         "this is not MakeHuman's hm08 base mesh")
    n_body = int(body.max()) + 1
    group_faces: dict[str, list[int]] = {}
    for g, f in faces:
        group_faces.setdefault(g, []).extend(f)
    groups = {g: np.unique(np.array(ix, dtype=np.int64)) for g, ix in group_faces.items()}
    mirror = np.arange(len(V))
    mirror_file = data_dir / "mesh_metadata" / "hm08.mirror"
    if mirror_file.is_file():
        pairs = np.loadtxt(mirror_file, usecols=(0, 1), dtype=np.int64)
        mirror[pairs[:, 0]] = pairs[:, 1]
    return MakeHumanBase(V * DM_TO_M, body, n_body, groups, mirror, data_dir)


@lru_cache(maxsize=8)
def load_group_faces(group: str, data_dir: Path | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quads of one base-mesh group with MakeHuman's texture coordinates.

    Returns ``(quads (k, 4) base-vertex ids, uv_quads (k, 4) ids into texcoords, texcoords (t, 2))``;
    ``helper-tights`` and ``helper-skirt`` are the garment proxies that follow every body target.
    """
    data_dir = Path(data_dir) if data_dir is not None else makehuman_data_dir()
    path = data_dir / "3dobjs" / "base.obj"
    _, faces, texcoords = _parse_obj(path, texcoords=True)
    rows = [(f, t) for g, f, t in faces if g == group and len(f) == 4]
    if not rows:
        raise AssetError(f"{path}: no quad group {group!r} in the MakeHuman base mesh")
    quads = np.array([f for f, _ in rows], dtype=np.int64)
    uv_quads = np.array([t for _, t in rows], dtype=np.int64)
    if uv_quads.min() < 0 or uv_quads.max() >= len(texcoords):
        raise AssetError(f"{path}: group {group!r} references texture coordinates the file lacks")
    return quads, uv_quads, texcoords


class TargetLibrary:
    """All MakeHuman morph targets, compiled once into an ``.npz`` (names, sparse vertex deltas)."""

    def __init__(self, path: Path, n_vertices: int):
        with np.load(path) as z:
            self.names = [str(n) for n in z["names"]]
            self._offsets = z["offsets"]
            self._indices = z["indices"]
            self._deltas = z["deltas"]
        self._row = {n: i for i, n in enumerate(self.names)}
        self.n_vertices = n_vertices

    def __contains__(self, name: str) -> bool:
        return name in self._row

    def delta(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(vertex indices, (k, 3) deltas in metres) of one target."""
        i = self._row[name]
        a, b = self._offsets[i], self._offsets[i + 1]
        return self._indices[a:b], self._deltas[a:b].astype(np.float64)

    def matrix(self, names: list[str]) -> sp.csc_matrix:
        """Sparse ``(3 * n_vertices, len(names))`` matrix of flattened deltas, one column per target."""
        rows, cols, vals = [], [], []
        for j, name in enumerate(names):
            idx, d = self.delta(name)
            rows.append((3 * idx[:, None] + np.arange(3)).ravel())
            cols.append(np.full(3 * len(idx), j))
            vals.append(d.ravel())
        if not rows:
            return sp.csc_matrix((3 * self.n_vertices, 0))
        return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * self.n_vertices, len(names)))

    def apply(self, vertices: np.ndarray, weights: dict[str, float]) -> np.ndarray:
        """Base vertices plus the weighted sum of targets (MakeHuman's additive morphing)."""
        out = vertices.copy()
        for name, w in weights.items():
            if w == 0.0:
                continue
            idx, d = self.delta(name)
            out[idx] += w * d
        return out


@lru_cache(maxsize=2)
def load_targets(n_vertices: int) -> TargetLibrary:
    return TargetLibrary(compiled_targets_path(), n_vertices)
