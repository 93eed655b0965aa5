"""Semantic body attributes measured on a mesh in our topology (issue 2 §4).

The attributes are those the statistical body models of Real-time Reshaping of Humans §5.1 and Avatar
Reshaping §5.1 edit along (height, weight, chest/waist/hip girth, limb lengths, muscularity), measured
the way a tailor or an anthropometric survey (ISO 8559-1) would, on the rest pose:

* ``stature_m``: floor (lowest vertex) to the top of the head.
* ``mass_kg``: enclosed volume x 1010 kg/m^3 (average body density). Boundary loops, if the mesh has
  any, are fan-filled first so the divergence-theorem volume is that of a closed surface.
* ``chest_m``, ``waist_m``, ``hip_m``: horizontal planar cross-sections. Of each section's closed
  curves the torso's is the one with the largest bounding box (arms and hands give separate, smaller
  curves); the girth is the perimeter of that curve's convex hull, which is what a tape measure laid
  around the body reads (it spans the hollow between the breasts and the small of the back).
  Chest: at bust-point height. Waist: the narrowest torso section in a band between crotch and bust
  (natural waist). Hip: the widest section between crotch and waist band (buttock prominence).
* ``arm_length_m``: acromion (shoulder tip) over the elbow point to the wrist (ulnar side), the tape
  path of ISO 8559 "arm length"; mean of left and right.
* ``leg_length_m``: crotch height above the floor (ISO "inside leg length").
* ``muscularity``: MakeHuman's macro ``muscle`` value when the phenotype is known (not measurable).

Landmarks are vertex indices of the full hm08 body found once by geometric rules on the default body
(:func:`landmark_vertices`), so they follow every shape change; on the 6k and 2k templates each
landmark is the template vertex nearest to it on the default body.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.spatial import ConvexHull

from bodystudio.errors import InputError

BODY_DENSITY_KG_M3 = 1010.0
ATTRIBUTE_NAMES = ("stature_m", "mass_kg", "chest_m", "waist_m", "hip_m", "arm_length_m", "leg_length_m",
                   "muscularity")
MESH_ATTRIBUTE_NAMES = ATTRIBUTE_NAMES[:-1]
# Fractions of the crotch -> bust-point height span searched for the waist (minimum girth) and the hips
# (maximum girth); the bands keep clear of the ribcage above and the thigh split below.
WAIST_BAND = (0.45, 0.85)
HIP_BAND = (0.05, 0.45)
N_BAND_LEVELS = 9


@dataclass(frozen=True)
class Landmarks:
    """Landmark vertex indices of one template (``_l`` at +x; right side via the mirror map)."""

    crotch: int
    bust: tuple[int, int]
    acromion: tuple[int, int]
    elbow: tuple[int, int]
    wrist: tuple[int, int]


@lru_cache(maxsize=1)
def _full_landmarks() -> Landmarks:
    from bodystudio.body.makehuman import load_base
    from bodystudio.body.model import build_body

    body = build_body(resolution="full")
    V, S = body.vertices, body.skeleton
    mirror = load_base().mirror[: len(V)]
    midline = np.flatnonzero(np.abs(V[:, 0]) < 1e-4)
    crotch = int(midline[np.argmin(V[midline, 1])])
    shoulder = S.heads[S.index("upperarm_l")]
    elbow_joint = S.heads[S.index("lowerarm_l")]
    wrist_joint = S.heads[S.index("hand_l")]
    # Bust point: most forward torso vertex on the left between 5 and 25 cm below the shoulder joint.
    chest = np.flatnonzero((V[:, 0] > 0.02) & (V[:, 0] < 0.8 * shoulder[0])
                           & (V[:, 1] > shoulder[1] - 0.25) & (V[:, 1] < shoulder[1] - 0.05))
    bust = int(chest[np.argmax(V[chest, 2])])
    # Acromion: the surface point straight above the shoulder joint.
    horizontal = np.linalg.norm((V - shoulder)[:, [0, 2]], axis=1)
    above = np.flatnonzero(V[:, 1] > shoulder[1])
    acromion = int(above[np.argmin(horizontal[above])])
    # Elbow point: the most posterior vertex within 6 cm of the elbow joint (the olecranon).
    near = np.flatnonzero(np.linalg.norm(V - elbow_joint, axis=1) < 0.06)
    elbow = int(near[np.argmin(V[near, 2])])
    # Wrist (ulnar side): most posterior vertex of the ring through the wrist joint across the forearm.
    forearm = (wrist_joint - elbow_joint) / np.linalg.norm(wrist_joint - elbow_joint)
    ring = np.flatnonzero((np.abs((V - wrist_joint) @ forearm) < 0.01)
                          & (np.linalg.norm(V - wrist_joint, axis=1) < 0.06))
    wrist = int(ring[np.argmin(V[ring, 2])])
    return Landmarks(crotch, *((int(i), int(mirror[i])) for i in (bust, acromion, elbow, wrist)))


def landmark_vertices(vertex_ids: np.ndarray | None = None) -> Landmarks:
    """Landmarks of the full body, or of a template keeping the full-body vertices ``vertex_ids``.

    A landmark not kept by the template moves to the kept vertex nearest to it on the default body.
    """
    full = _full_landmarks()
    if vertex_ids is None:
        return full
    ids = np.ascontiguousarray(vertex_ids, dtype=np.int64)
    key = ids.tobytes()
    if key not in _TEMPLATE_LANDMARKS:
        _TEMPLATE_LANDMARKS[key] = _template_landmarks(ids)
    return _TEMPLATE_LANDMARKS[key]


_TEMPLATE_LANDMARKS: dict[bytes, Landmarks] = {}


def _template_landmarks(ids: np.ndarray) -> Landmarks:
    from scipy.spatial import cKDTree

    from bodystudio.body.model import shaped_vertices

    full = _full_landmarks()
    tree = cKDTree(shaped_vertices()[ids])
    V0 = shaped_vertices()

    def near(i: int) -> int:
        return int(tree.query(V0[i])[1])

    return Landmarks(near(full.crotch), *(tuple(near(i) for i in pair)
                                           for pair in (full.bust, full.acromion, full.elbow, full.wrist)))


def has_boundary(F: np.ndarray) -> bool:
    """Whether some directed edge of the faces has no opposite edge (a boundary of an oriented surface)."""
    n = int(F.max()) + 1
    a, b = F.ravel(), F[:, [1, 2, 0]].ravel()
    return not np.array_equal(np.sort(a * n + b), np.sort(b * n + a))


def close_boundary_loops(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Close every boundary loop of a manifold mesh by a fan of triangles around the loop's centroid.

    The fans are oriented like the faces next to each loop, so the closed surface keeps one orientation.
    """
    import igl

    F = np.ascontiguousarray(F, dtype=np.int64)
    if not has_boundary(F):
        return V, F
    loops = [np.asarray(loop, dtype=np.int64) for loop in igl.boundary_loop_all(F) if len(loop) >= 3]
    if not loops:
        return V, F
    directed = set(zip(F.ravel().tolist(), F[:, [1, 2, 0]].ravel().tolist(), strict=True))
    new_V, new_F = [V], [F]
    n = len(V)
    for loop in loops:
        a, b = loop, np.roll(loop, -1)
        # The faces traverse a boundary edge a -> b in one direction; the fan must traverse it b -> a.
        if (int(a[0]), int(b[0])) not in directed:
            a, b = b, a
        new_V.append(V[loop].mean(0, keepdims=True))
        new_F.append(np.stack([b, a, np.full(len(loop), n)], axis=1))
        n += 1
    return np.vstack(new_V), np.vstack(new_F)


def enclosed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Signed volume of a closed, outward-oriented triangle mesh (divergence theorem, sum of tetrahedra)."""
    return float(np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() / 6.0)


def body_mass(V: np.ndarray, F: np.ndarray, density_kg_m3: float = BODY_DENSITY_KG_M3) -> float:
    """Body mass = enclosed volume x density (issue 2 §4), after closing any boundary loops."""
    Vc, Fc = close_boundary_loops(V, F)
    return enclosed_volume(Vc, Fc) * density_kg_m3


def horizontal_section_curves(V: np.ndarray, F: np.ndarray, height: float) -> list[np.ndarray]:
    """Closed curves of the mesh cut by the plane y = ``height``, each as its (k, 2) points in (x, z).

    A vertex exactly on the plane counts as above it, so every face is cut by 0 or 2 of its edges and
    the cut points, keyed by their mesh edge, link into one component per closed curve.
    """
    above = V[:, 1] >= height
    A = above[F]
    cut = A.any(1) & ~A.all(1)
    Fc = F[cut]
    if len(Fc) == 0:
        return []
    e0 = np.stack([Fc[:, 0], Fc[:, 1], Fc[:, 2]], 1)
    e1 = np.stack([Fc[:, 1], Fc[:, 2], Fc[:, 0]], 1)
    crosses = above[e0] != above[e1]  # exactly two per cut face
    i0, i1 = e0[crosses], e1[crosses]
    lo, hi = np.minimum(i0, i1), np.maximum(i0, i1)
    keys, point_of = np.unique(lo * len(V) + hi, return_inverse=True)
    lo, hi = keys // len(V), keys % len(V)
    t = (height - V[lo, 1]) / (V[hi, 1] - V[lo, 1])
    points = V[lo][:, [0, 2]] + t[:, None] * (V[hi] - V[lo])[:, [0, 2]]
    label = _segment_components(point_of.reshape(-1, 2), len(keys))
    return [points[label == c] for c in range(label.max() + 1)]


@njit(cache=True)
def _segment_components(segments: np.ndarray, n_points: int) -> np.ndarray:
    """Connected-component label of each point linked by ``segments`` (union-find with path halving)."""
    parent = np.arange(n_points)
    for a, b in segments:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a != b:
            parent[max(a, b)] = min(a, b)
    label = np.empty(n_points, dtype=np.int64)
    n_labels = 0
    for i in range(n_points):
        root = i
        while parent[root] != root:
            root = parent[root]
        if root == i:
            label[i] = n_labels
            n_labels += 1
        else:
            label[i] = label[root]  # roots are the smallest index of their component, labelled first
    return label


def torso_girth(V: np.ndarray, F: np.ndarray, height: float) -> float:
    """Tape-measure girth at ``height``: convex-hull perimeter of the section's largest curve.

    The largest curve is the one with the largest bounding box in (x, z): the torso, not an arm or hand.
    """
    curves = [pts for pts in horizontal_section_curves(V, F, height) if len(pts) >= 3]
    if not curves:
        return float("nan")
    torso = max(curves, key=lambda pts: float(np.prod(np.ptp(pts, axis=0))))
    return float(ConvexHull(torso).area)  # of a 2-D hull, .area is the perimeter


def _resolve_vertex_ids(n_vertices: int, resolution: str | None, vertex_ids: np.ndarray | None):
    from bodystudio.body.model import RESOLUTIONS, template_topology

    if vertex_ids is not None:
        if len(vertex_ids) != n_vertices:
            raise InputError(f"mesh has {n_vertices} vertices but the template's vertex_ids name {len(vertex_ids)}")
        return np.asarray(vertex_ids)
    if resolution is not None:
        ids, _ = template_topology(resolution)
        expected = 13380 if ids is None else len(ids)
        if n_vertices != expected:
            raise InputError(f"mesh has {n_vertices} vertices but the {resolution} template has {expected}")
        return ids
    counts = {}
    for res in RESOLUTIONS:
        ids, _ = template_topology(res)
        counts[res] = 13380 if ids is None else len(ids)
        if counts[res] == n_vertices:
            return ids
    valid = ", ".join(f"{n} ({res})" for res, n in counts.items())
    raise InputError(f"mesh has {n_vertices} vertices; not in bodystudio's body topology, which has {valid}")


def measure_attributes(vertices: np.ndarray, faces: np.ndarray, resolution: str | None = None,
                       vertex_ids: np.ndarray | None = None, muscularity: float | None = None) -> dict[str, float]:
    """Semantic attributes (stature, mass, girths, limb lengths) of a rest-pose body in our topology.

    ``resolution`` or ``vertex_ids`` (full-body indices of the template's vertices) name the template;
    without them it is detected from the vertex count. ``muscularity`` (the phenotype's ``muscle``) is
    passed through, NaN when unknown.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"expected (n, 3) vertices and (m, 3) triangles, got {V.shape} and {F.shape}")
    ids = _resolve_vertex_ids(len(V), resolution, vertex_ids)
    L = landmark_vertices(ids)
    floor = V[:, 1].min()
    crotch_y = V[L.crotch, 1]
    bust_y = V[list(L.bust), 1].mean()
    span = bust_y - crotch_y

    def band_girths(lo_hi):
        levels = crotch_y + span * np.linspace(*lo_hi, N_BAND_LEVELS)
        y = V[F, 1]
        # Only faces reaching into the band can be cut by its planes.
        Fb = F[(y.max(1) >= levels[0]) & (y.min(1) <= levels[-1])]
        return [torso_girth(V, Fb, h) for h in levels]

    arm = np.mean([np.linalg.norm(V[L.acromion[s]] - V[L.elbow[s]]) + np.linalg.norm(V[L.elbow[s]] - V[L.wrist[s]])
                   for s in (0, 1)])
    return {
        "stature_m": float(V[:, 1].max() - floor),
        "mass_kg": body_mass(V, F),
        "chest_m": torso_girth(V, F, bust_y),
        "waist_m": min(band_girths(WAIST_BAND)),
        "hip_m": max(band_girths(HIP_BAND)),
        "arm_length_m": float(arm),
        "leg_length_m": float(crotch_y - floor),
        "muscularity": float("nan") if muscularity is None else float(muscularity),
    }


def measure_body(body) -> dict[str, float]:
    """Attributes of a :class:`~bodystudio.body.model.BodyModel` (its phenotype gives muscularity)."""
    return measure_attributes(body.vertices, body.faces, vertex_ids=body.vertex_ids,
                              resolution="full" if body.vertex_ids is None else None,
                              muscularity=body.phenotype.muscle)
