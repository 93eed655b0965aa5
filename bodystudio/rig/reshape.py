"""Avatar reshaping, §5.1 of Avatar Reshaping: a semantic edit of the fitted model carried to the scan by
deformation transfer (Sumner and Popović 2004).

The edit ``β* = β' + f(Δγ)`` (the statistical model's attribute map, :meth:`edit`) gives ``M* = M(θ', β*)``.
Each model triangle's deformation gradient ``S_k`` (M' -> M*) is applied to the scan triangles it
corresponds to (closest compatible model triangle of each scan triangle); the scan's new vertices solve
the Poisson equation of eq. 1, ``argmin sum_t A_t ||∇_t Z* - S_t ∇_t Z||^2``, whose matrix depends on the
scan only and is factorised once per scan, so each edit costs a back-substitution. The skeleton follows
through the joints' scan-vertex coordinates (eq. 6).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import face_normals
from bodystudio.rig.avatar import Avatar
from bodystudio.rig.skeleton_transfer import closest_points

# Short names accepted by ``--reshape`` for the statistical model's attributes.
ATTRIBUTE_ALIASES = {"stature": "stature_m", "height": "stature_m", "mass": "mass_kg", "weight": "mass_kg",
                     "chest": "chest_m", "waist": "waist_m", "hip": "hip_m", "arm": "arm_length_m",
                     "leg": "leg_length_m", "muscle": "muscularity", "muscularity": "muscularity"}
#: Largest edit accepted per attribute: about three to four standard deviations of the adult population
#: (stature sd ~9 cm, mass sd ~12 kg, girths ~9 cm, limb lengths ~4 cm). Beyond it the statistical model
#: extrapolates (``stature=+5`` made a 460 m avatar) and the result cannot be trusted.
RESHAPE_LIMITS = {"stature_m": 0.30, "mass_kg": 40.0, "chest_m": 0.30, "waist_m": 0.30, "hip_m": 0.30,
                  "arm_length_m": 0.15, "leg_length_m": 0.20, "muscularity": 0.5}
SOFT_ANCHOR = 1e-6  # relative weight tying the solution to the original positions (removes the null space)


def parse_reshape(text: str) -> dict[str, float]:
    """``"stature=+0.05,mass=-5"`` -> ``{"stature_m": 0.05, "mass_kg": -5.0}``."""
    out: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, sep, value = item.partition("=")
        key = ATTRIBUTE_ALIASES.get(name.strip(), name.strip())
        if not sep:
            raise InputError(f"--reshape {item!r}: expected NAME=DELTA, e.g. stature=+0.05,mass=-5")
        if key in out:  # 'stature=0.05,stature_m=-0.05': the last one silently won (rel6b)
            raise InputError(f"--reshape {text!r}: {key} is given twice; give each attribute once")
        try:
            out[key] = float(value)
        except ValueError:
            raise InputError(f"--reshape {item!r}: {value!r} is not a number") from None
    if not out:
        raise InputError("--reshape is empty; e.g. stature=+0.05,mass=-5")
    return check_reshape(out)


def check_reshape(deltas: dict[str, float]) -> dict[str, float]:
    """Refuse attribute changes the statistical model cannot be trusted for (unknown names, NaN, beyond
    :data:`RESHAPE_LIMITS`); returns ``deltas``."""
    for key, value in deltas.items():
        if key not in RESHAPE_LIMITS:
            raise InputError(f"--reshape {key}={value}: unknown attribute {key!r}; valid: "
                             f"{', '.join(sorted(ATTRIBUTE_ALIASES))}")
        limit = RESHAPE_LIMITS[key]
        if not np.isfinite(value) or abs(value) > limit:
            unit = {"m": " m", "kg": " kg"}.get(key.rpartition("_")[2], "")
            raise InputError(f"--reshape {key}={value:+g}: change outside the population's plausible span "
                             f"[-{limit:g}, +{limit:g}]{unit}; lengths are in metres, mass in kg")
    return deltas


def deformation_gradients(V0: np.ndarray, V1: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Per-triangle deformation gradients ``(m, 3, 3)`` from V0 to V1 (Sumner's fourth-vertex frames)."""
    def frames(V):
        e1 = V[F[:, 1]] - V[F[:, 0]]
        e2 = V[F[:, 2]] - V[F[:, 0]]
        n = np.cross(e1, e2)
        n /= np.sqrt(np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20))
        return np.stack([e1, e2, n], axis=2)

    return frames(V1) @ np.linalg.inv(frames(V0))


@dataclass(frozen=True, eq=False)
class ScanReshaper:
    """Deformation transfer onto one scan with its Poisson matrix factorised once."""

    scan_V: np.ndarray
    scan_F: np.ndarray
    model_V: np.ndarray  # M' (posed fitted model)
    model_F: np.ndarray

    @cached_property
    def _operators(self):
        G = igl.grad(self.scan_V, self.scan_F)  # (3m, n): all x-derivatives, then y, then z
        area = 0.5 * igl.doublearea(self.scan_V, self.scan_F)
        D = sp.diags(np.tile(area, 3))
        L = (G.T @ D @ G).tocsc()
        mass = np.zeros(len(self.scan_V))
        for k in range(3):
            np.add.at(mass, self.scan_F[:, k], area / 3.0)
        eps = SOFT_ANCHOR * L.diagonal().mean() / mass.mean()
        lu = splu((L + eps * sp.diags(mass)).tocsc())
        return G, D, lu, eps * mass

    @cached_property
    def triangle_correspondence(self) -> np.ndarray:
        """For each scan triangle the model triangle closest to its centroid (compatible normals preferred)."""
        centroids = self.scan_V[self.scan_F].mean(1)
        tri, _, _ = closest_points(centroids, self.model_V, self.model_F)
        return tri

    def reshape(self, model_target: np.ndarray) -> np.ndarray:
        """Scan vertices after transferring the model's deformation ``M' -> model_target`` (same topology)."""
        G, D, lu, anchor = self._operators
        S = deformation_gradients(self.model_V, model_target, self.model_F)[self.triangle_correspondence]
        m = len(self.scan_F)
        grad = (G @ self.scan_V).reshape(3, m, 3).transpose(1, 0, 2)  # (m, d/dx.., coord)
        target = np.einsum("tdc,tec->tde", grad, S)  # ∇(S z) = ∇z S^T per triangle
        rhs = G.T @ D @ target.transpose(1, 0, 2).reshape(3 * m, 3)
        # The soft anchor pulls towards the original positions moved by the model's mean displacement.
        tri, lam, _ = closest_points(self.scan_V, self.model_V, self.model_F)
        shift = sum(lam[:, k, None] * (model_target - self.model_V)[self.model_F[tri, k]] for k in range(3))
        Z = lu.solve(np.asarray(rhs + anchor[:, None] * (self.scan_V + shift)))
        # Poisson fixes shape up to translation: put the result where the model's displacement says.
        return Z + (self.scan_V + shift - Z).mean(0)


def reshape_avatar(avatar: Avatar, fit, model, deltas: dict[str, float],
                   reshaper: ScanReshaper | None = None) -> tuple[Avatar, np.ndarray]:
    """Semantic edit (§5.1) of the fitted model transferred to the avatar; returns it and ``β*``."""
    check_reshape(deltas)
    if "muscularity" not in model.attribute_names:
        deltas = {k: v for k, v in deltas.items() if k != "muscularity"}
    coeffs = model.edit(fit.coeffs, deltas)
    skel = model.skeleton(coeffs)
    target = linear_blend_skinning(model.vertices(coeffs), model.weights, skinning_transforms(skel, fit.pose))
    reshaper = reshaper or ScanReshaper(avatar.vertices, avatar.faces, fit.vertices, fit.faces)
    Z = reshaper.reshape(target)
    out = avatar.with_vertices(Z, rest_rotations=skel.rest_rotations.copy())
    out.metadata["reshape"] = dict(deltas)
    out.metadata["reshaped_coeffs"] = coeffs.tolist()
    return out, coeffs


def face_normal_agreement(V: np.ndarray, F: np.ndarray, W: np.ndarray) -> float:
    """Mean cosine between face normals of two embeddings (a smoothness check for tests)."""
    return float(np.mean(np.sum(face_normals(V, F) * face_normals(W, F), axis=1)))
