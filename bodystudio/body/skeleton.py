"""Skeletons from MakeHuman's ``rigs/standard/rig.*.json``: joints that follow the body shape.

Each bone's head and tail is defined on the mesh (strategy CUBE: centre of a joint cube's vertices;
VERTEX: one vertex; MEAN: mean of listed vertices), so joint positions are a fixed linear function of
the vertices, ``J = R V``. That is the idea of eq. 3 of Real-time Reshaping of Humans (joints
expressed in the shape's own vertices) and of §4.2 of Avatar Reshaping: joints follow any reshape.
Rest frames follow Blender's bone convention (y along the bone, roll about it), which the rigs'
``roll`` values are defined in; Blender is z-up, so frames are built there and rotated back.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from bodystudio.errors import AssetError, InputError

RIGS = ("game_engine", "default", "default_no_toes", "cmu_mb")
# Our world (= MakeHuman's: y up, facing +z) to Blender's (z up, facing -y): b = (x, -z, y).
TO_BLENDER = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


@dataclass(frozen=True, eq=False)
class RigDefinition:
    """A rig read from JSON: bone names in topological order, parents and the joint regressor."""

    name: str
    bone_names: tuple[str, ...]
    parents: np.ndarray  # (B,) parent index, -1 for roots
    head_regressor: sp.csr_matrix  # (B, n_all) head positions = head_regressor @ V_all
    tail_regressor: sp.csr_matrix
    rolls: np.ndarray  # (B,) Blender roll, radians
    weights_file: Path


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A skeleton in the rest pose: world-space bone heads, tails and rest frames (metres)."""

    bone_names: tuple[str, ...]
    parents: np.ndarray
    heads: np.ndarray  # (B, 3)
    tails: np.ndarray  # (B, 3)
    rolls: np.ndarray  # (B,)

    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    def index(self, name: str) -> int:
        try:
            return self.bone_names.index(name)
        except ValueError:
            raise InputError(f"unknown bone {name!r}; valid bones: {', '.join(self.bone_names)}") from None

    @cached_property
    def rest_rotations(self) -> np.ndarray:
        """(B, 3, 3) bone rest frames in world axes: column 1 runs head -> tail."""
        return bone_rest_rotations(self.heads, self.tails, self.rolls)

    @cached_property
    def rest_frames(self) -> np.ndarray:
        """(B, 4, 4) rigid transforms bone -> world in the rest pose."""
        A = np.tile(np.eye(4), (self.n_bones, 1, 1))
        A[:, :3, :3] = self.rest_rotations
        A[:, :3, 3] = self.heads
        return A

    @cached_property
    def lengths(self) -> np.ndarray:
        return np.linalg.norm(self.tails - self.heads, axis=1)

    @cached_property
    def children(self) -> list[list[int]]:
        out: list[list[int]] = [[] for _ in self.bone_names]
        for j, p in enumerate(self.parents):
            if p >= 0:
                out[p].append(j)
        return out


def blender_vec_roll_to_matrix(direction: np.ndarray, roll: float) -> np.ndarray:
    """Blender's ``vec_roll_to_mat3``: bone frame whose y axis is ``direction``, rolled about it."""
    x, y, z = direction / np.linalg.norm(direction)
    theta = 1.0 + y
    theta_alt = x * x + z * z
    if theta > 1e-5 or theta_alt > 2.5e-4:
        if theta <= 1e-5:
            theta = theta_alt * 0.5 + theta_alt * theta_alt * 0.125
        B = np.array([[1 - x * x / theta, x, -x * z / theta],
                      [-x, y, -z],
                      [-x * z / theta, z, 1 - z * z / theta]])
    else:
        B = np.diag([-1.0, -1.0, 1.0])
    R = Rotation.from_rotvec(roll * np.array([x, y, z])).as_matrix()
    return R @ B


def bone_rest_rotations(heads: np.ndarray, tails: np.ndarray, rolls: np.ndarray) -> np.ndarray:
    """Rest frames of bones in our axes, computed in Blender's axes where the rolls are defined."""
    out = np.empty((len(heads), 3, 3))
    for j, (h, t, r) in enumerate(zip(heads, tails, rolls, strict=True)):
        d = TO_BLENDER @ (t - h)
        if not np.linalg.norm(d) > 1e-9:
            d = np.array([0.0, 0.0, 1e-3])
        out[j] = TO_BLENDER.T @ blender_vec_roll_to_matrix(d, r)
    return out


def _point_row(spec: dict, cubes: dict[str, np.ndarray], rig_file: Path, bone: str) -> tuple[np.ndarray, np.ndarray]:
    strategy = spec.get("strategy")
    if strategy == "CUBE":
        name = spec["cube_name"]
        if name not in cubes:
            raise AssetError(f"{rig_file}: bone {bone} uses joint cube {name!r}, which the base mesh lacks")
        idx = cubes[name]
    elif strategy == "VERTEX":
        idx = np.array([spec["vertex_index"]])
    elif strategy == "MEAN":
        idx = np.array(spec["vertex_indices"])
    else:
        raise AssetError(f"{rig_file}: bone {bone} has unknown joint strategy {strategy!r}")
    return idx, np.full(len(idx), 1.0 / len(idx))


def load_rig(name: str, data_dir: Path, n_all: int, cubes: dict[str, np.ndarray]) -> RigDefinition:
    """Read ``rigs/standard/rig.NAME.json`` into a :class:`RigDefinition` (bones ordered parents first)."""
    if name not in RIGS:
        raise InputError(f"unknown rig {name!r}; valid rigs: {', '.join(RIGS)}")
    rig_file = data_dir / "rigs" / "standard" / f"rig.{name}.json"
    weights_name = "default" if name == "default_no_toes" else name
    weights_file = data_dir / "rigs" / "standard" / f"weights.{weights_name}.json"
    try:
        spec = json.loads(rig_file.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetError(f"{rig_file}: cannot read rig ({exc}); "
                         "delete the asset cache and rerun 'make setup'") from None
    order: list[str] = []
    placed: set[str] = set()
    remaining = sorted(spec)
    while remaining:
        progress = [b for b in remaining if not spec[b]["parent"] or spec[b]["parent"] in placed]
        if not progress:
            raise AssetError(f"{rig_file}: bones {remaining[:3]} have parents outside the rig")
        order.extend(progress)
        placed.update(progress)
        remaining = [b for b in remaining if b not in placed]
    index = {b: i for i, b in enumerate(order)}
    parents = np.array([index[spec[b]["parent"]] if spec[b]["parent"] else -1 for b in order])
    regs = []
    for end in ("head", "tail"):
        rows, cols, vals = [], [], []
        for i, b in enumerate(order):
            idx, w = _point_row(spec[b][end], cubes, rig_file, b)
            rows.append(np.full(len(idx), i))
            cols.append(idx)
            vals.append(w)
        regs.append(sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                  shape=(len(order), n_all)))
    rolls = np.array([spec[b].get("roll", 0.0) for b in order])
    return RigDefinition(name, tuple(order), parents, regs[0], regs[1], rolls, weights_file)


def skeleton_from_vertices(rig: RigDefinition, vertices_all: np.ndarray) -> Skeleton:
    """Place the rig's joints on a shaped base mesh (all vertices, helpers included)."""
    return Skeleton(rig.bone_names, rig.parents, rig.head_regressor @ vertices_all,
                    rig.tail_regressor @ vertices_all, rig.rolls)


def load_skin_weights(rig: RigDefinition, n_body: int, vertex_ids: np.ndarray | None = None) -> np.ndarray:
    """Dense ``(n_body, B)`` skin weights from ``weights.*.json``, normalised to sum 1 per vertex.

    With ``vertex_ids`` the rows of those base-mesh vertices instead (``(k, B)``; the helper geometry,
    e.g. the garment proxies, is weighted in the same file).
    """
    try:
        data = json.loads(rig.weights_file.read_text())["weights"]
    except (OSError, json.JSONDecodeError, KeyError) as exc:
        raise AssetError(f"{rig.weights_file}: cannot read skin weights ({exc}); rerun 'make setup'") from None
    rows = np.arange(n_body) if vertex_ids is None else np.asarray(vertex_ids, dtype=np.int64)
    row_of = {int(v): i for i, v in enumerate(rows)}
    W = np.zeros((len(rows), len(rig.bone_names)))
    col = {b: i for i, b in enumerate(rig.bone_names)}
    for bone, pairs in data.items():
        if bone not in col or not pairs:
            continue
        arr = np.asarray(pairs, dtype=np.float64)
        idx = arr[:, 0].astype(np.int64)
        if vertex_ids is None:
            keep = idx < n_body
            np.add.at(W[:, col[bone]], idx[keep], arr[keep, 1])
        else:
            hit = np.array([row_of.get(int(i), -1) for i in idx])
            keep = hit >= 0
            np.add.at(W[:, col[bone]], hit[keep], arr[keep, 1])
    W = np.clip(W, 0.0, None)
    total = W.sum(1, keepdims=True)
    if np.any(total <= 0):
        raise AssetError(f"{rig.weights_file}: {int((total <= 0).sum())} vertices have no skin weight")
    return W / total
