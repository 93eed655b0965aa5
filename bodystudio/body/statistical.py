"""Statistical body model: PCA of a sampled population plus semantic edit directions (issue 2 §4).

Real-time Reshaping of Humans §3 and §5.1 and Avatar Reshaping §4.1 and §5.1 learn a PCA shape space from
a database of registered bodies and a linear map from semantic attributes (height, weight, girths,
muscularity) to PCA coefficients; a semantic edit adds that map's directions (eq. 4 of Real-time
Reshaping, ``M^T = M^S + sum_i lambda_i w_i``; ``beta* = beta' + f(delta gamma)`` of Avatar Reshaping
§5.1). Here the database is ``n_samples`` adults drawn from :mod:`bodystudio.body.population`, built
by the MakeHuman model, so every body is in our topology and rigged.

Each training vector stacks the rest-pose template vertices with the rig's bone heads and tails, so
the PCA basis carries the joints along: any coefficient vector gives a mesh *and* its skeleton, which
is the rig's own joint definition applied to that shape whenever the shape is in the span of the
population (joints are linear in the base-mesh vertices, eq. 3 of Real-time Reshaping). The model
poses with the MakeHuman skin weights of its template.

Coefficients are in the orthonormal PCA basis of the stacked vector (metres); ``stddev`` gives each
component's population standard deviation.
"""

from __future__ import annotations

import logging
import zipfile
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from bodystudio.body.assets import bodystudio_home
from bodystudio.body.makehuman import load_base, load_targets
from bodystudio.body.measure import ATTRIBUTE_NAMES, MESH_ATTRIBUTE_NAMES, measure_attributes
from bodystudio.body.model import DEFAULT_RIG, BodyModel, build_body, rig_definition, shape_weights
from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import InputError
from bodystudio.fileio import atomic_path

log = logging.getLogger(__name__)

STATISTICAL_MODEL_VERSION = 1
DEFAULT_SAMPLES = 300
DEFAULT_SEED = 0
# Finite-difference steps and convergence tolerances of the measured-attribute Newton iteration in edit().
_FD_STEP = {"stature_m": 0.01, "mass_kg": 1.0, "chest_m": 0.01, "waist_m": 0.01, "hip_m": 0.01,
            "arm_length_m": 0.01, "leg_length_m": 0.01}
_TOLERANCE = {"stature_m": 5e-4, "mass_kg": 0.1, "chest_m": 2e-3, "waist_m": 2e-3, "hip_m": 2e-3,
              "arm_length_m": 1e-3, "leg_length_m": 1e-3}
# an edit that ends more than this many tolerances off a target is refused (``edit``): 2.5 mm of stature, 0.5 kg
_REACH_FACTOR = 5.0


@dataclass(frozen=True, eq=False)
class StatisticalBodyModel:
    """A PCA body shape space with joints and a semantic attribute map (see module docstring)."""

    resolution: str
    rig: str
    mean: np.ndarray  # (n, 3) mean rest-pose vertices
    basis: np.ndarray  # (k, n, 3) orthonormal (with the joint rows) principal components
    stddev: np.ndarray  # (k,) population standard deviation of each coefficient
    faces: np.ndarray  # (m, 3)
    weights: np.ndarray  # (n, B) skin weights of the template
    vertex_ids: np.ndarray | None  # template vertices' indices in the full body (None = full)
    bone_names: tuple[str, ...]
    parents: np.ndarray  # (B,)
    rolls: np.ndarray  # (B,)
    joint_mean_heads: np.ndarray  # (B, 3)
    joint_mean_tails: np.ndarray
    joint_basis_heads: np.ndarray  # (k, B, 3)
    joint_basis_tails: np.ndarray
    attribute_names: tuple[str, ...]
    attribute_map: np.ndarray  # (len(attribute_names) + 1, k): coeffs = [attributes, 1] @ attribute_map
    coeffs_to_attribute_map: np.ndarray  # (k + 1, len(attribute_names)): attributes ~ [coeffs, 1] @ this
    training_attributes: np.ndarray  # (N, len(attribute_names)) measured on each training body
    training_coeffs: np.ndarray  # (N, k)

    @property
    def n_components(self) -> int:
        return len(self.stddev)

    @cached_property
    def _vertex_basis(self) -> np.ndarray:
        return self.basis.reshape(self.n_components, -1).T  # (3n, k)

    def _coeffs(self, coeffs) -> np.ndarray:
        c = np.asarray(coeffs, dtype=np.float64)
        if c.shape != (self.n_components,):
            raise InputError(f"expected {self.n_components} shape coefficients, got array of shape {c.shape}")
        return c

    def vertices(self, coeffs) -> np.ndarray:
        """Rest-pose vertices ``mean + sum_i c_i basis_i`` (the PCA shape space of Avatar Reshaping §4.1)."""
        return self.mean + np.tensordot(self._coeffs(coeffs), self.basis, axes=1)

    def skeleton(self, coeffs) -> Skeleton:
        """The rig's skeleton of the shape ``coeffs``: joints from the same coefficients as the vertices."""
        c = self._coeffs(coeffs)
        heads = self.joint_mean_heads + np.tensordot(c, self.joint_basis_heads, axes=1)
        tails = self.joint_mean_tails + np.tensordot(c, self.joint_basis_tails, axes=1)
        return Skeleton(self.bone_names, self.parents, heads, tails, self.rolls)

    def body(self, coeffs) -> BodyModel:
        """A posable :class:`BodyModel` of the shape ``coeffs`` with the template's rig and skin weights.

        A PCA shape has no MakeHuman phenotype: the BodyModel carries the default one, so take its
        attributes from :meth:`measure`, not from ``body.phenotype``.
        """
        return BodyModel(self.vertices(coeffs), self.faces, self.skeleton(coeffs), self.weights,
                         self.resolution, self.rig, vertex_ids=self.vertex_ids)

    def project(self, vertices) -> np.ndarray:
        """Least-squares coefficients of rest-pose ``vertices`` given in the model's topology."""
        V = np.asarray(vertices, dtype=np.float64)
        if V.shape != self.mean.shape:
            raise InputError(f"expected {self.mean.shape} vertices in the {self.resolution} template, got {V.shape}")
        c, *_ = np.linalg.lstsq(self._vertex_basis, (V - self.mean).ravel(), rcond=None)
        return c

    def measure(self, coeffs) -> dict[str, float]:
        """Attributes measured on the mesh of ``coeffs``; muscularity from the linear map coeffs -> attributes."""
        c = self._coeffs(coeffs)
        out = measure_attributes(self.vertices(c), self.faces, vertex_ids=self.vertex_ids,
                                 resolution="full" if self.vertex_ids is None else None)
        predicted = np.append(c, 1.0) @ self.coeffs_to_attribute_map
        out["muscularity"] = float(predicted[self.attribute_names.index("muscularity")])
        return out

    def _check_names(self, names) -> None:
        unknown = sorted(set(names) - set(self.attribute_names))
        if unknown:
            raise InputError(f"unknown attribute(s) {', '.join(unknown)}; valid: {', '.join(self.attribute_names)}")

    @cached_property
    def _attribute_moments(self) -> tuple[np.ndarray, np.ndarray]:
        A = self.training_attributes
        return A.mean(0), np.cov(A, rowvar=False)

    def _conditional_change(self, given: dict[str, float]) -> np.ndarray:
        """Expected change of every attribute given changes of some (Gaussian conditioning on the population)."""
        _, cov = self._attribute_moments
        mask = np.array([n in given for n in self.attribute_names])
        delta = np.zeros(len(self.attribute_names))
        delta[mask] = [float(given[n]) for n in np.array(self.attribute_names)[mask]]
        if mask.any() and (~mask).any():
            delta[~mask] = cov[np.ix_(~mask, mask)] @ np.linalg.solve(cov[np.ix_(mask, mask)], delta[mask])
        return delta

    def attributes_to_coeffs(self, attributes: dict[str, float], refine: bool = True) -> np.ndarray:
        """Shape coefficients of given attribute values: the linear map f(gamma) of Avatar Reshaping §5.1.

        Attributes left out take their population expectation given the ones supplied (Gaussian
        conditioning on the training attributes), so {"stature_m": 1.9} gives a typical 1.9 m person.
        With ``refine`` a few Newton steps along the supplied attributes' directions then make the
        measured values of the supplied mesh attributes match exactly (mass is not linear in shape).
        """
        self._check_names(attributes)
        mu, _ = self._attribute_moments
        offsets = {n: float(v) - mu[self.attribute_names.index(n)] for n, v in attributes.items()}
        a = mu + self._conditional_change(offsets)
        c = np.append(a, 1.0) @ self.attribute_map
        targets = {n: float(attributes[n]) for n in MESH_ATTRIBUTE_NAMES if n in attributes}
        return self._match_measured(c, targets) if refine and targets else c

    @property
    def semantic_directions(self) -> np.ndarray:
        """(len(attribute_names), k) coefficient change per unit of each attribute, the others fixed (eq. 4 w_i)."""
        return self.attribute_map[:-1]

    def edit(self, coeffs, deltas: dict[str, float], others: str = "held", iterations: int = 5) -> np.ndarray:
        """Semantic edit, eq. 4 of Real-time Reshaping: ``c + sum_i lambda_i w_i``, then Newton on the mesh.

        The linear step moves along the attribute directions; a few Newton steps (Jacobian by finite
        differences of the measured attributes) then make the measured attributes hit
        ``measured(c) + deltas``. ``others="held"`` holds every other measured attribute at its value
        before the edit (the regression directions' meaning); ``others="follow"`` lets them change as
        the population's correlations predict (a heavier body also gets wider girths; give a 0 delta to
        hold one, e.g. ``{"mass_kg": 10, "stature_m": 0}``, a heavier body of the same height). A muscularity
        change uses the linear step only (it is not measurable on the mesh).
        """
        self._check_names(deltas)
        if others not in ("held", "follow"):
            raise InputError(f"others={others!r}; valid: held, follow")
        c0 = self._coeffs(coeffs)
        if others == "held":
            step = np.array([float(deltas.get(n, 0.0)) for n in self.attribute_names])
            names = MESH_ATTRIBUTE_NAMES
        else:
            step = self._conditional_change(deltas)
            names = tuple(n for n in MESH_ATTRIBUTE_NAMES if n in deltas)
        before = self.measure(c0)
        targets = {n: before[n] + float(deltas.get(n, 0.0)) for n in names}
        c, residual = self._match_measured(c0 + step @ self.semantic_directions, targets, iterations,
                                           with_residual=True)
        if iterations > 0:
            # A wrong body with exit 0 is the worst answer: an edit the shape space cannot make with the other
            # measurements held (e.g. 17 cm shorter at the same leg length) is refused, not returned half-made.
            tol = np.array([_TOLERANCE[n] for n in targets])
            off = np.abs(residual) / (_REACH_FACTOR * tol)
            if off.max() > 1.0:
                k = int(np.argmax(off))
                asked = ", ".join(f"{n} {v:+g}" for n, v in deltas.items())
                raise InputError(f"edit ({asked}) is not reachable for this body with the other measurements "
                                 f"{'held' if others == 'held' else 'following'}: {list(targets)[k]} ends "
                                 f"{-residual[k]:+.3g} off its target; use a smaller edit")
        return c

    def _match_measured(self, c: np.ndarray, targets: dict[str, float], iterations: int = 5,
                        with_residual: bool = False):
        """Newton steps along the targets' semantic directions until the measured attributes equal ``targets``.

        Each step is the full Gauss-Newton step when it lowers the residual (in units of each attribute's
        tolerance), else halved up to three times; with none lowering it the iteration stops at the best body
        so far (a full step far from a reachable target once made a -45000 kg body). ``with_residual``: also
        return ``targets - measured`` of the returned coefficients.
        """
        names = list(targets)
        goal = np.array([targets[n] for n in names])
        tol = np.array([_TOLERANCE[n] for n in names])
        h = np.array([_FD_STEP[n] for n in names])
        D = self.semantic_directions[[self.attribute_names.index(n) for n in names]]
        m = self._mesh_attributes(c, names)
        for _ in range(iterations):
            residual = goal - m
            if np.all(np.abs(residual) < tol):
                break
            J = np.stack([(self._mesh_attributes(c + h[j] * D[j], names) - m) / h[j] for j in range(len(names))], 1)
            step = np.linalg.lstsq(J, residual, rcond=None)[0] @ D
            cost = np.linalg.norm(residual / tol)
            for alpha in (1.0, 0.5, 0.25, 0.125):
                m_try = self._mesh_attributes(c + alpha * step, names)
                if np.linalg.norm((goal - m_try) / tol) < cost:
                    c, m = c + alpha * step, m_try
                    break
            else:
                break
        return (c, goal - m) if with_residual else c

    def _mesh_attributes(self, c: np.ndarray, names: list[str]) -> np.ndarray:
        m = self.measure(c)
        return np.array([m[n] for n in names])


def population_shapes(subjects, vertex_ids: np.ndarray | None, rig: str = DEFAULT_RIG,
                      chunk: int = 50):
    """Yield ``(template vertices (n, 3), bone heads (B, 3), bone tails (B, 3))`` of each subject.

    Equal to :func:`~bodystudio.body.model.shaped_vertices` (MakeHuman's additive targets, feet on
    y = 0) restricted to the template and the joint-defining vertices, but computed for a chunk of
    subjects at once as one sparse (targets x subjects) product over only the rows needed.
    """
    base = load_base()
    targets = load_targets(len(base.vertices))
    rig_def = rig_definition(rig)
    n_body = base.n_body
    ids = np.arange(n_body) if vertex_ids is None else np.asarray(vertex_ids)
    regressors = sp.vstack([rig_def.head_regressor, rig_def.tail_regressor]).tocsc()
    joint_vertices = np.flatnonzero(np.diff(regressors.indptr))
    keep = np.unique(np.concatenate([ids, joint_vertices]))
    # Rows: x, y, z of every kept vertex, then y of every body vertex (the floor is the lowest of them).
    rows = np.concatenate([(3 * keep[:, None] + np.arange(3)).ravel(), 3 * np.arange(n_body) + 1])
    position = np.searchsorted(keep, ids)
    R = regressors[:, keep].tocsr()
    weights = [shape_weights(phenotype, local) for phenotype, local in subjects]
    names = sorted({name for w in weights for name, v in w.items() if v != 0.0})
    M = targets.matrix(names).tocsr()[rows]
    W = np.array([[w.get(name, 0.0) for w in weights] for name in names]).reshape(len(names), len(subjects))
    base_rows = base.vertices.ravel()[rows]
    n_keep = 3 * len(keep)
    for start in range(0, len(subjects), chunk):
        shapes = base_rows[:, None] + M @ W[:, start:start + chunk]  # (rows, subjects in the chunk)
        for j in range(shapes.shape[1]):
            V_keep = shapes[:n_keep, j].reshape(-1, 3).copy()
            V_keep[:, 1] -= shapes[n_keep:, j].min()
            HT = R @ V_keep
            yield V_keep[position], HT[: len(rig_def.bone_names)], HT[len(rig_def.bone_names):]


def population_training_set(n_samples: int, seed: int, resolution: str, rig: str = DEFAULT_RIG,
                            progress: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stacked rest-pose (vertices, bone heads, bone tails) ``(N, 3n + 6B)``, attributes ``(N, 8)``, faces.

    Bodies of the seeded population are shaped with the MakeHuman targets directly (no skin-weight work
    per body, :func:`population_shapes`) and measured with :func:`measure_attributes`.
    """
    from rich.progress import Progress

    from bodystudio.body.population import sample_population

    template = build_body(resolution=resolution, rig=rig)
    ids, faces = template.vertex_ids, template.faces
    subjects = sample_population(n_samples, seed)
    X = np.empty((n_samples, 3 * template.n_vertices + 6 * template.skeleton.n_bones))
    A = np.empty((n_samples, len(ATTRIBUTE_NAMES)))
    with Progress(disable=not progress, transient=True) as bar:
        task = bar.add_task(f"population ({resolution})", total=n_samples)
        for i, (V, heads, tails) in enumerate(population_shapes(subjects, ids, rig)):
            X[i] = np.concatenate([V.ravel(), heads.ravel(), tails.ravel()])
            m = measure_attributes(V, faces, vertex_ids=ids, resolution="full" if ids is None else None,
                                   muscularity=subjects[i][0].muscle)
            A[i] = [m[n] for n in ATTRIBUTE_NAMES]
            bar.advance(task)
    return X, A, faces


def build_statistical_model(resolution: str = "6k", n_components: int = 20, n_samples: int = DEFAULT_SAMPLES,
                            seed: int = DEFAULT_SEED, rig: str = DEFAULT_RIG,
                            progress: bool = True) -> StatisticalBodyModel:
    """Learn the PCA (Avatar Reshaping §4.1) and the attribute -> coefficient map (eq. 4, §5.1) from a population."""
    if not 1 <= n_components < n_samples:
        raise InputError(f"n_components={n_components} must be between 1 and n_samples-1={n_samples - 1}")
    template = build_body(resolution=resolution, rig=rig)
    n, B = template.n_vertices, template.skeleton.n_bones
    X, A, faces = population_training_set(n_samples, seed, resolution, rig, progress)
    mean = X.mean(0)
    Xc = X - mean
    # PCA through the (N, N) Gram matrix: N << 3n, and one matrix product is far cheaper than a thin SVD.
    eigenvalues, U = np.linalg.eigh(Xc @ Xc.T)
    order = np.argsort(eigenvalues)[::-1]
    s = np.sqrt(np.clip(eigenvalues[order], 0.0, None))
    U = U[:, order]
    k = n_components
    Vt = (U[:, :k].T @ Xc) / s[:k, None]
    C = U[:, :k] * s[:k]
    Z = np.hstack([A, np.ones((n_samples, 1))])
    attribute_map = np.linalg.lstsq(Z, C, rcond=None)[0]
    coeffs_to_attribute_map = np.linalg.lstsq(np.hstack([C, np.ones((n_samples, 1))]), A, rcond=None)[0]

    def split(rows):
        return rows[..., : 3 * n], rows[..., 3 * n: 3 * n + 3 * B], rows[..., 3 * n + 3 * B:]

    mv, mh, mt = split(mean)
    bv, bh, bt = split(Vt[:k])
    log.info("statistical model %s: %d bodies, %d components explain %.4f of the variance", resolution,
             n_samples, k, float((s[:k] ** 2).sum() / (s ** 2).sum()))
    return StatisticalBodyModel(
        resolution=resolution, rig=rig, mean=mv.reshape(n, 3), basis=bv.reshape(k, n, 3),
        stddev=s[:k] / np.sqrt(n_samples - 1), faces=faces, weights=template.weights, vertex_ids=template.vertex_ids,
        bone_names=template.skeleton.bone_names, parents=template.skeleton.parents, rolls=template.skeleton.rolls,
        joint_mean_heads=mh.reshape(B, 3), joint_mean_tails=mt.reshape(B, 3),
        joint_basis_heads=bh.reshape(k, B, 3), joint_basis_tails=bt.reshape(k, B, 3),
        attribute_names=ATTRIBUTE_NAMES, attribute_map=attribute_map,
        coeffs_to_attribute_map=coeffs_to_attribute_map, training_attributes=A, training_coeffs=C)


_ARRAY_FIELDS = ("mean", "basis", "stddev", "faces", "weights", "parents", "rolls", "joint_mean_heads",
                 "joint_mean_tails", "joint_basis_heads", "joint_basis_tails", "attribute_map",
                 "coeffs_to_attribute_map", "training_attributes", "training_coeffs")


def save_statistical_model(path: str | Path, model: StatisticalBodyModel) -> None:
    """Write the model as one versioned ``.npz`` (atomically)."""
    arrays = {f: getattr(model, f) for f in _ARRAY_FIELDS}
    arrays.update(version=np.array(STATISTICAL_MODEL_VERSION), resolution=np.array(model.resolution),
                  rig=np.array(model.rig), bone_names=np.array(model.bone_names),
                  attribute_names=np.array(model.attribute_names),
                  vertex_ids=np.array([], dtype=np.int64) if model.vertex_ids is None else model.vertex_ids)
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def read_statistical_model(path: str | Path) -> StatisticalBodyModel:
    """Read a model written by :func:`save_statistical_model`; a wrong version or broken file raises FileFormatError."""
    from bodystudio.errors import FileFormatError

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if int(z["version"]) != STATISTICAL_MODEL_VERSION:
                raise FileFormatError(f"{path}: statistical model version {int(z['version'])}, expected "
                                      f"{STATISTICAL_MODEL_VERSION}; delete it to rebuild")
            arrays = {f: z[f] for f in _ARRAY_FIELDS}
            ids = z["vertex_ids"]
            return StatisticalBodyModel(resolution=str(z["resolution"]), rig=str(z["rig"]),
                                        bone_names=tuple(str(b) for b in z["bone_names"]),
                                        attribute_names=tuple(str(a) for a in z["attribute_names"]),
                                        vertex_ids=ids if len(ids) else None, **arrays)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise FileFormatError(f"{path}: not a readable statistical body model ({exc}); delete it to rebuild") from None


def statistical_model_path(resolution: str, n_components: int, n_samples: int, seed: int, rig: str) -> Path:
    """Cache file of a model; its name fingerprints the inputs so a changed population or asset set rebuilds."""
    import hashlib

    from bodystudio.body.model import shaped_vertices, template_topology
    from bodystudio.body.population import sample_population

    ids, faces = template_topology(resolution)
    inputs = hashlib.sha1(repr(sample_population(4, seed)).encode())
    for array in (shaped_vertices().round(7), faces, np.array([]) if ids is None else ids):
        inputs.update(np.ascontiguousarray(array).tobytes())
    return (bodystudio_home() / "compiled" / f"statistical-{resolution}-{rig}-k{n_components}-n{n_samples}-s{seed}"
            f"-v{STATISTICAL_MODEL_VERSION}-{inputs.hexdigest()[:10]}.npz")


def load_statistical_model(resolution: str = "6k", n_components: int = 20, n_samples: int = DEFAULT_SAMPLES,
                           seed: int = DEFAULT_SEED, rig: str = DEFAULT_RIG,
                           progress: bool = True) -> StatisticalBodyModel:
    """The cached statistical model under ``bodystudio_home()/compiled/``; built (< 1 min) on first use."""
    from bodystudio.errors import FileFormatError

    path = statistical_model_path(resolution, n_components, n_samples, seed, rig)
    if path.is_file():
        try:
            return read_statistical_model(path)
        except FileFormatError as exc:
            log.warning("rebuilding: %s", exc)
    model = build_statistical_model(resolution, n_components, n_samples, seed, rig, progress)
    save_statistical_model(path, model)
    return model
