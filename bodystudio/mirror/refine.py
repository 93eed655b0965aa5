"""Per-frame refinement of the IK pose against the frame's silhouette, depth and Kinect joints (MIR12).

The IK of §5.2 (:mod:`bodystudio.mirror.track`) fits bone directions to the Kinect joints only, and the
joints of the SDK are centimetres off the body's surface. What the warp of §5.4 needs is that the *projected
source body covers the person's silhouette* in the image, since the warp maps the source's projection onto the
target's. This step refines the root (translation and rotation) and the swing of the spine, neck, head,
clavicles, limbs, hands and feet (not their twist, which an oracle measured to cost the warp nothing:
docs/mirror.md "MIR12") by a few Gauss-Newton steps of the energy

``E = w_sil (E_out + E_cover) + w_depth E_depth + w_joint E_joint + E_trunk + E_prior``

* ``E_out``: the distance outside the foreground mask of every projected (subsampled) source vertex: a body
  point projecting outside the person's silhouette is wrong whatever occludes it (the distance-transform
  silhouette term of Rapid Skin / the garment fit, one-sided);
* ``E_cover``: every outline pixel of the mask pulled onto the nearest projected rim vertex (along the rim's
  image normal): the mask's outline must be drawn by the body's outline;
* ``E_depth``: point-to-plane distance of the player's depth points to their nearest front-facing vertex;
* ``E_joint``: the Kinect joints as soft targets (the IK's objective, tracked joints weighted up);
* ``E_trunk``: the bend of the spine, neck, head and clavicles against their parents held near the rest pose
  (a weak pose prior, 16 degrees: the Kinect joints give these short bones to 5-12 degrees and the surface hardly
  shows a bend of the lower spine; MIR12g, docs/mirror.md "Who owns the last 0.04");
* ``E_prior``: Tikhonov damping of the change from the IK pose.

The run's plan also refines the twist of spine_01 and spine_02 (:data:`TWIST_BONES`: the upper body's yaw against
the pelvis, which the IK takes from different joints), and a step turns the root about the body's centroid, not
the Root bone's head on the floor (:data:`ROOT_PIVOT`; MIR12h, docs/mirror.md "The root's yaw and pivot").

Every residual is linear in the parameters to first order through the skinning: a vertex ``v`` moves by
``dt + w x (v - h_root)`` for the root and ``s_j(v) (e_j x (v - h_j))`` for bone ``j``'s swing about the axes
``e_j`` perpendicular to the posed bone, where ``s_j(v)`` is the skin weight of ``v`` on ``j``'s subtree.

Speed (issue 12, MIRFAST): ``J^T J`` and ``J^T r`` are accumulated row by row in numba
(:func:`accumulate_normal_equations`; a row touches only the bones whose subtree holds the point), the forward
kinematics, skinning, mask outline and nearest-point queries (:func:`nearest_within`, a grid instead of two k-d
trees) are numba kernels, and the mask work is limited to the silhouette's box: ~3.3 ms CPU per frame on one core
against MIR12b's ~10 with the same result (to ~1e-12; ``tests/mirror/refine_reference.py`` keeps MIR12b's numpy
implementation, and ``tests/mirror/test_pose_refine_analytic.py`` pins the two together).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from bodystudio.body.kinect import KINECT_JOINT_SETS, kinect_joint_names
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.errors import InputError
from bodystudio.mirror.track import blend_skin
from bodystudio.mirror.track import posed_frames as _posed_frames

#: Bones whose swing is refined (their twist is the IK's); the Root gets its full rotation and translation.
#: spine_03, head, hands and feet added to the first set: warp_iou +0.003 / +0.005 / +0.001 on MIR-SYNTH
#: 41 / 42 / 43 for 1.8 ms more per frame (one core; docs/mirror.md, MIR12b).
SWING_BONES = ("spine_01", "spine_02", "spine_03", "neck_01", "head", "clavicle_l", "clavicle_r", "upperarm_l",
               "upperarm_r", "lowerarm_l", "lowerarm_r", "hand_l", "hand_r", "thigh_l", "thigh_r", "calf_l", "calf_r",
               "foot_l", "foot_r")
#: The first set (MIR12b's oracle compares it).
TRUNK_AND_LIMB_BONES = ("spine_01", "spine_02", "neck_01", "clavicle_l", "clavicle_r", "upperarm_l", "upperarm_r",
                        "lowerarm_l", "lowerarm_r", "thigh_l", "thigh_r", "calf_l", "calf_r")
#: Bones whose bend against the parent E_trunk holds near the rest pose (``RefineWeights.trunk_rad``): the spine,
#: neck, head and clavicles, short bones whose direction the Kinect joints give to 5-12 degrees and the body's
#: surface hardly shows (docs/mirror.md, MIR12g).
TRUNK_BONES = ("spine_01", "spine_02", "spine_03", "neck_01", "head", "clavicle_l", "clavicle_r")
#: E_trunk's scale: 16 degrees of bend count as one (a weak pull; 2-8 degrees measured no better on the warp).
TRUNK_RAD = float(np.radians(16.0))
#: A scale for :attr:`RefineWeights.pelvis_tilt_rad` that the run can switch on (``run.PELVIS_TILT_RAD``): 1.5 degrees
#: of the pelvis's lean count as one (mir12ad, docs/mirror.md).
PELVIS_TILT_RAD = float(np.radians(1.5))
#: Gauss-Newton steps per frame: on MIR-SYNTH 41 / 42 one step scores the warp as well as two or three
#: (warp_iou 0.913 / 0.894 against 0.913 / 0.894 / 0.912 / 0.894) at half the cost (docs/mirror.md).
ITERATIONS = 1
#: Bones whose twist (the turn about the bone) the run's plan refines as well (``refine_plan(twist_bones=...)``):
#: the upper body's yaw against the pelvis. The IK takes the pelvis's yaw from the hip joints and the shoulders'
#: from the shoulder joints, each to ~4 degrees; with the spine's twist fixed the root could only turn both
#: together, so the refinement left the root's yaw as the IK gave it (3.0-4.0 degrees off on MIR-SYNTH 41 / 42 /
#: 43). With these two: 1.8-3.1 degrees, warp_iou +0.004 / +0.005 / +0.006 (docs/mirror.md, MIR12h).
TWIST_BONES = ("spine_01", "spine_02")
#: Where the root's rotation turns in a step: "centroid" (the posed body's centroid; the translation makes up the
#: difference) or "head" (the Root bone's head, on the floor between the feet: a few degrees of tilt about it move
#: the pelvis by centimetres, and the step's first-order rotation shrinks the body toward the floor by
#: ``angle^2 / 2`` of its height, which a second step used to take out). MIR12h; "head" is the pivot before.
ROOT_PIVOT = "centroid"
#: Every ``VERTEX_STRIDE``-th vertex enters the silhouette and depth terms.
VERTEX_STRIDE = 2
#: Rim vertices: ``|cos|`` of the (skinned) normal and the viewing ray below this.
RIM_COS = 0.3


@dataclass(frozen=True)
class RefineWeights:
    """Residual scales of the energy (a residual divided by its scale counts 1): pixels, metres, radians."""

    sil_px: float = 2.0  # silhouette residuals (E_out, E_cover)
    depth_m: float = 0.01  # point-to-plane
    joint_m: float = 0.04  # Kinect joints (tracked; inferred ones count 1/4)
    # damping of the change from the IK pose; a tight prior (0.15 rad, 5 cm) kept half the gain on MIR-SYNTH 41
    # (warp_iou 0.894 -> 0.899, 0.5 rad / 20 cm 0.906, these 0.913): the silhouette and depth know better
    prior_rad: float = 3.0  # change of a rotation from the IK
    prior_m: float = 1.0  # change of the root translation from the IK
    sil_samples: int = 600  # mask outline pixels of E_cover
    depth_samples: int = 400  # depth points of E_depth
    sil_weight: float = 1.0  # relative weights of the terms (their sums are normalised per sample)
    depth_weight: float = 1.0
    joint_weight: float = 1.0
    # E_trunk: the bend of each of TRUNK_BONES against its parent (its swing away from the rest pose), this scale
    # in radians (16 degrees; None: no such term). On MIR-SYNTH 41 / 42 / 43 it takes spine_01's swing error from
    # 6-9 to 1.5-1.8 degrees and the displacement error from 7.7 / 8.3 / 6.7 to 5.6 / 6.7 / 5.0 mm (MIR12g)
    trunk_rad: float | None = TRUNK_RAD
    # E_upright (mir12ad): the pelvis's forward / backward lean off the vertical (:func:`pelvis_lean`; a turn about the
    # vertical and a sideways tilt are free), this scale in radians; None (the default): no such term. The root's
    # rotation is the only thing in the plan that tilts the pelvis, and with E_trunk holding the spine near rest a
    # stooping person's bend went into a forward lean of the pelvis instead (52: +3 degrees), which turns the
    # shorter target's trunk and legs with it (:data:`PELVIS_TILT_RAD`). Holding the sideways tilt too measured worse
    # (52 +0.0004 against +0.0008 end to end).
    pelvis_tilt_rad: float | None = None


@dataclass(frozen=True, eq=False)
class _RefinePlan:
    """Per-body data: the vertex subset, its rest positions/normals, its skin weights and subtree weights."""

    subset: np.ndarray
    rest_vertices: np.ndarray
    rest_normals: np.ndarray
    weight_idx: np.ndarray  # (n, k) bones of the k largest skin weights
    weight_val: np.ndarray  # (n, k)
    subtree_weight: np.ndarray  # (n, 1 + S): weight on the root's subtree (1) and on each swing bone's subtree
    bones: np.ndarray  # (1 + S,) the root, then the swing bones
    joint_moves: np.ndarray  # (J, 1 + S) how much Kinect joint k moves with bone j's rotation (0..1)
    rest_relative: np.ndarray  # (B, 4, 4) A_parent^-1 A_j (the root: A_root), for the forward kinematics
    rest_inverse: np.ndarray  # (B, 4, 4) A_j^-1
    n_twist: int = 0  # the last n_twist entries of ``bones`` turn about the bone itself (its twist), one column used


def _descendants(parents, j) -> np.ndarray:
    inside = np.zeros(len(parents), bool)
    inside[j] = True
    for b in range(len(parents)):  # parents come before children
        if parents[b] >= 0 and inside[parents[b]]:
            inside[b] = True
    return inside


def refine_plan(vertices_rest: np.ndarray, faces: np.ndarray, weights: np.ndarray, skeleton: Skeleton,
                version: str = "v2", stride: int = VERTEX_STRIDE,
                swing_bones: tuple[str, ...] = SWING_BONES, twist_bones: tuple[str, ...] = ()) -> _RefinePlan:
    """The per-body data of :func:`refine_pose` (computed once per source body); ``swing_bones`` the bones
    whose swing is refined, ``twist_bones`` those whose twist (the turn about the bone) is refined too."""
    from bodystudio.geometry.mesh import vertex_normals

    names = skeleton.bone_names
    missing = [b for b in ("Root", *swing_bones, *twist_bones) if b not in names]
    if missing:
        raise InputError(f"pose refinement needs the game_engine rig; bone {missing[0]!r} is missing")
    parents = np.asarray(skeleton.parents)
    root = int(np.flatnonzero(parents < 0)[0])
    bones = np.array([root] + [names.index(b) for b in (*swing_bones, *twist_bones)])
    subset = np.arange(0, len(vertices_rest), max(1, int(stride)))
    W = np.asarray(weights, float)[subset]
    inside = np.stack([_descendants(parents, j) for j in bones], axis=1).astype(float)  # (B, 1 + S)
    subtree = W @ inside
    k = min(6, W.shape[1])
    idx = np.ascontiguousarray(np.argsort(-W, axis=1)[:, :k])
    val = np.take_along_axis(W, idx, 1)
    val = val / np.maximum(val.sum(1, keepdims=True), 1e-12)
    N = vertex_normals(np.asarray(vertices_rest, float), np.asarray(faces))[subset]
    moves = np.zeros((len(kinect_joint_names(version)), len(bones)))
    for kj, name in enumerate(kinect_joint_names(version)):
        for b_name, end, w in KINECT_JOINT_SETS[version][name]:
            b = names.index(b_name)
            for c, j in enumerate(bones):
                # a bone's tail turns with the bone and its ancestors, its head only with the ancestors
                if inside[b, c] and (end == "tail" or b != j):
                    moves[kj, c] += w
    A = skeleton.rest_frames
    rel = np.array([A[j] if p < 0 else np.linalg.solve(A[p], A[j]) for j, p in enumerate(parents)])
    return _RefinePlan(subset, np.asarray(vertices_rest, float)[subset], N, idx, val, subtree, bones, moves, rel,
                       np.linalg.inv(A), len(twist_bones))


def _forward_kinematics(plan: _RefinePlan, parents, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Posed bone frames (B, 4, 4): :func:`bodystudio.body.skinning.forward_kinematics` with the rest-frame
    products cached in the plan; and the top rows (B, 3, 4) of the skinning transforms ``M_j A_j^-1``."""
    return _posed_frames(plan.rest_relative, plan.rest_inverse, Rotation.from_rotvec(pose.rotations).as_matrix(),
                         np.asarray(pose.translation, float), np.asarray(parents, np.int64))


def _skin(plan: _RefinePlan, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skinned subset vertices and (normalised) normals by the blended LBS matrices; ``transforms`` (B, 3, 4)."""
    return blend_skin(transforms, plan.weight_idx, plan.weight_val, plan.rest_vertices, plan.rest_normals)


@njit(cache=True)
def accumulate_normal_equations(H: np.ndarray, Jtr: np.ndarray, P: np.ndarray, a: np.ndarray, s: np.ndarray,
                                heads: np.ndarray, axes: np.ndarray, residuals: np.ndarray) -> None:
    """Add ``J^T J`` to ``H`` and ``J^T r`` to ``Jtr`` for residuals ``r_i = a_i . p_i + residuals_i`` of points
    ``P`` (n, 3) along directions ``a`` (n, 3) (the Gauss-Newton step of the energy in the module docstring),
    without forming ``J``.

    A point moves by ``dt + w x (p - h_root)`` (weight ``s_0``) and ``s_j e x (p - h_j)`` for a swing about axis
    ``e`` of bone ``j``, so its row is ``s_0 a`` (translation), ``s_0 (p - h_root) x a`` (root rotation) and
    ``s_j e . ((p - h_j) x a)`` (two axes per bone); a bone whose subtree weight ``s_j(p)`` is 0 adds nothing,
    which is most of them for most points. Only the upper triangle of ``H`` is filled.
    """
    row = np.empty(H.shape[0])
    cols = np.empty(H.shape[0], np.int64)
    for i in range(P.shape[0]):
        _add_row(H, Jtr, P[i], a[i, 0], a[i, 1], a[i, 2], s[i], heads, axes, residuals[i], row, cols)


@njit(cache=True)
def _add_row(H, Jtr, p, ax, ay, az, s, heads, axes, residual, row, cols):
    """One residual's row (see :func:`accumulate_normal_equations`) added to ``H`` (upper triangle) and ``Jtr``.

    The last entries of ``heads`` may be twist entries (MIR12h: ``H`` then has one column for each, after the swing
    columns, instead of two: ``H`` is ``6 + 2 S + T`` wide for ``1 + S + T`` entries): their axis is the bone."""
    n_twist = 4 + 2 * heads.shape[0] - H.shape[0]
    first_twist = heads.shape[0] - n_twist
    k = 0
    for c in range(heads.shape[0]):
        sc = s[c]
        if sc == 0.0:
            continue
        rx, ry, rz = p[0] - heads[c, 0], p[1] - heads[c, 1], p[2] - heads[c, 2]
        cx, cy, cz = ry * az - rz * ay, rz * ax - rx * az, rx * ay - ry * ax  # (p - h) x a
        if c == 0:
            row[0], row[1], row[2] = sc * ax, sc * ay, sc * az
            row[3], row[4], row[5] = sc * cx, sc * cy, sc * cz
            for q in range(6):
                cols[q] = q
            k = 6
        elif c >= first_twist:
            e0 = axes[c - 1, 0]
            row[k] = sc * (e0[0] * cx + e0[1] * cy + e0[2] * cz)
            cols[k] = 4 + 2 * first_twist + (c - first_twist)
            k += 1
        else:
            e0 = axes[c - 1, 0]
            e1 = axes[c - 1, 1]
            row[k] = sc * (e0[0] * cx + e0[1] * cy + e0[2] * cz)
            row[k + 1] = sc * (e1[0] * cx + e1[1] * cy + e1[2] * cz)
            cols[k] = 6 + 2 * (c - 1)
            cols[k + 1] = 7 + 2 * (c - 1)
            k += 2
    for u in range(k):
        cu = cols[u]
        Jtr[cu] += row[u] * residual
        for v in range(u, k):  # cols ascend: (cols[u], cols[v]) is in the upper triangle
            H[cu, cols[v]] += row[u] * row[v]


@njit(cache=True)
def accumulate_image_normal_equations(H, Jtr, V, Pc, ids, image_dirs, residuals, fx, fy, R, s, heads, axes):
    """:func:`accumulate_normal_equations` for image residuals ``r_i = d_i . uv(p_i) + residuals_i`` of the points
    ``V[ids]`` (camera coordinates ``Pc[ids]``), ``d_i`` = ``image_dirs`` (m, 2): the direction in space is
    ``d^T (d uv / d p)``, the (undistorted) projection's derivative."""
    row = np.empty(H.shape[0])
    cols = np.empty(H.shape[0], np.int64)
    for m in range(len(ids)):
        i = ids[m]
        z = max(Pc[i, 2], 1e-6)
        gu = image_dirs[m, 0] * fx / z
        gv = image_dirs[m, 1] * fy / z
        gz = -(gu * Pc[i, 0] + gv * Pc[i, 1]) / z  # d . (d uv / d Pc) = (gu, gv, gz)
        ax = gu * R[0, 0] + gv * R[1, 0] + gz * R[2, 0]
        ay = gu * R[0, 1] + gv * R[1, 1] + gz * R[2, 1]
        az = gu * R[0, 2] + gv * R[1, 2] + gz * R[2, 2]
        _add_row(H, Jtr, V[i], ax, ay, az, s[i], heads, axes, residuals[m], row, cols)


@njit(cache=True)
def accumulate_outline_normal_equations(H, Jtr, V, N, Pc, uv, ids, targets, scale, fx, fy, R, s, heads, axes):
    """``E_cover``'s rows: outline pixel ``targets`` (m, 2) onto the projected rim points ``V[ids]`` along the
    image normal ``n2`` (their normal ``N`` projected, unit): residual ``scale n2 . (uv - target)``, added by
    :func:`accumulate_image_normal_equations`'s rule."""
    row = np.empty(H.shape[0])
    cols = np.empty(H.shape[0], np.int64)
    Du = np.empty(3)
    Dv = np.empty(3)
    for m in range(len(ids)):
        i = ids[m]
        z = max(Pc[i, 2], 1e-6)
        for c in range(3):  # rows of d uv / d p = D R
            Du[c] = fx / z * R[0, c] - fx * Pc[i, 0] / z**2 * R[2, c]
            Dv[c] = fy / z * R[1, c] - fy * Pc[i, 1] / z**2 * R[2, c]
        nu = Du[0] * N[i, 0] + Du[1] * N[i, 1] + Du[2] * N[i, 2]
        nv = Dv[0] * N[i, 0] + Dv[1] * N[i, 1] + Dv[2] * N[i, 2]
        length = max(np.sqrt(nu * nu + nv * nv), 1e-9)
        nu, nv = nu / length, nv / length
        residual = scale * (nu * (uv[i, 0] - targets[m, 0]) + nv * (uv[i, 1] - targets[m, 1]))
        _add_row(H, Jtr, V[i], scale * (nu * Du[0] + nv * Dv[0]), scale * (nu * Du[1] + nv * Dv[1]),
                 scale * (nu * Du[2] + nv * Dv[2]), s[i], heads, axes, residual, row, cols)


@njit(cache=True)
def nearest_within(points: np.ndarray, queries: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The nearest of ``points`` (n, D) to each of ``queries`` (m, D) closer than ``radius``: distances (inf where
    none) and indices (``n`` where none), as ``cKDTree(points).query(queries, distance_upper_bound=radius)`` gives
    them; by a grid of cells at least ``radius`` wide (a point that near lies in the query's cell or a
    neighbour), which costs a fraction of building the tree for the few hundred queries of a frame."""
    n, D = points.shape
    m = queries.shape[0]
    dist = np.full(m, np.inf)
    index = np.full(m, n, np.int64)
    if n == 0:
        return dist, index
    finite = np.ones(n, np.bool_)
    for i in range(n):
        for d in range(D):
            if not np.isfinite(points[i, d]):
                finite[i] = False
    if not finite.any():
        return dist, index
    lo = np.full(D, np.inf)
    hi = np.full(D, -np.inf)
    for i in range(n):
        if finite[i]:
            for d in range(D):
                lo[d] = min(lo[d], points[i, d])
                hi[d] = max(hi[d], points[i, d])
    extent = hi - lo
    cell = radius
    dims = np.empty(D, np.int64)
    while True:  # at most ~a million cells: wider cells where the points spread far
        n_cells = 1
        for d in range(D):
            dims[d] = int(extent[d] / cell) + 1
            n_cells *= dims[d]
        if n_cells <= 1 << 20:
            break
        cell *= 2.0
    cells = np.empty(n, np.int64)
    start = np.zeros(n_cells + 1, np.int64)
    for i in range(n):
        if not finite[i]:  # never anyone's nearest (kept out of every cell)
            cells[i] = -1
            continue
        c = 0
        for d in range(D):
            c = c * dims[d] + min(int((points[i, d] - lo[d]) / cell), dims[d] - 1)
        cells[i] = c
        start[c + 1] += 1
    for c in range(n_cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):  # counting sort: the points of cell c are order[start[c]:start[c + 1]], ascending
        if cells[i] >= 0:
            order[fill[cells[i]]] = i
            fill[cells[i]] += 1
    r2 = radius * radius
    coord = np.empty(D, np.int64)
    for j in range(m):
        usable = True
        for d in range(D):
            step = np.floor((queries[j, d] - lo[d]) / cell)
            if not np.abs(step) < 1e15:  # not finite, or far beyond every cell: no neighbour
                usable = False
                break
            coord[d] = int(step)
        if not usable:
            continue
        best, best_i = np.inf, n
        for t in range(3 ** D):
            c, code, inside = 0, t, True
            for d in range(D):
                k = coord[d] + code % 3 - 1
                code //= 3
                if k < 0 or k >= dims[d]:
                    inside = False
                c = c * dims[d] + k
            if not inside:
                continue
            for s in range(start[c], start[c + 1]):
                i = order[s]
                d2 = 0.0
                for d in range(D):
                    d2 += (points[i, d] - queries[j, d]) ** 2
                if d2 < best or (d2 == best and i < best_i):
                    best, best_i = d2, i
        if best < r2:
            dist[j] = np.sqrt(best)
            index[j] = best_i
    return dist, index


def _sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image at pixels (n, 2) (clamped at the border)."""
    if not len(uv):  # OpenCV cannot remap zero points
        return np.zeros(0)
    m = cv2.remap(image, uv[:, :1].astype(np.float32), uv[:, 1:].astype(np.float32), cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE)
    return m.ravel().astype(np.float64)


def mask_box(mask: np.ndarray, margin_px: int) -> tuple[int, int, int, int] | None:
    """``(y0, y1, x0, x1)``: the bounding box of ``mask`` grown by ``margin_px`` (clipped to the image); None
    for an empty mask. One numba scan of the rows (each from both ends to its first and last pixel; numpy's
    ``any(axis=1)`` over a 640x480 mask took ~0.06 ms of the ~0.15 the two ``any`` took, MIR12e)."""
    m = np.ascontiguousarray(mask, dtype=bool)
    if m.ndim != 2 or m.size == 0:
        return None
    y0, y1, x0, x1 = _box_of(m)
    if y1 < 0:
        return None
    return grown_box((y0, y1 + 1, x0, x1 + 1), margin_px, m.shape)


def grown_box(box: tuple[int, int, int, int], margin_px: int, shape) -> tuple[int, int, int, int]:
    """``box`` ``(y0, y1, x0, x1)`` grown by ``margin_px`` and clipped to an image of ``shape``."""
    y0, y1, x0, x1 = box
    return (max(y0 - margin_px, 0), min(y1 + margin_px, shape[0]), max(x0 - margin_px, 0),
            min(x1 + margin_px, shape[1]))


@njit(cache=True)
def _box_of(mask):
    """The first and last row and column holding a pixel of ``mask`` (-1s when empty)."""
    h, w = mask.shape
    y0, y1, x0, x1 = -1, -1, w, -1
    for y in range(h):
        row = mask[y]
        first = -1
        for x in range(w):
            if row[x]:
                first = x
                break
        if first < 0:
            continue
        if y0 < 0:
            y0 = y
        y1 = y
        x0 = min(x0, first)
        for x in range(w - 1, first - 1, -1):
            if row[x]:
                x1 = max(x1, x)
                break
    return y0, y1, x0, x1


#: Margin (px) of the distance transform's window around the projected body (:func:`_distance_near_the_body`).
NEAR_BODY_PX = 24


def _distance_near_the_body(dist_out: np.ndarray, allowed: np.ndarray, box, silhouette, points: np.ndarray,
                            done) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """:func:`_distance_where_needed` on the mask's box clipped to the body's points grown by
    :data:`NEAR_BODY_PX` (two actors: the other player's side of the allowed mask is left out, MIR12e), and the
    distances sampled at ``points``. The window's values are the whole box's where the nearest mask pixel lies in
    the window, which holds wherever a sample's distance is below its distance to a window side beyond which
    the mask has pixels (a chamfer distance is at least the L-infinity one); :func:`_window_is_exact` checks it
    with slack for the bilinear neighbours and the central differences, and the window is grown to the mask's
    whole box when a sample fails (then :func:`_distance_where_needed`'s window, the same values)."""
    near = silhouette
    if done is None and len(points):
        lo = np.floor(points.min(0)).astype(int) - NEAR_BODY_PX
        hi = np.floor(points.max(0)).astype(int) + NEAR_BODY_PX + 1
        clipped = (max(silhouette[0], box[0] + lo[1]), min(silhouette[1], box[0] + hi[1]),
                   max(silhouette[2], box[2] + lo[0]), min(silhouette[3], box[2] + hi[0]))
        if clipped[0] < clipped[1] and clipped[2] < clipped[3]:
            near = clipped
    done = _distance_where_needed(dist_out, allowed, box, near, points, done)
    d = _sample(dist_out, points)
    if near is not silhouette and not _window_is_exact(done, box, silhouette, points, d):
        done = _distance_where_needed(dist_out, allowed, box, silhouette, points, done)
        d = _sample(dist_out, points)
    return done, d


def _window_is_exact(window, box, silhouette, points: np.ndarray, d: np.ndarray) -> bool:
    """Whether every sample (box pixels ``points``, distances ``d``) and its neighbours read by the bilinear
    sample and the central differences (+-1 px) are nearer to the mask than to any side of ``window`` (box
    pixels) beyond which the mask (its box ``silhouette``, image pixels) has pixels."""
    if not len(points):
        return True
    wy0, wy1, wx0, wx1 = window
    sy0, sy1, sx0, sx1 = (silhouette[0] - box[0], silhouette[1] - box[0], silhouette[2] - box[2],
                          silhouette[3] - box[2])
    margin = np.full(len(points), np.inf)
    if wx0 > sx0:
        margin = np.minimum(margin, points[:, 0] - wx0)
    if wx1 < sx1:
        margin = np.minimum(margin, wx1 - 1 - points[:, 0])
    if wy0 > sy0:
        margin = np.minimum(margin, points[:, 1] - wy0)
    if wy1 < sy1:
        margin = np.minimum(margin, wy1 - 1 - points[:, 1])
    return bool(np.all(d + 6.0 <= margin))


def silhouette_distance(mask: np.ndarray, margin_px: int = 40,
                        box: tuple[int, int, int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Distance (pixels, float32) outside ``mask`` to it, 0 inside: the data of ``E_out``, over the mask's
    bounding box grown by ``margin_px`` only (a 640x480 transform costs ~2 ms); returns it and the box's
    ``(x0, y0)`` origin. ``box``: that box when the caller has it (:func:`mask_box`)."""
    m = np.asarray(mask, bool)
    box = mask_box(m, margin_px) if box is None else box
    if box is None:
        return np.full((1, 1), np.float32(margin_px)), np.zeros(2)
    y0, y1, x0, x1 = box
    crop = (~m[y0:y1, x0:x1]).astype(np.uint8)
    return cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_5), np.array([x0, y0], float)


def _distance_where_needed(dist_out: np.ndarray, allowed: np.ndarray, box, silhouette, points: np.ndarray,
                           done: tuple[int, int, int, int] | None) -> tuple[int, int, int, int]:
    """Fill ``dist_out`` (the distance transform over ``box``, :func:`silhouette_distance`) in the window that the
    samples at ``points`` (box pixels) and their central differences read: the mask's own box (``silhouette``)
    grown to hold them. A chamfer distance path to the nearest mask pixel stays in the box spanned by the two, so
    the window's values are the whole box's (to float32 rounding, ~4e-6 px) at a fraction of its area (the 40 px
    margin is mostly empty). ``done``: the window filled so far (nothing is recomputed while it holds the points).
    Returns the window ``(y0, y1, x0, x1)`` in box pixels."""
    by0, by1, bx0, bx1 = box
    h, w = by1 - by0, bx1 - bx0
    y0, y1, x0, x1 = silhouette[0] - by0, silhouette[1] - by0, silhouette[2] - bx0, silhouette[3] - bx0
    if len(points):
        lo, hi = np.floor(points.min(0)).astype(int), np.floor(points.max(0)).astype(int)
        x0, x1 = min(x0, lo[0] - 3), max(x1, hi[0] + 5)
        y0, y1 = min(y0, lo[1] - 3), max(y1, hi[1] + 5)
    window = (max(y0, 0), min(y1, h), max(x0, 0), min(x1, w))
    if done is not None and done[0] <= window[0] and done[1] >= window[1] and done[2] <= window[2] \
            and done[3] >= window[3]:
        return done
    if done is not None:  # a later step's body reaches farther: one window holding both
        window = (min(window[0], done[0]), max(window[1], done[1]), min(window[2], done[2]), max(window[3], done[3]))
    y0, y1, x0, x1 = window
    crop = (~allowed[by0 + y0:by0 + y1, bx0 + x0:bx0 + x1]).astype(np.uint8)
    dist_out[y0:y1, x0:x1] = cv2.distanceTransform(crop, cv2.DIST_L2, cv2.DIST_MASK_5)
    return window


def mask_outline(mask: np.ndarray, keep_out: np.ndarray | None = None,
                 box: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """(m, 2) pixel centres ``(x, y)`` of the outline of ``mask`` (inside pixels with an outside 8-neighbour),
    without those within 2 px of ``keep_out`` (another player occluding the person) or on the image border, in
    row-major order. ``box`` (:func:`mask_box`, a margin of at least 3 px around ``mask | keep_out``) limits the
    work to it: the same pixels, since nothing outside it can touch the outline (a box edge inside the image is
    empty)."""
    m = np.asarray(mask, bool)
    y0, y1, x0, x1 = (0, m.shape[0], 0, m.shape[1]) if box is None else box
    k = np.zeros((1, 1), bool) if keep_out is None else np.asarray(keep_out, bool)[y0:y1, x0:x1]
    ys, xs = _outline_pixels(m[y0:y1, x0:x1], k, bool(k.any()))
    return np.c_[xs + x0, ys + y0].astype(np.float64)


@njit(cache=True)
def _outline_pixels(mask, keep_out, has_keep_out):
    """Rows and columns of the inside pixels of ``mask`` with an outside 8-neighbour (the pixels a 3x3 erosion
    removes), none on its border, none within 2 px (5x5) of a ``keep_out`` pixel."""
    h, w = mask.shape
    ys = np.empty(h * w, np.int64)
    xs = np.empty(h * w, np.int64)
    n = 0
    for y in range(1, h - 1):
        for x in range(1, w - 1):
            if not mask[y, x]:
                continue
            if (mask[y - 1, x - 1] and mask[y - 1, x] and mask[y - 1, x + 1] and mask[y, x - 1] and mask[y, x + 1]
                    and mask[y + 1, x - 1] and mask[y + 1, x] and mask[y + 1, x + 1]):
                continue
            if has_keep_out and _any_in_window(keep_out, y - 2, y + 3, x - 2, x + 3):
                continue
            ys[n] = y
            xs[n] = x
            n += 1
    return ys[:n], xs[:n]


@njit(cache=True)
def _any_in_window(image, y0, y1, x0, x1):
    for y in range(max(y0, 0), min(y1, image.shape[0])):
        for x in range(max(x0, 0), min(x1, image.shape[1])):
            if image[y, x]:
                return True
    return False


def trunk_bends(M: np.ndarray, world: np.ndarray, rest_rotations: np.ndarray, parents, bones: np.ndarray,
                axes: np.ndarray, posture: np.ndarray | None = None) -> np.ndarray:
    """(n, 2) the bend of each of ``bones`` against its parent, as the components on its two swing ``axes``
    (n, 2, 3) of the rotation vector taking the bone's rest direction (turned with its parent) onto its posed one;
    ``M`` the posed frames, ``world`` the world rotations (:func:`_bone_frames`). ``posture`` (B, 3): each bone's
    direction in its parent's frame (rest-world axes, :func:`posture_directions`) to bend from instead of the rest
    direction (a subject's static stoop or nod).

    A swing ``delta`` about ``e_k`` of bone ``j`` turns its direction about ``e_k`` and leaves its parent alone, so
    the bend becomes ``bend_k + delta_k`` to first order: the residual of E_trunk, ``(bend_k + delta_k) / s``.
    """
    d = M[bones, :3, 1]
    centre = rest_rotations[bones][:, :, 1] if posture is None else posture[bones]
    q = np.einsum("nij,nj->ni", world[np.asarray(parents)[bones]], centre)
    n = np.cross(q, d)
    s = np.linalg.norm(n, axis=1)
    angle = np.arctan2(s, np.einsum("ij,ij->i", q, d))
    b = n * (angle / np.maximum(s, 1e-12))[:, None]
    return np.einsum("nkj,nj->nk", axes, b)


def pelvis_tilt(world_rotation: np.ndarray, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """(3,) the tilt of a bone's world rotation (rest-world to posed-world axes) off the vertical: the rotation
    vector (world axes, perpendicular to ``up``) of the smallest turn taking ``up`` onto ``world_rotation @ up``,
    i.e. the swing of the swing-twist split about ``up``; a turn about ``up`` alone gives 0. A world turn ``w`` about
    an axis perpendicular to ``up`` adds ``w`` to it to first order (E_upright's residual, mir12ad)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    d = np.asarray(world_rotation, dtype=np.float64) @ u
    n = np.cross(u, d)
    s = np.linalg.norm(n)
    return n * (np.arctan2(s, float(u @ d)) / max(s, 1e-12))


def pelvis_lean(world_rotation: np.ndarray, up=(0.0, 1.0, 0.0), lateral=(1.0, 0.0, 0.0)) -> tuple[float, np.ndarray]:
    """The forward / backward lean of a bone's world rotation: the component of its tilt (:func:`pelvis_tilt`) about
    its own ``lateral`` axis (rest-world, the body's left) turned into the world and laid horizontal, and that unit
    axis (world). A sideways tilt and a turn about ``up`` give 0 (mir12ad's E_upright)."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    a = np.asarray(world_rotation, dtype=np.float64) @ np.asarray(lateral, dtype=np.float64)
    a = a - (a @ u) * u
    a = a / max(np.linalg.norm(a), 1e-12)
    return float(a @ pelvis_tilt(world_rotation, up)), a


def posture_directions(skeleton: Skeleton, pose: Pose) -> np.ndarray:
    """(B, 3) each bone's posed direction in its parent's frame, in rest-world axes (``W_p^T d_j``; the root: its
    rest direction): what :func:`trunk_bends` bends from, averaged over frames a subject's static posture."""
    from bodystudio.body.skinning import forward_kinematics

    G = forward_kinematics(skeleton, pose)[:, :3, :3]
    world = G @ np.transpose(skeleton.rest_rotations, (0, 2, 1))
    parents = np.asarray(skeleton.parents)
    out = skeleton.rest_rotations[:, :, 1].copy()
    child = parents >= 0
    out[child] = np.einsum("nji,nj->ni", world[parents[child]], G[child][:, :, 1])
    return out


def updated_posture(posture: np.ndarray | None, skeleton: Skeleton, pose: Pose, frames: int, window: int,
                    bones=None) -> np.ndarray:
    """E_trunk's centre (:func:`trunk_bends`' ``posture``) after one more frame's ``pose``: for ``bones`` (names;
    None: all) the running mean of :func:`posture_directions` (``frames`` seen so far, this one included; an
    exponential mean of ``window`` frames once there are more), every other bone its rest direction.

    Its fixed point is the mean bend that the data terms alone would give: a prior held at that centre no longer
    shrinks a subject's static stoop or nod towards the rest pose, as one held at the rest pose does."""
    d = posture_directions(skeleton, pose)
    rest = skeleton.rest_rotations[:, :, 1]
    if posture is not None:
        rate = 1.0 / min(max(int(frames), 1), max(int(window), 1))
        d = (1.0 - rate) * posture + rate * d
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
    if bones is not None:
        keep = ~np.isin(np.asarray(skeleton.bone_names), list(bones))
        d[keep] = rest[keep]
    return d


def apply_update(skeleton: Skeleton, pose: Pose, delta: np.ndarray, bones: np.ndarray, axes: np.ndarray,
                 world: np.ndarray) -> Pose:
    """The pose turned by ``delta`` (root translation, root rotation vector in world axes, two swing angles per
    bone about ``axes``); ``world`` (B, 3, 3) the pose's world rotations (rest-world to posed-world)."""
    rotvecs = pose.rotations.copy()
    rotvecs[bones] = _turned_rotations(np.ascontiguousarray(skeleton.rest_rotations[bones]),
                                       np.asarray(skeleton.parents, np.int64)[bones], np.asarray(delta, float),
                                       np.ascontiguousarray(axes), np.ascontiguousarray(world), bones)
    return Pose(rotvecs, pose.translation + delta[:3])


@njit(cache=True)
def _turned_rotations(rest_rotations, parents, delta, axes, world, bones):
    """The local rotation vectors of ``bones`` after the turns of :func:`apply_update`:
    ``W_j' = W_p' L_j'`` with ``L_j' = W_p^T exp(w) W_j`` (first order the same turn of j's subtree in world axes),
    in the rest frame: ``log(Rr^T L_j' Rr)``."""
    n = len(bones)
    out = np.empty((n, 3))
    turns = np.empty((n, 3))
    for b in range(n):
        if b == 0:
            turns[b] = delta[3:6]
        else:
            turns[b] = delta[6 + 2 * (b - 1)] * axes[b - 1, 0] + delta[7 + 2 * (b - 1)] * axes[b - 1, 1]
    turn = np.empty(3)
    for b in range(n):
        turn[:] = turns[b]
        for c in range(n):  # a bone listed twice (its swing and its twist) turns by both
            if c != b and bones[c] == bones[b]:
                turn += turns[c]
        L = _rotation_matrix(turn) @ world[bones[b]]
        if parents[b] >= 0:
            L = world[parents[b]].T @ L
        out[b] = _rotation_vector(rest_rotations[b].T @ L @ rest_rotations[b])
    return out


@njit(cache=True)
def _rotation_matrix(rotvec):
    """The rotation matrix of a rotation vector through its unit quaternion (as scipy's ``from_rotvec``)."""
    angle = np.sqrt(rotvec[0] ** 2 + rotvec[1] ** 2 + rotvec[2] ** 2)
    if angle <= 1e-3:
        scale = 0.5 - angle**2 / 48 + angle**4 / 3840
    else:
        scale = np.sin(angle / 2) / angle
    x, y, z, w = scale * rotvec[0], scale * rotvec[1], scale * rotvec[2], np.cos(angle / 2)
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = x * x - y * y - z * z + w * w, 2 * (x * y - z * w), 2 * (x * z + y * w)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + z * w), -x * x + y * y - z * z + w * w, 2 * (y * z - x * w)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - y * w), 2 * (y * z + x * w), -x * x - y * y + z * z + w * w
    return R


@njit(cache=True)
def _rotation_vector(R):
    """The rotation vector of a rotation matrix through its unit quaternion (as scipy's ``from_matrix``, then
    ``as_rotvec``: the largest of the trace and the diagonal picks the stable formula)."""
    q = np.empty(4)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    i = 0
    for k in range(1, 3):
        if R[k, k] > R[i, i]:
            i = k
    if trace > R[i, i]:
        q[3] = 1 + trace
        q[0], q[1], q[2] = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1 - trace + 2 * R[i, i]
        q[j] = R[j, i] + R[i, j]
        q[k] = R[k, i] + R[i, k]
        q[3] = R[k, j] - R[j, k]
    q /= np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    if q[3] < 0:
        q = -q
    norm = np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2)
    angle = 2 * np.arctan2(norm, q[3])
    if angle <= 1e-3:
        scale = 2 + angle**2 / 12 + 7 * angle**4 / 2880
    else:
        scale = angle / np.sin(angle / 2)
    return scale * q[:3]


@njit(cache=True)
def _project_body(V, N, R, t, K, lens, has_distortion, eye, width, height, origin, dist_shape, rim_cos):
    """One pass over the skinned points: camera coordinates ``Pc`` (n, 3), pixels ``uv`` (n, 2; NaN behind the
    camera; :meth:`Camera.project_with_depth`'s formulas with OpenCV's distortion), pixels in the distance window
    ``local = uv - origin``, whether each lies inside the window (1 px in, 2 px off its far sides) and in the
    image, whether it is on the rim (in the image, ``|cos| < rim_cos``) and the cosine of its normal ``N`` with
    the viewing ray from ``eye``. MIR12h: numpy's ten passes over the arrays cost ~0.4 ms more a step (A/B in one
    process on MIR-SYNTH 41)."""
    n = V.shape[0]
    Pc = np.empty((n, 3))
    uv = np.empty((n, 2))
    local = np.empty((n, 2))
    in_box = np.zeros(n, np.bool_)
    rim = np.zeros(n, np.bool_)
    cos = np.empty(n)
    k1, k2, p1, p2, k3 = lens[0], lens[1], lens[2], lens[3], lens[4]
    for i in range(n):
        for r in range(3):
            Pc[i, r] = V[i, 0] * R[r, 0] + V[i, 1] * R[r, 1] + V[i, 2] * R[r, 2] + t[r]
        z = Pc[i, 2]
        if z <= 0:
            x = y = np.nan
        else:
            x = Pc[i, 0] / z
            y = Pc[i, 1] / z
        if has_distortion:
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            y = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = xd
        u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
        v = K[1, 1] * y + K[1, 2]
        uv[i, 0] = u
        uv[i, 1] = v
        lu = u - origin[0]
        lv = v - origin[1]
        local[i, 0] = lu
        local[i, 1] = lv
        ok = u >= 0 and u <= width - 1 and v >= 0 and v <= height - 1  # False for NaN
        in_box[i] = ok and lu >= 1 and lv >= 1 and lu < dist_shape[0] - 2 and lv < dist_shape[1] - 2
        rx, ry, rz = V[i, 0] - eye[0], V[i, 1] - eye[1], V[i, 2] - eye[2]
        cos[i] = (N[i, 0] * rx + N[i, 1] * ry + N[i, 2] * rz) / np.sqrt(rx * rx + ry * ry + rz * rz)
        rim[i] = ok and abs(cos[i]) < rim_cos
    return Pc, uv, local, in_box, rim, cos


#: The pixel steps of the distance transform's central differences: +x, -x, +y, -y.
_STEPS_PX = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


@njit(cache=True)
def _bone_frames(M, rest_rotations, bones):
    """From the posed frames ``M`` (B, 4, 4): the world rotations ``M_j R_rest_j^T`` (B, 3, 3), the heads of
    ``bones`` (root first) and two unit axes perpendicular to each swing bone's direction (S, 2, 3)."""
    world = np.empty((len(M), 3, 3))
    for j in range(len(M)):
        for r in range(3):
            for c in range(3):
                world[j, r, c] = M[j, r, 0] * rest_rotations[j, c, 0] + M[j, r, 1] * rest_rotations[j, c, 1] \
                    + M[j, r, 2] * rest_rotations[j, c, 2]
    heads = np.empty((len(bones), 3))
    for b in range(len(bones)):
        heads[b] = M[bones[b], :3, 3]
    axes = np.empty((len(bones) - 1, 2, 3))
    for b in range(1, len(bones)):
        d = M[bones[b], :3, 1]
        h = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        a = np.array([d[1] * h[2] - d[2] * h[1], d[2] * h[0] - d[0] * h[2], d[0] * h[1] - d[1] * h[0]])
        a /= np.sqrt(a[0] ** 2 + a[1] ** 2 + a[2] ** 2)
        axes[b - 1, 0] = a
        axes[b - 1, 1] = np.array([d[1] * a[2] - d[2] * a[1], d[2] * a[0] - d[0] * a[2], d[0] * a[1] - d[1] * a[0]])
    return world, heads, axes


_BLAS = None


def _one_blas_thread():
    """A context holding BLAS to one thread: MIR12b's normal equations (``J^T J`` of a few thousand rows by ~44
    columns) crossed OpenBLAS's threading threshold, and its threads spinning on a loaded machine made the step
    cost 150-300 ms wall instead of ~10 (mirror run on MIR-SYNTH, load 30). ``J^T J`` is now accumulated in numba
    and what is left for BLAS is small, but the context costs ~0.01 ms and keeps any of it off the pool."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def refine_pose(plan: _RefinePlan, skeleton: Skeleton, pose: Pose, camera, foreground: np.ndarray,
                kinect_positions=None, tracked=None, depth_points=None, others: np.ndarray | None = None,
                version: str = "v2", iterations: int = ITERATIONS,
                weights: RefineWeights = RefineWeights(), posture: np.ndarray | None = None) -> Pose:
    """The IK ``pose`` refined by Gauss-Newton so that the projected body fits ``foreground`` (the person's
    refined mask in the colour image of ``camera``), the player's ``depth_points`` (N, 3) and the Kinect joints.

    ``others``: pixels of other players (a body point projecting there may be occluded, not outside).
    Root translation/rotation and the swing of the plan's bones (:data:`SWING_BONES` by default) change, and the
    twist of its twist bones (none by default; the run's plan :data:`TWIST_BONES`); every other rotation, and every
    other twist, is the IK's. ``iterations`` Gauss-Newton steps from ``pose``. ``posture`` (B, 3): where E_trunk
    holds each trunk bone (its direction in the parent's frame, :func:`posture_directions`); None: the rest pose.
    """
    tilt = weights.pelvis_tilt_rad
    if tilt is not None and (isinstance(tilt, bool) or not isinstance(tilt, (int, float, np.integer, np.floating))
                             or not (np.isfinite(tilt) and tilt > 0)):
        raise InputError(f"refine_pose: pelvis_tilt_rad must be a positive number of radians (the pelvis tilt that "
                         f"counts as one) or None for no such term, got {tilt!r}")
    if posture is not None and np.shape(posture) != (skeleton.n_bones, 3):
        raise InputError(f"refine_pose: posture of shape {np.shape(posture)}; give one direction per bone, "
                         f"({skeleton.n_bones}, 3) (refine.posture_directions), or None for the rest pose")
    with _one_blas_thread():
        return _refine_pose(plan, skeleton, pose, camera, foreground, kinect_positions, tracked, depth_points,
                            others, version, iterations, weights, posture)


def _refine_pose(plan, skeleton, pose, camera, foreground, kinect_positions, tracked, depth_points, others,
                 version, iterations, weights, posture=None) -> Pose:
    fg = np.asarray(foreground, bool)
    if fg.shape != (camera.height, camera.width):
        raise InputError(f"refine_pose: foreground {fg.shape} is not the camera's ({camera.height}, {camera.width})")
    allowed = fg if others is None else fg | others
    silhouette = mask_box(allowed, 0)
    box = None if silhouette is None else grown_box(silhouette, 40, allowed.shape)
    if box is None:
        dist_out, origin = silhouette_distance(allowed, 40, None)
        dist_shape = np.array(dist_out.shape[::-1])
    else:  # the transform over the box, computed where the body projects (see _distance_where_needed)
        origin = np.array([box[2], box[0]], float)
        dist_shape = np.array([box[3] - box[2], box[1] - box[0]])
        dist_out = np.empty((dist_shape[1], dist_shape[0]), np.float32)
        done = None
    outline = mask_outline(fg, others, box) if box is not None else np.zeros((0, 2))
    rng = np.random.default_rng(0)
    if len(outline) > weights.sil_samples:
        outline = outline[rng.choice(len(outline), weights.sil_samples, replace=False)]
    K = T = None
    if kinect_positions is not None:
        from bodystudio.mirror.track import check_kinect_joints

        K, T = check_kinect_joints(kinect_positions, tracked, version)
        jw = np.where(np.all(np.isfinite(K), axis=1), np.where(T, 1.0, 0.25), 0.0)
        K = np.nan_to_num(K)
    pts = None
    if depth_points is not None and len(depth_points):
        pts = np.asarray(depth_points, float)
        if len(pts) > weights.depth_samples:
            pts = pts[rng.choice(len(pts), weights.depth_samples, replace=False)]
    bones = plan.bones
    S = len(bones) - 1
    n_swing = S - plan.n_twist
    n_par = 6 + 2 * n_swing + plan.n_twist  # a twist entry has one column (MIR12h)
    prior_scale = np.r_[np.full(3, weights.prior_m), np.full(n_par - 3, weights.prior_rad)]
    start = pose
    total = np.zeros(n_par)
    eye = camera.center
    lens = np.asarray(camera.dist, np.float64) if camera.has_distortion else np.zeros(5)
    parents = skeleton.parents
    rest_rotations = np.ascontiguousarray(skeleton.rest_rotations)
    trunk = None
    if weights.trunk_rad is not None:  # positions among the swing bones
        names = [skeleton.bone_names[b] for b in bones[1:]]
        trunk = np.array([names.index(n) for n in TRUNK_BONES if n in names], int)
    pelvis = skeleton.bone_names.index("pelvis") if weights.pelvis_tilt_rad is not None \
        and "pelvis" in skeleton.bone_names else None
    for _ in range(max(0, int(iterations))):
        M, transforms = _forward_kinematics(plan, parents, pose)
        world, heads, axes = _bone_frames(M, rest_rotations, bones)
        for k in range(len(bones) - 1 - plan.n_twist, len(bones) - 1):  # twist entries: about the bone, one column
            axes[k, 0] = M[bones[k + 1], :3, 1]
            axes[k, 1] = 0.0
        V, N = _skin(plan, transforms)
        root_head = heads[0].copy()
        if ROOT_PIVOT == "centroid":  # the root's rotation turns about the body's centroid (the kernels' heads[0])
            heads[0] = V.mean(axis=0)
        Pc, uv, local, in_box_mask, rim_mask, cos = _project_body(
            V, N, camera.R, camera.t, camera.K, lens, camera.has_distortion, eye, camera.width, camera.height,
            origin, dist_shape.astype(np.float64), RIM_COS)
        H = np.zeros((n_par, n_par))
        Jtr = np.zeros(n_par)
        used = False
        # E_out: projected body points outside the silhouette, pulled down the distance transform
        # (points beyond the box are more than its margin out; they have no gradient there and are left out)
        in_box = np.flatnonzero(in_box_mask)
        if box is not None:
            done, d_in = _distance_near_the_body(dist_out, allowed, box, silhouette, local[in_box], done)
        else:
            d_in = _sample(dist_out, local[in_box])
        outside = d_in > 0.5
        out = in_box[outside]
        if len(out):
            lo = local[out]
            around = _sample(dist_out, (lo[None] + _STEPS_PX[:, None]).reshape(-1, 2)).reshape(4, -1)
            g = np.c_[around[0] - around[1], around[2] - around[3]] / 2.0  # central differences
            scale = weights.sil_weight ** 0.5 / (weights.sil_px * max(len(out), len(outline), 1) ** 0.5)
            accumulate_image_normal_equations(H, Jtr, V, Pc, out, scale * g, scale * np.minimum(d_in[outside], 30.0),
                                              camera.fx, camera.fy, camera.R, plan.subtree_weight, heads, axes)
            used = True
        # E_cover: the mask's outline pixels onto the nearest projected rim vertex, along its image normal
        rim = np.flatnonzero(rim_mask)
        if len(rim) >= 3 and len(outline):
            dist, nearest = nearest_within(uv[rim], outline, 25.0)
            keep = np.isfinite(dist)
            scale = weights.sil_weight ** 0.5 / (weights.sil_px * max(len(outline), 1) ** 0.5)
            accumulate_outline_normal_equations(H, Jtr, V, N, Pc, uv, rim[nearest[keep]], outline[keep], scale,
                                                camera.fx, camera.fy, camera.R, plan.subtree_weight, heads, axes)
            used = True
        # E_depth: point-to-plane to the nearest front-facing vertex (within 5 cm)
        if pts is not None:
            front = np.flatnonzero(cos < 0)
            dist, nearest = nearest_within(V[front], pts, 0.05)
            keep = np.isfinite(dist)
            if keep.any():
                v_ids = front[nearest[keep]]
                n3 = N[v_ids]
                r = np.einsum("ij,ij->i", n3, V[v_ids] - pts[keep])
                scale = weights.depth_weight ** 0.5 / (weights.depth_m * len(pts) ** 0.5)
                accumulate_normal_equations(H, Jtr, V[v_ids], scale * n3, plan.subtree_weight[v_ids], heads, axes,
                                            scale * r)
                used = True
        # E_joint: the Kinect joints as soft targets (three residuals each, along the world axes)
        if K is not None and jw.any():
            from bodystudio.body.kinect import kinect_joints

            heads_all = M[:, :3, 3]
            tails_all = heads_all + M[:, :3, 1] * skeleton.lengths[:, None]
            P = kinect_joints(skeleton, heads_all, tails_all, version)
            use = np.flatnonzero(jw > 0)
            scale = (weights.joint_weight * jw[use] / jw[use].sum()) ** 0.5 / weights.joint_m
            accumulate_normal_equations(H, Jtr, np.repeat(P[use], 3, axis=0),
                                        (scale[:, None, None] * np.eye(3)).reshape(-1, 3),
                                        np.repeat(plan.joint_moves[use], 3, axis=0), heads, axes,
                                        (scale[:, None] * (P[use] - K[use])).ravel())
            used = True
        if not used:
            break
        # E_prior on the total change from the IK pose (``total``): (total + delta) / scale
        H = np.triu(H) + np.triu(H, 1).T
        H[np.diag_indices(n_par)] += 1.0 / prior_scale**2
        grad = Jtr + total / prior_scale**2
        if trunk is not None:  # E_trunk: each trunk bone's bend (its swing off the rest pose) plus its own swing
            bend = trunk_bends(M, world, rest_rotations, parents, bones[1 + trunk], axes[trunk], posture)
            cols = (6 + 2 * trunk[:, None] + np.arange(2)).ravel()
            H[cols, cols] += 1.0 / weights.trunk_rad**2
            grad[cols] += bend.ravel() / weights.trunk_rad**2
        if pelvis is not None:  # E_upright: the root's world turn about the lateral axis leans the pelvis 1:1
            lean, axis = pelvis_lean(world[pelvis])
            H[3:6, 3:6] += np.outer(axis, axis) / weights.pelvis_tilt_rad**2
            grad[3:6] += axis * lean / weights.pelvis_tilt_rad**2
        try:
            delta = -np.linalg.solve(H, grad)
        except np.linalg.LinAlgError:
            return start
        total = total + delta
        if plan.n_twist:  # apply_update's layout: two columns per entry (a twist entry's second axis is 0)
            delta = np.r_[delta[:6 + 2 * n_swing], np.c_[delta[6 + 2 * n_swing:], np.zeros(plan.n_twist)].ravel()]
        pose = apply_update(skeleton, pose, delta, bones, axes, world)
        if ROOT_PIVOT == "centroid":  # v -> R (v - c) + c + dt moves the root head h by (R - I)(h - c) + dt
            pose = Pose(pose.rotations, pose.translation + (_rotation_matrix(delta[3:6]) - np.eye(3))
                        @ (root_head - heads[0]))
    return pose if np.all(np.isfinite(pose.rotations)) else start
