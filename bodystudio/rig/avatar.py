"""The rigged avatar: the scan itself (bind pose = the scan's pose), its transferred skeleton and skin.

Bone ``j`` has bind frame ``[R_bind_j | h_j]`` (the fitted model's posed bone frame, with the head the
scan's transferred joint) and a canonical rest frame ``R_rest_j`` (the fitted model's rest pose) that
poses are expressed in, so any pose of the body model (local axis-angle rotations in rest frames)
drives the avatar: global rotations ``G_j`` follow from forward kinematics on the rest frames (the root
keeping its bind orientation), heads
from the bind offsets (``h_j' = h_p' + G_p R_bind_p^T (h_j - h_p)``, as in a glTF node hierarchy), and
bone ``j`` moves bind-pose vertices by ``S_j = [G_j R_bind_j^T | h_j' - G_j R_bind_j^T h_j]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.body.skinning import linear_blend_skinning
from bodystudio.geometry.mesh import Mesh


@dataclass(frozen=True, eq=False)
class Avatar:
    """A rigged scan: vertices in the bind pose (metres, y up), faces, colours, skeleton and skin weights."""

    vertices: np.ndarray  # (n, 3)
    faces: np.ndarray  # (m, 3)
    vertex_colors: np.ndarray | None
    bone_names: tuple[str, ...]
    parents: np.ndarray  # (B,)
    joint_coordinates: np.ndarray | None  # (B, n): heads = joint_coordinates @ vertices (eq. 4/6)
    bind_rotations: np.ndarray  # (B, 3, 3)
    rest_rotations: np.ndarray  # (B, 3, 3)
    bone_lengths: np.ndarray  # (B,)
    weights: np.ndarray  # (n, B), <= 4 influences
    bind_translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    metadata: dict = field(default_factory=dict)
    loaded_heads: np.ndarray | None = None  # an avatar read back from a file knows its heads, not their coordinates

    @cached_property
    def heads(self) -> np.ndarray:
        """Bind-pose bone heads ``(B, 3)``: combinations of scan vertices (eq. 6)."""
        if self.joint_coordinates is None:
            return self.loaded_heads
        return self.joint_coordinates @ self.vertices

    @property
    def n_bones(self) -> int:
        return len(self.bone_names)

    @property
    def mesh(self) -> Mesh:
        return Mesh(self.vertices, self.faces, self.vertex_colors)

    @cached_property
    def bind_frames(self) -> np.ndarray:
        A = np.tile(np.eye(4), (self.n_bones, 1, 1))
        A[:, :3, :3] = self.bind_rotations
        A[:, :3, 3] = self.heads
        return A

    def global_rotations(self, pose: Pose) -> np.ndarray:
        """``G_j``: world rotations of the bones for local rotations in the canonical rest frames.

        A root keeps its bind orientation (the scan's facing and lean) with the pose's root rotation on
        top: the root's rest frame is a short floor-level bone whose direction varies by degrees with the
        fitted shape, and the fit's root rotation already absorbed that difference.
        """
        R = self.rest_rotations
        local = Rotation.from_rotvec(pose.rotations).as_matrix()
        G = np.empty_like(R)
        for j, p in enumerate(self.parents):
            G[j] = self.bind_rotations[j] @ local[j] if p < 0 else G[p] @ R[p].T @ R[j] @ local[j]
        return G

    def skinning_transforms(self, pose: Pose) -> np.ndarray:
        """``S_j`` ``(B, 4, 4)`` moving bind-pose points to ``pose`` (root translation relative to the bind)."""
        G = self.global_rotations(pose)
        delta = G @ np.transpose(self.bind_rotations, (0, 2, 1))
        h = self.heads
        posed_heads = np.empty_like(h)
        for j, p in enumerate(self.parents):
            if p < 0:
                posed_heads[j] = h[j] + (pose.translation - self.bind_translation)
            else:
                posed_heads[j] = posed_heads[p] + delta[p] @ (h[j] - h[p])
        S = np.tile(np.eye(4), (self.n_bones, 1, 1))
        S[:, :3, :3] = delta
        S[:, :3, 3] = posed_heads - np.einsum("bij,bj->bi", delta, h)
        return S

    def posed(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """Posed vertices and bone heads (linear blend skinning)."""
        S = self.skinning_transforms(pose)
        return linear_blend_skinning(self.vertices, self.weights, S), S[:, :3, 3] + np.einsum(
            "bij,bj->bi", S[:, :3, :3], self.heads)

    def local_node_rotations(self, pose: Pose) -> np.ndarray:
        """glTF/BVH node rotations ``G_p^T G_j`` (root: ``G_j``) ``(B, 3, 3)`` realising ``pose``."""
        G = self.global_rotations(pose)
        out = np.empty_like(G)
        for j, p in enumerate(self.parents):
            out[j] = G[j] if p < 0 else G[p].T @ G[j]
        return out

    def with_vertices(self, vertices: np.ndarray, rest_rotations: np.ndarray | None = None) -> Avatar:
        """The same rig on reshaped vertices: joints follow through their coordinates (§5.1 + eq. 6)."""
        return Avatar(vertices, self.faces, self.vertex_colors, self.bone_names, self.parents, self.joint_coordinates,
                      self.bind_rotations, self.rest_rotations if rest_rotations is None else rest_rotations,
                      self.bone_lengths, self.weights, self.bind_translation, dict(self.metadata))
