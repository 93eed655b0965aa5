"""Virtual garments skinned to the MakeHuman body (§1 of issue 13; §6 of Garment Replacement in Monocular Video).

The paper simulates a garment on the reconstructed body (Marvelous Designer). We build garments that
follow the body by skinning instead, from assets we have:

* ``tights`` and ``skirt``: MakeHuman's garment proxies ``helper-tights`` / ``helper-skirt`` of the hm08
  base mesh, which every body target moves, so they fit any shape;
* ``tshirt`` and ``longsleeve``: the body surface region between hem lines (waist, neckline, sleeve
  ends), cut exactly along those lines and offset outwards along the normals.

Every garment gets texture coordinates (MakeHuman's where they do not overlap, xatlas otherwise), a
procedural cloth texture baked from a pattern over the rest-pose surface (so stripes run horizontally
whatever the UV layout), and skin weights transferred from the nearest body surface point. A user's
own garment mesh (OBJ/glTF, in the body's rest pose) is bound the same way with
:func:`load_garment_mesh`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import igl
import numpy as np
import scipy.sparse as sp
from scipy import ndimage

from bodystudio.body.makehuman import load_group_faces
from bodystudio.body.model import BodyModel, build_body, rig_definition, shaped_vertices
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import load_skin_weights
from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms
from bodystudio.errors import AssetError, FileFormatError, InputError
from bodystudio.geometry.mesh import quads_to_triangles, vertex_normals

log = logging.getLogger(__name__)

GARMENTS = ("tights", "skirt", "tshirt", "longsleeve")
PATTERNS = ("stripes", "checks", "print", "plain")
#: Proxy group of the base mesh for each proxy garment.
PROXY_GROUPS = {"tights": "helper-tights", "skirt": "helper-skirt"}
#: Smallest distance a garment keeps outside the skin, metres (so the rendered skin never pokes through).
MIN_CLEARANCE_M = 0.004
#: Offset of the body-region garments along the body normals, metres.
SHIRT_OFFSET_M = 0.008
#: Share of UV area that may overlap before the UVs are rebuilt with xatlas.
MAX_UV_OVERLAP = 0.01
TEXTURE_SIZE = 512


@dataclass(frozen=True, eq=False)
class Garment:
    """A textured garment in the body's rest pose, skinned to its skeleton (metres, y up).

    ``vertices`` (n, 3) rest pose; ``faces`` (m, 3); ``uv`` (n, 2) in [0, 1] (v up, OpenGL); ``texture``
    (S, S, 3) uint8 RGB, row 0 at v = 1; ``weights`` (n, B) skin weights over the body's bones, rows sum
    to 1; ``weld`` (n,) the same id for vertices split only by a UV seam (normals are averaged over it).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    weights: np.ndarray
    weld: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    def normals(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """Unit vertex normals of the (posed) garment, continuous across UV seams."""
        return welded_normals(self.vertices if vertices is None else vertices, self.faces, self.weld)


def welded_normals(V: np.ndarray, F: np.ndarray, weld: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals computed on the welded mesh, so seam copies share one normal."""
    n_weld = int(weld.max()) + 1
    Vw = np.zeros((n_weld, 3))
    Vw[weld] = V
    return vertex_normals(Vw, weld[F])[weld]


# --- mesh surgery -------------------------------------------------------------------------------

def cut_mesh_at_isoline(V: np.ndarray, F: np.ndarray, field: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """Keep the part of a triangle mesh where a per-vertex scalar ``field`` < 0, cut exactly along field = 0.

    Triangles straddling the zero level are split at the linearly interpolated crossing points (the
    hem line is a clean curve, not a staircase of whole faces). Returns ``(V', F', M)`` with ``M`` the
    sparse ``(n', n)`` interpolation matrix, so any per-vertex attribute follows as ``M @ attr``.
    """
    field = np.asarray(field, dtype=np.float64)
    inside = field < 0
    edge_vertex: dict[tuple[int, int], int] = {}
    rows: list[tuple[int, int, float]] = []  # (new vertex, old vertex, weight)
    kept = np.flatnonzero(inside)
    new_id = np.full(len(V), -1, dtype=np.int64)
    new_id[kept] = np.arange(len(kept))
    rows.extend((int(new_id[i]), int(i), 1.0) for i in kept)
    n_new = len(kept)

    def crossing(a: int, b: int) -> int:
        nonlocal n_new
        key = (a, b) if a < b else (b, a)
        if key not in edge_vertex:
            fa, fb = field[key[0]], field[key[1]]
            t = fa / (fa - fb)
            edge_vertex[key] = n_new
            rows.extend([(n_new, key[0], 1.0 - t), (n_new, key[1], t)])
            n_new += 1
        return edge_vertex[key]

    out_faces: list[list[int]] = []
    count = inside[F].sum(1)
    out_faces.extend(new_id[F[count == 3]].tolist())
    for f in F[(count == 1) | (count == 2)]:
        ins = inside[f]
        # rotate so the odd-one-out vertex comes first, keeping the winding
        k = int(np.flatnonzero(ins != (ins.sum() == 2))[0])
        a, b, c = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
        if inside[a]:  # one vertex inside: a small triangle
            out_faces.append([int(new_id[a]), crossing(a, b), crossing(a, c)])
        else:  # two inside: a quad (b, c, ca, ab) split in two
            ab, ca = crossing(a, b), crossing(c, a)
            out_faces.append([int(new_id[b]), int(new_id[c]), ca])
            out_faces.append([int(new_id[b]), ca, ab])
    r, c, w = (np.array(x) for x in zip(*rows, strict=True)) if rows else (np.zeros(0),) * 3
    M = sp.csr_matrix((w.astype(np.float64), (r.astype(np.int64), c.astype(np.int64))), shape=(n_new, len(V)))
    Vn = M @ V
    Fn = np.array(out_faces, dtype=np.int64).reshape(-1, 3)
    return Vn, Fn, M


def largest_component(F: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """(kept vertex ids, faces re-indexed) of the largest face-connected component."""
    from scipy.sparse.csgraph import connected_components

    A = sp.coo_matrix((np.ones(2 * len(F)), (np.r_[F[:, 0], F[:, 1]], np.r_[F[:, 1], F[:, 2]])),
                      shape=(n_vertices, n_vertices))
    _, labels = connected_components(A, directed=False)
    face_label = labels[F[:, 0]]
    biggest = np.bincount(face_label).argmax()
    Fk = F[face_label == biggest]
    ids = np.unique(Fk)
    remap = np.full(n_vertices, -1, dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    return ids, remap[Fk]


# --- skinning -----------------------------------------------------------------------------------

def transfer_skin_weights(points: np.ndarray, body_V: np.ndarray, body_F: np.ndarray,
                          body_weights: np.ndarray) -> np.ndarray:
    """Skin weights of garment points: the body's weights at the nearest body surface point.

    The weights of the nearest point's triangle are blended with its barycentric coordinates, so the
    garment moves like the skin under it (the usual proxy binding of MakeHuman/MPFB clothes).
    """
    P = np.ascontiguousarray(points, dtype=np.float64)
    _, tri, closest = igl.point_mesh_squared_distance(P, np.ascontiguousarray(body_V, dtype=np.float64),
                                                      np.ascontiguousarray(body_F, dtype=np.int64))
    T = body_F[tri]
    bary = igl.barycentric_coordinates(closest, body_V[T[:, 0]], body_V[T[:, 1]], body_V[T[:, 2]])
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(1, keepdims=True)
    W = np.einsum("nk,nkb->nb", bary, body_weights[T])
    return W / W.sum(1, keepdims=True)


def push_outside_body(points: np.ndarray, body_V: np.ndarray, body_F: np.ndarray,
                      clearance_m: float = MIN_CLEARANCE_M) -> np.ndarray:
    """Move garment points that lie inside the skin (or closer than ``clearance_m``) out along the body normal."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    S, _, C, N = igl.signed_distance(P, np.ascontiguousarray(body_V, dtype=np.float64),
                                     np.ascontiguousarray(body_F, dtype=np.int64),
                                     sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    close = S < clearance_m
    out = P.copy()
    n = N[close] / np.maximum(np.linalg.norm(N[close], axis=1, keepdims=True), 1e-12)
    out[close] = C[close] + clearance_m * n
    return out


def pose_garment(garment: Garment, body: BodyModel, pose: Pose) -> np.ndarray:
    """Posed garment vertices ``(n, 3)``: linear blend skinning with the body's skeleton and the garment's weights."""
    if garment.weights.shape[1] != body.skeleton.n_bones:
        raise InputError(f"garment {garment.name!r} is skinned to {garment.weights.shape[1]} bones but the body "
                         f"has {body.skeleton.n_bones}; dress this body again")
    return linear_blend_skinning(garment.vertices, garment.weights, skinning_transforms(body.skeleton, pose))


# --- texture coordinates and procedural cloth ------------------------------------------------------

def split_uv_seams(faces: np.ndarray, uv_faces: np.ndarray, texcoords: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vertex per (position, texture coordinate) pair: ``(vertex id per new vertex, faces, uv)``."""
    pairs = np.stack([faces.ravel(), uv_faces.ravel()], axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return unique[:, 0], inverse.reshape(faces.shape), texcoords[unique[:, 1]]


def normalized_uv(uv: np.ndarray) -> np.ndarray:
    """Texture coordinates shifted and uniformly scaled into [0.01, 0.99]^2 (aspect kept)."""
    lo, hi = uv.min(0), uv.max(0)
    return 0.01 + 0.98 * (uv - lo) / max(float((hi - lo).max()), 1e-12)


def uv_overlap_fraction(uv: np.ndarray, F: np.ndarray, size: int = 512) -> float:
    """Share of the UV triangles' total area that lies over another triangle (mirrored or stacked charts).

    ``1 - (texels covered) / (summed triangle area in texels)``, with the coverage rasterised.
    """
    from bodystudio.capture.render import render
    from bodystudio.geometry.camera import Camera

    flat = np.column_stack([uv * size - 0.5, np.ones(len(uv))])
    covered = render(flat, F, Camera("uv", np.eye(3), None, np.eye(3), np.zeros(3), size, size)).mask.sum()
    e1, e2 = uv[F[:, 1]] - uv[F[:, 0]], uv[F[:, 2]] - uv[F[:, 0]]
    total = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum() * size**2
    return float(max(0.0, 1.0 - covered / max(total, 1e-12)))


def xatlas_uv(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Automatic UV atlas (xatlas): ``(original vertex id per new vertex, faces, uv in [0, 1])``."""
    import xatlas

    vmapping, indices, uvs = xatlas.parametrize(np.ascontiguousarray(V, dtype=np.float32),
                                                np.ascontiguousarray(F, dtype=np.uint32))
    return vmapping.astype(np.int64), indices.astype(np.int64), uvs.astype(np.float64)


def uv_texel_positions(V: np.ndarray, F: np.ndarray, uv: np.ndarray, size: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise the mesh in texture space: (covered mask (S, S), rest-pose point per texel (S, S, 3)).

    Texel ``(row, col)`` has its centre at ``u = (col + 0.5) / S``, ``v = 1 - (row + 0.5) / S``. The
    capture renderer does the rasterisation through a camera at the origin looking along +z at the
    UV layout placed on the plane z = 1.
    """
    from bodystudio.capture.render import render
    from bodystudio.geometry.camera import Camera

    flat = np.column_stack([uv[:, 0] * size - 0.5, (1.0 - uv[:, 1]) * size - 0.5, np.ones(len(uv))])
    cam = Camera("uv", np.eye(3), None, np.eye(3), np.zeros(3), size, size)
    result = render(flat, F, cam)
    P = np.zeros((size, size, 3))
    pts, rc = result.surface_points(V, F)
    P[rc[:, 0], rc[:, 1]] = pts
    return result.mask, P


def cloth_pattern(points: np.ndarray, pattern: str, colors: np.ndarray, period_m: float = 0.06) -> np.ndarray:
    """Cloth colour (K, 3) in [0, 1] at rest-pose surface points: a solid texture in body coordinates.

    ``stripes``: horizontal bands; ``checks``: squares over height and arc length around the body's
    vertical axis; ``print``: polka dots; ``plain``: one colour. ``colors`` (3, 3): base, second, accent
    (the accent is unused by these patterns; accent lines along the checks' borders widened into blobs
    where the body-centred arc coordinate runs along the surface, e.g. the shins).
    """
    y = points[:, 1]
    arc = np.arctan2(points[:, 0], points[:, 2]) * 0.15  # arc length on a 15 cm cylinder
    base, second = colors[0], colors[1]
    if pattern == "plain":
        t = np.zeros(len(points))
    elif pattern == "stripes":
        t = (np.floor(y / (period_m / 2)) % 2).astype(np.float64)
    elif pattern == "checks":
        t = ((np.floor(y / period_m) + np.floor(arc / period_m)) % 2).astype(np.float64)
    elif pattern == "print":
        cell = period_m * 1.5
        dy = (y / cell) % 1.0 - 0.5
        row = np.floor(y / cell)
        dx = (arc / cell + 0.5 * row) % 1.0 - 0.5
        t = (np.hypot(dx, dy) < 0.25).astype(np.float64)
    else:
        raise InputError(f"unknown cloth pattern {pattern!r}; valid: {', '.join(PATTERNS)}")
    out = base[None] * (1 - t[:, None]) + second[None] * t[:, None]
    return out


def cloth_colors(seed: int) -> np.ndarray:
    """Three distinct cloth colours (base, second, accent) in [0, 1], chosen by ``seed``."""
    rng = np.random.default_rng(seed)
    hue = rng.uniform(0, 1)
    out = []
    for k, (sat, val) in enumerate(((0.7, 0.75), (0.15, 0.95), (0.8, 0.35))):
        h = (hue + 0.37 * k) % 1.0
        out.append(_hsv_to_rgb(h, sat, val))
    return np.array(out)


def _hsv_to_rgb(h: float, s: float, v: float) -> np.ndarray:
    import colorsys

    return np.array(colorsys.hsv_to_rgb(h, s, v))


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup of (K, 2) UVs (v up; texel centres at ``(i + 0.5) / S``) -> (K, 3) in [0, 1]."""
    S_h, S_w = texture.shape[:2]
    if len(uv) == 0:  # cv2.remap refuses an empty map
        return np.zeros((0, 3))
    mx = (uv[:, 0] * S_w - 0.5).astype(np.float32).reshape(-1, 1)
    my = ((1.0 - uv[:, 1]) * S_h - 0.5).astype(np.float32).reshape(-1, 1)
    out = cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3).astype(np.float64) / 255.0


def bake_procedural_texture(V: np.ndarray, F: np.ndarray, uv: np.ndarray, pattern: str = "stripes",
                            size: int = TEXTURE_SIZE, seed: int = 0) -> np.ndarray:
    """Texture image (S, S, 3) uint8 of a procedural cloth pattern evaluated on the rest-pose surface.

    Texels outside the UV charts take the nearest chart texel's colour (no dark seams under bilinear
    filtering).
    """
    if pattern not in PATTERNS:
        raise InputError(f"unknown cloth pattern {pattern!r}; valid: {', '.join(PATTERNS)}")
    if not 16 <= int(size) <= 4096:
        raise InputError(f"texture size {size} must lie in [16, 4096] texels")
    size = int(size)
    mask, P = uv_texel_positions(V, F, uv, size)
    if not mask.any():
        raise InputError("the garment's UV layout covers no texel; its texture coordinates are degenerate")
    color = np.zeros((size, size, 3))
    color[mask] = cloth_pattern(P[mask], pattern, cloth_colors(seed))
    _, (ri, ci) = ndimage.distance_transform_edt(~mask, return_indices=True)
    color = color[ri, ci]
    return np.clip(np.round(color * 255), 0, 255).astype(np.uint8)


# --- the garments ------------------------------------------------------------------------------

def hem_reference(body: BodyModel) -> BodyModel:
    """The body with the ``game_engine`` rig, whose bones the hem lines are placed on (same vertices:
    every rig's joints are defined on the same shaped base mesh)."""
    if body.rig == "game_engine":
        return body
    return build_body(body.phenotype, body.local, resolution=body.resolution, rig="game_engine")


def leggings_field(V: np.ndarray, body: BodyModel) -> np.ndarray:
    """< 0 between the leggings' hem lines: 6 cm above the hip joints and 6 cm above the ankles."""
    sk = hem_reference(body).skeleton
    waist_y = 0.5 * (sk.heads[sk.index("thigh_l")][1] + sk.heads[sk.index("thigh_r")][1]) + 0.06
    ankle_y = 0.5 * (sk.heads[sk.index("foot_l")][1] + sk.heads[sk.index("foot_r")][1]) + 0.06
    return np.maximum(V[:, 1] - waist_y, ankle_y - V[:, 1])


def proxy_garment_mesh(body: BodyModel, name: str
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A MakeHuman garment proxy shaped like ``body``: ``(V, F, uv, weld, weights)`` with UV seams split.

    ``helper-tights`` is a whole-body suit; the leggings are its part between the waist and the ankles.
    MakeHuman's texture coordinates are kept (rescaled to the unit square) unless their charts overlap.
    The skin weights are MakeHuman's own for the proxy vertices: on the skirt, weights transferred from
    the nearest skin tear it between the legs when walking (99th-percentile edge stretch 5.8x against
    1.6x, ``walk`` motion, 6k body), on the leggings both agree (mean total variation 0.02).
    """
    quads, uv_quads, texcoords = load_group_faces(PROXY_GROUPS[name])
    V_all = shaped_vertices(body.phenotype, body.local)
    ids = np.unique(quads)
    remap = np.full(len(V_all), -1, dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    F_welded = quads_to_triangles(remap[quads])
    V_welded = V_all[ids]
    weld, F, uv = split_uv_seams(F_welded, quads_to_triangles(uv_quads), texcoords)
    V = V_welded[weld]
    try:
        W = load_skin_weights(rig_definition(body.rig), len(body.vertices), vertex_ids=ids)[weld]
    except AssetError:  # a rig whose weights leave out the proxies: the skin's, diffused (as for user meshes)
        W = transfer_skin_weights(V, body.vertices, body.faces, body.weights)
        W = smooth_skin_weights(W, F, weld, 30)
    if name == "tights":
        V, F, M = cut_mesh_at_isoline(V, F, leggings_field(V, body))
        uv, W = M @ uv, M @ W
        keep, F = largest_component(F, len(V))
        V, uv, W = V[keep], uv[keep], W[keep]
        weld = _weld_positions(V)
    uv = normalized_uv(uv)
    if uv_overlap_fraction(uv, F) > MAX_UV_OVERLAP:
        log.info("%s: MakeHuman's UV charts overlap; rebuilding them with xatlas", name)
        vmap, F, uv = xatlas_uv(V, F)
        V, weld, W = V[vmap], weld[vmap], W[vmap]
    return V, F, uv, weld, W / W.sum(1, keepdims=True)


def arm_coordinate(V: np.ndarray, body: BodyModel, side: str) -> np.ndarray:
    """Distance (m) along the arm chain shoulder -> elbow -> wrist of each point's closest chain point."""
    sk = hem_reference(body).skeleton
    up, low = sk.index(f"upperarm_{side}"), sk.index(f"lowerarm_{side}")
    shoulder, elbow, wrist = sk.heads[up], sk.heads[low], sk.tails[low]
    out = np.empty(len(V))
    best = np.full(len(V), np.inf)
    start = 0.0
    for a, b, first in ((shoulder, elbow, True), (elbow, wrist, False)):
        d = b - a
        L = float(np.linalg.norm(d))
        t = (V - a) @ d / L**2
        t = np.clip(t, None if first else 0.0, 1.0)
        dist = np.linalg.norm(V - (a + t[:, None] * d), axis=1)
        better = dist < best
        out[better] = start + t[better] * L
        best[better] = dist[better]
        start += L
    return out


def shirt_region_field(body: BodyModel, sleeve: str = "short") -> np.ndarray:
    """Per body vertex: < 0 inside the shirt, 0 on a hem line (waist, neckline, sleeve ends), > 0 outside."""
    body = hem_reference(body)
    V, sk = body.vertices, body.skeleton
    hip_y = 0.5 * (sk.heads[sk.index("thigh_l")][1] + sk.heads[sk.index("thigh_r")][1])
    neck = sk.heads[sk.index("neck_01")]
    waist = (hip_y + 0.06) - V[:, 1]
    # the neckline dips 6 cm at the front (a crew neck), a little at the back
    front = np.clip((V[:, 2] - neck[2]) / 0.08, 0.0, 1.0)
    neckline = V[:, 1] - (neck[1] - 0.015 - 0.05 * front)
    fields = [waist, neckline]
    for side in ("l", "r"):
        names = [f"upperarm_{side}", f"lowerarm_{side}", f"hand_{side}"]
        arm_weight = body.weights[:, [sk.index(n) for n in names]].sum(1)
        s = arm_coordinate(V, body, side)
        up = sk.index(f"upperarm_{side}")
        upper_len = float(sk.lengths[up])
        chain = upper_len + float(sk.lengths[sk.index(f"lowerarm_{side}")])
        hem = 0.45 * upper_len if sleeve == "short" else chain - 0.03
        fields.append(np.where(arm_weight > 0.5, s - hem, -1.0))
    return np.max(fields, axis=0)


def shirt_garment_mesh(body: BodyModel, sleeve: str = "short", offset_m: float = SHIRT_OFFSET_M
                       ) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """The body surface between the shirt's hem lines, offset along the normals: ``(V, F, M)``.

    ``M`` maps body-vertex attributes to the garment's vertices (weights follow the skin exactly).
    """
    N = vertex_normals(body.vertices, body.faces)
    shell = body.vertices + offset_m * N
    Vc, Fc, M = cut_mesh_at_isoline(shell, body.faces, shirt_region_field(body, sleeve))
    ids, Fk = largest_component(Fc, len(Vc))
    return Vc[ids], Fk, M[ids]


def dress(body: BodyModel, name: str, pattern: str = "stripes", texture_size: int = TEXTURE_SIZE,
          seed: int = 0) -> Garment:
    """Build garment ``name`` (tights, skirt, tshirt, longsleeve) fitted and skinned to ``body``."""
    if not isinstance(body, BodyModel):
        raise InputError(f"dress needs a BodyModel (bodystudio.body.build_body), got {type(body).__name__}")
    if name not in GARMENTS:
        raise InputError(f"unknown garment {name!r}; valid: {', '.join(GARMENTS)}")
    if pattern not in PATTERNS:
        raise InputError(f"unknown cloth pattern {pattern!r}; valid: {', '.join(PATTERNS)}")
    if not 16 <= int(texture_size) <= 4096:
        raise InputError(f"texture size {texture_size} must lie in [16, 4096] texels")
    if name in PROXY_GROUPS:
        V, F, uv, weld, W = proxy_garment_mesh(body, name)
        # push each welded position once so seam copies stay together
        n_weld = int(weld.max()) + 1
        Vw = np.zeros((n_weld, 3))
        Vw[weld] = V
        V = push_outside_body(Vw, body.vertices, body.faces)[weld]
    else:
        Vs, Fs, M = shirt_garment_mesh(body, "short" if name == "tshirt" else "long")
        weld, F, uv = xatlas_uv(Vs, Fs)
        V = Vs[weld]
        W = np.asarray(M @ body.weights)[weld]
        W = W / W.sum(1, keepdims=True)
    texture = bake_procedural_texture(V, F, uv, pattern, texture_size, seed)
    return Garment(name, V, F, uv, texture, W, weld)


def load_garment_mesh(path: str | Path, body: BodyModel, pattern: str = "stripes",
                      texture_size: int = TEXTURE_SIZE, seed: int = 0, max_distance_m: float = 0.15,
                      smooth_iterations: int = 30) -> Garment:
    """A user's garment mesh (OBJ, glTF/GLB, PLY) in the body's rest pose, bound to ``body``.

    Its own UVs and texture image are kept when present; otherwise xatlas UVs and a procedural
    ``pattern``. Skin weights come from the nearest body surface point, diffused ``smooth_iterations``
    times over the garment (MakeHuman's skirt bound this way: 99th-percentile edge stretch over a walk
    5.8x without diffusion, 1.44x with 30 steps, 1.60x with MakeHuman's own skirt weights).
    Refused with one line: unreadable files, non-metre scale, a garment far from the body.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such garment mesh file")
    if path.suffix.lower() not in (".obj", ".glb", ".gltf", ".ply"):
        raise FileFormatError(f"{path}: unsupported garment format; use .obj, .glb, .gltf or .ply")
    try:
        loaded = trimesh.load(path, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types for broken files
        raise FileFormatError(f"{path}: cannot read the garment mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FileFormatError(f"{path}: contains no triangles; give a triangle mesh of the garment")
    V = np.asarray(loaded.vertices, dtype=np.float64)
    F = np.asarray(loaded.faces, dtype=np.int64)
    if not np.all(np.isfinite(V)):
        raise FileFormatError(f"{path}: {int((~np.isfinite(V)).any(1).sum())} vertices are NaN or infinite")
    extent = float(np.ptp(V, axis=0).max())
    body_extent = float(np.ptp(body.vertices, axis=0).max())
    if not 0.02 < extent < 1.5 * body_extent:
        raise InputError(f"{path}: the garment spans {extent:.3g} units but the body {body_extent:.2f} m; "
                         "export it in metres (y up, facing +z) around the body's rest pose")
    d2, _, _ = igl.point_mesh_squared_distance(V, body.vertices, body.faces)
    median = float(np.median(np.sqrt(d2)))
    if median > max_distance_m:
        raise InputError(f"{path}: the garment lies {median:.2f} m (median) from the body surface; "
                         f"place it on the body's rest pose (within {max_distance_m} m)")
    uv = getattr(loaded.visual, "uv", None)
    texture = None
    if uv is not None and len(uv) == len(V) and np.all(np.isfinite(uv)):
        uv = np.asarray(uv, dtype=np.float64)
        image = _material_image(loaded.visual)
        if image is not None:
            texture = image
        weld = _weld_positions(V)
    else:
        weld0, F, uv = xatlas_uv(V, F)
        V, weld = V[weld0], weld0
    if texture is None:
        if uv.min() < 0 or uv.max() > 1:
            uv = normalized_uv(uv)
        texture = bake_procedural_texture(V, F, uv, pattern, texture_size, seed)
    V = push_outside_body(V, body.vertices, body.faces)
    W = transfer_skin_weights(V, body.vertices, body.faces, body.weights)
    W = smooth_skin_weights(W, F, weld, smooth_iterations)
    return Garment(path.stem, V, F, uv, texture, W, weld)


def _weld_positions(V: np.ndarray) -> np.ndarray:
    _, inverse = np.unique(np.round(V, 7), axis=0, return_inverse=True)
    return inverse.ravel().astype(np.int64)


def _material_image(visual) -> np.ndarray | None:
    material = getattr(visual, "material", None)
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    if image is None:
        return None
    arr = np.asarray(image.convert("RGB"), dtype=np.uint8)
    if arr.shape[:2] == (2, 2) and np.all(arr == arr[0, 0]):
        # trimesh's stand-in for a material without an image (``trimesh.visual.material.empty_material``, e.g.
        # an OBJ with texture coordinates and no .mtl): no texture of the file's own
        return None
    return arr if arr.ndim == 3 and min(arr.shape[:2]) >= 2 else None


def smooth_skin_weights(W: np.ndarray, F: np.ndarray, weld: np.ndarray, iterations: int) -> np.ndarray:
    """Diffuse skin weights over the garment surface (uniform Laplacian steps on the welded mesh).

    Transferred weights jump where a loose garment's nearest skin switches from one leg to the other;
    diffusing them lets the cloth between the legs follow both (a skinning stand-in for the paper's
    cloth simulation, §6).
    """
    n_weld = int(weld.max()) + 1
    Fw = weld[F]
    E = np.vstack([Fw[:, [0, 1]], Fw[:, [1, 2]], Fw[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                      shape=(n_weld, n_weld)).tocsr()
    A.data[:] = 1.0
    P = sp.diags(1.0 / np.maximum(np.asarray(A.sum(1)).ravel(), 1)) @ A
    Ww = np.zeros((n_weld, W.shape[1]))
    Ww[weld] = W
    for _ in range(int(iterations)):
        Ww = 0.5 * Ww + 0.5 * (P @ Ww)
    return Ww[weld] / Ww[weld].sum(1, keepdims=True)
