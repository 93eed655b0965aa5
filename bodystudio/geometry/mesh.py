"""Triangle meshes: the plain ``Mesh`` type, derived quantities and file I/O (PLY, OBJ, GLB, STL).

Inputs are ``(n, 3)`` float64 vertex arrays and ``(m, 3)`` int face arrays, as in libigl's Python API.
Derived data (normals, areas, edges) are cached properties computed by libigl or numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import igl
import numpy as np

from bodystudio.errors import FileFormatError
from bodystudio.fileio import atomic_path

MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in metres (y-up world frame) with optional per-vertex colours (uint8 RGB)."""

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        V = np.ascontiguousarray(self.vertices, dtype=np.float64)
        F = np.ascontiguousarray(self.faces, dtype=np.int64)
        if V.ndim != 2 or V.shape[1] != 3:
            raise ValueError(f"vertices must be (n, 3), got {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3:
            raise ValueError(f"faces must be (m, 3) triangles, got {F.shape}")
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "faces", F)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @cached_property
    def face_normals(self) -> np.ndarray:
        return face_normals(self.vertices, self.faces)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        return vertex_normals(self.vertices, self.faces)

    @cached_property
    def face_areas(self) -> np.ndarray:
        return 0.5 * igl.doublearea(self.vertices, self.faces)

    @cached_property
    def bounds(self) -> np.ndarray:
        return np.stack([self.vertices.min(0), self.vertices.max(0)])

    def with_vertices(self, vertices: np.ndarray) -> Mesh:
        """Same topology and colours, new vertex positions."""
        return Mesh(vertices, self.faces, self.vertex_colors, dict(self.metadata))


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit face normals (counter-clockwise winding faces outwards)."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], n)
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)


def vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Barycentric vertex areas: a third of each incident triangle's area (libigl's barycentric mass)."""
    M = igl.massmatrix(np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                       igl.MASSMATRIX_TYPE_BARYCENTRIC)
    return np.asarray(M.diagonal()).ravel()


def quads_to_triangles(quads: np.ndarray) -> np.ndarray:
    """Split each quad (a, b, c, d) into triangles (a, b, c) and (a, c, d)."""
    quads = np.asarray(quads)
    tris = np.empty((2 * len(quads), 3), dtype=quads.dtype)
    tris[0::2] = quads[:, [0, 1, 2]]
    tris[1::2] = quads[:, [0, 2, 3]]
    return tris


def checked_mesh_arrays(path: str | Path, vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(n, 3)`` finite and faces ``(m, 3)`` indexing them, as read from ``path``; a broken file
    (2D vertices, NaN, a face index out of range) raises a one-line FileFormatError naming it."""
    V = np.asarray(vertices)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3 or not np.issubdtype(V.dtype, np.number):
        raise FileFormatError(f"{path}: vertices must have 3 coordinates each, got shape {V.shape}; fix the file")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise FileFormatError(f"{path}: faces must be triangles of vertex indices, got shape {F.shape}; fix the file")
    V = V.astype(np.float64)
    if not np.all(np.isfinite(V)):
        raise FileFormatError(f"{path}: {int((~np.isfinite(V)).any(1).sum())} vertices are NaN or infinite")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise FileFormatError(f"{path}: face indices span [{F.min()}, {F.max()}] but the file has {len(V)} "
                              "vertices; the face list is corrupt")
    return V, F.astype(np.int64)


def load_mesh(path: str | Path) -> Mesh:
    """Read a triangle mesh from PLY, OBJ, GLB/GLTF, STL or OFF (scenes are concatenated)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise FileFormatError(f"{path}: unsupported mesh format; use one of {', '.join(MESH_SUFFIXES)}")
    try:
        loaded = trimesh.load(path, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types for broken files
        raise FileFormatError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FileFormatError(f"{path}: contains no triangles (a point cloud or empty file?); give a triangle mesh")
    colors = None
    visual = getattr(loaded, "visual", None)
    if visual is not None and getattr(visual, "kind", None) == "vertex":
        colors = np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8)
    V, F = checked_mesh_arrays(path, loaded.vertices, loaded.faces)
    return Mesh(V, F, colors)


def save_mesh(path: str | Path, mesh: Mesh) -> None:
    """Write a mesh atomically; the format follows the suffix (.ply, .obj, .glb, .stl, .off)."""
    import trimesh

    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise FileFormatError(f"{path}: unsupported mesh format; use one of {', '.join(MESH_SUFFIXES)}")
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=mesh.vertex_colors, process=False)
    with atomic_path(path) as tmp:
        tm.export(tmp, file_type=path.suffix.lower().lstrip("."))
