"""The rigged MakeHuman body: shape from phenotype and local targets, skeleton, skin weights, posing.

``build_body(phenotype, local, resolution, rig)`` returns a :class:`BodyModel` in metres, y up, feet on
y = 0. Resolutions: ``full`` (the 13 380-vertex hm08 body), ``6k`` and ``2k`` (about 6 000 and 2 500
vertices). The decimated templates keep a subset of the full body's vertices (quadric edge collapse
without vertex relocation, pymeshlab), so targets, joint definitions and skin weights carry over
exactly by selecting rows.
"""

from __future__ import annotations

import logging
import zipfile
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np
from scipy.spatial import cKDTree

from bodystudio.body.assets import bodystudio_home
from bodystudio.body.makehuman import load_base, load_targets
from bodystudio.body.phenotype import Phenotype, local_target_weights, macro_target_weights
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import RigDefinition, Skeleton, load_rig, load_skin_weights, skeleton_from_vertices
from bodystudio.body.skinning import dual_quaternion_skinning, linear_blend_skinning, posed_joints, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.fileio import atomic_path
from bodystudio.geometry.mesh import Mesh, quads_to_triangles

log = logging.getLogger(__name__)

RESOLUTIONS = {"full": None, "6k": 6000, "2k": 2500}
DEFAULT_RIG = "game_engine"
_DECIMATION_VERSION = 1


@dataclass(frozen=True, eq=False)
class BodyModel:
    """A shaped body in its rest pose with skeleton and skin weights (all arrays in metres)."""

    vertices: np.ndarray  # (n, 3) rest pose
    faces: np.ndarray  # (m, 3)
    skeleton: Skeleton
    weights: np.ndarray  # (n, B), rows sum to 1
    resolution: str = "full"
    rig: str = DEFAULT_RIG
    phenotype: Phenotype = field(default_factory=Phenotype)
    local: dict = field(default_factory=dict)
    vertex_ids: np.ndarray | None = None  # indices into the full body's vertices (None = all)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @cached_property
    def mesh(self) -> Mesh:
        return Mesh(self.vertices, self.faces)

    def pose(self, pose: Pose, method: str = "lbs") -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices ``(n, 3)`` and bone heads ``(B, 3)``; ``method`` is ``lbs`` or ``dqs``."""
        S = skinning_transforms(self.skeleton, pose)
        if method == "lbs":
            V = linear_blend_skinning(self.vertices, self.weights, S)
        elif method == "dqs":
            V = dual_quaternion_skinning(self.vertices, self.weights, S)
        else:
            raise InputError(f"unknown skinning method {method!r}; valid: lbs, dqs")
        heads, _ = posed_joints(self.skeleton, pose)
        return V, heads

    def rest_pose(self) -> Pose:
        return Pose.rest(self.skeleton.n_bones)


def _check_choice(value: str, valid, what: str) -> None:
    if value not in valid:
        raise InputError(f"unknown {what} {value!r}; valid: {', '.join(valid)}")


def shape_weights(phenotype: Phenotype, local: dict[str, float] | None = None) -> dict[str, float]:
    """Target weights (macro and local) of a phenotype, MakeHuman's modifier blend."""
    base = load_base()
    targets = load_targets(len(base.vertices))
    weights = macro_target_weights(phenotype, targets.names)
    for name, w in local_target_weights(local or {}, base.data_dir, targets.names).items():
        weights[name] = weights.get(name, 0.0) + w
    return weights


def shaped_vertices(phenotype: Phenotype | None = None, local: dict[str, float] | None = None) -> np.ndarray:
    """All base-mesh vertices (helpers and joint cubes included) of a shape, feet on y = 0."""
    base = load_base()
    targets = load_targets(len(base.vertices))
    V = targets.apply(base.vertices, shape_weights(phenotype or Phenotype(), local))
    V[:, 1] -= V[: base.n_body, 1].min()
    return V


@lru_cache(maxsize=8)
def _rig(name: str) -> RigDefinition:
    base = load_base()
    return load_rig(name, base.data_dir, len(base.vertices), base.joint_cubes)


@lru_cache(maxsize=8)
def _full_weights(rig: str) -> np.ndarray:
    return load_skin_weights(_rig(rig), load_base().n_body)


def template_topology(resolution: str) -> tuple[np.ndarray | None, np.ndarray]:
    """(vertex ids into the full body or None, triangle faces) of a template resolution."""
    _check_choice(resolution, RESOLUTIONS, "resolution")
    if RESOLUTIONS[resolution] is None:
        return None, quads_to_triangles(load_base().body_quads)
    return _decimated(resolution)


@lru_cache(maxsize=4)
def _decimated(resolution: str) -> tuple[np.ndarray, np.ndarray]:
    base = load_base()
    full_faces = quads_to_triangles(base.body_quads)
    cache = bodystudio_home() / "compiled" / f"template-{resolution}-v{_DECIMATION_VERSION}.npz"
    if cache.is_file():
        # A truncated or damaged cache (a killed writer before atomic writes, a full disk) is rebuilt.
        try:
            with np.load(cache) as z:
                ids, faces = z["vertex_ids"], z["faces"]
            if ids.ndim == 1 and faces.ndim == 2 and faces.shape[1] == 3 and faces.max(initial=-1) < len(ids):
                return ids, faces
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            pass
        log.warning("%s is unreadable; building the %s template again", cache, resolution)
    ids, faces = decimate_keeping_vertices(base.vertices[: base.n_body], full_faces, RESOLUTIONS[resolution])
    with atomic_path(cache) as tmp:
        np.savez(tmp, vertex_ids=ids, faces=faces)
    return ids, faces


def decimate_keeping_vertices(V: np.ndarray, F: np.ndarray, n_target: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge-collapse decimation (pymeshlab) to about ``n_target`` vertices, keeping a vertex subset.

    Returns the indices of the kept vertices in ``V`` and the new faces over those indices.
    """
    from bodystudio.geometry.meshlab import import_pymeshlab

    pymeshlab = import_pymeshlab()

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V, F))
    # Faces ~ 2 x vertices for a closed surface; the body has a few holes, so aim slightly lower.
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(2 * n_target), optimalplacement=False,
                                                preserveboundary=True, preservenormal=True, preservetopology=True,
                                                planarquadric=True, qualitythr=0.5)
    ms.meshing_remove_unreferenced_vertices()
    out = ms.current_mesh()
    Vl, Fl = out.vertex_matrix(), out.face_matrix()
    dist, ids = cKDTree(V).query(Vl)
    if dist.max() > 1e-9:
        raise RuntimeError("decimation moved vertices; expected optimalplacement=False to keep them")
    return ids.astype(np.int64), Fl.astype(np.int64)


def build_body(phenotype: Phenotype | None = None, local: dict[str, float] | None = None,
               resolution: str = "full", rig: str = DEFAULT_RIG) -> BodyModel:
    """Shape, rig and skin a MakeHuman body.

    >>> body = build_body(Phenotype(gender=1.0), {"upperarm-fat-decr-incr": 0.3}, resolution="6k")
    """
    phenotype = phenotype or Phenotype()
    _check_choice(resolution, RESOLUTIONS, "resolution")
    rig_def = _rig(rig)
    base = load_base()
    V_all = shaped_vertices(phenotype, local)
    ids, faces = template_topology(resolution)
    weights = _full_weights(rig)
    V = V_all[: base.n_body]
    if ids is not None:
        V, weights = V[ids], weights[ids]
        weights = weights / weights.sum(1, keepdims=True)
    return BodyModel(V, faces, skeleton_from_vertices(rig_def, V_all), weights, resolution, rig,
                     phenotype, dict(local or {}), ids)


def rig_definition(rig: str = DEFAULT_RIG) -> RigDefinition:
    """The rig's bone order, parents and joint regressors over all base-mesh vertices."""
    return _rig(rig)
