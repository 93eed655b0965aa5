"""Scene illumination and albedo from the body model (§5 of Garment Replacement in Monocular Video).

§5.2: ``L = 400`` directional lights on a golden-spiral hemisphere facing the camera; each row of the
matrix ``A`` of Eq. 7 is one sample pixel's Lambert response to each light (albedo times the clamped
cosine, times the light's visibility when self-shadowing is on), and the light colours ``x >= 0``
solve ``argmin ||A x - b||`` by non-negative least squares. We add an ambient column (a constant
sky term) because the synthetic and most real scenes have one; dropping it biases the lights
(tested). §5.1: the albedo of each body vertex is its colour averaged over the frames that see it.

Two additions for a fitted body (measured in docs/garment.md): an L1 ``sparsity`` penalty on the
directional lights (the paper notes that NNLS "minimizes the amount of non-zero lights"; on imperfect
normals and shadows it does not, and a penalty restores it while the unpenalised ambient takes the
constant part), and :func:`chromaticity_groups`, §5.1's own assumption that shading changes a point's
intensity but not its chromaticity, used to tie the albedo of same-coloured vertices while the lights
are solved (``garment/fit.py``'s ``estimate_appearance``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize
from threadpoolctl import threadpool_limits

from bodystudio.errors import FileFormatError, InputError

N_LIGHTS = 400
SOLVERS = ("nnls", "fast_nnls", "lstsq")
GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


@dataclass(frozen=True, eq=False)
class Lighting:
    """Directional lights: unit ``directions`` (L, 3) towards the lights (world), RGB ``colors`` (L, 3) >= 0,
    and an RGB ``ambient`` (3,) term; radiance = albedo * (ambient + sum_l max(0, n . d_l) colors_l)."""

    directions: np.ndarray
    colors: np.ndarray
    ambient: np.ndarray

    def __post_init__(self):
        d = np.asarray(self.directions, dtype=np.float64).reshape(-1, 3)
        c = np.asarray(self.colors, dtype=np.float64).reshape(-1, 3)
        a = np.asarray(self.ambient, dtype=np.float64).reshape(3)
        if len(d) != len(c):
            raise InputError(f"lighting needs one colour per direction, got {len(d)} and {len(c)}")
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        if np.any(norm < 1e-12) or not (np.all(np.isfinite(d)) and np.all(np.isfinite(c)) and np.all(np.isfinite(a))):
            raise InputError("light directions must be finite non-zero vectors and colours finite")
        if np.any(c < 0) or np.any(a < 0):
            raise InputError("light colours and ambient must be >= 0 (a light cannot emit negative light)")
        object.__setattr__(self, "directions", d / norm)
        object.__setattr__(self, "colors", c)
        object.__setattr__(self, "ambient", a)

    @classmethod
    def single(cls, direction, intensity: float = 1.0, ambient: float = 0.2) -> Lighting:
        """One white directional light plus white ambient."""
        return cls(np.asarray(direction, dtype=np.float64)[None], np.full((1, 3), float(intensity)),
                   np.full(3, float(ambient)))

    def to_dict(self) -> dict:
        return {"directions": self.directions.tolist(), "colors": self.colors.tolist(),
                "ambient": self.ambient.tolist()}

    @classmethod
    def from_dict(cls, data: dict, source: str = "lighting") -> Lighting:
        """Lights from ``to_dict``'s layout; a malformed dict raises a one-line FileFormatError naming ``source``."""
        try:
            d = np.asarray(data["directions"], dtype=np.float64).reshape(-1, 3)
            c = np.asarray(data["colors"], dtype=np.float64).reshape(-1, 3)
            a = np.asarray(data["ambient"], dtype=np.float64).reshape(3)
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise FileFormatError(f"{source}: lights need 'directions' and 'colors' (n x 3) and 'ambient' (3 numbers) "
                                  f"({type(exc).__name__}: {exc})") from None
        try:
            return cls(d, c, a)
        except InputError as exc:
            raise FileFormatError(f"{source}: {exc}") from None


def golden_spiral_hemisphere(n: int = N_LIGHTS, axis=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``n`` unit directions spread uniformly over the hemisphere around ``axis`` (§5.2, Swinbank & Purser 2006).

    Equal-area bands: point k has ``cos(polar) = 1 - (k + 0.5) / n`` and azimuth ``k`` golden angles.
    """
    if n < 1:
        raise InputError(f"the light hemisphere needs at least one light, got {n}")
    k = np.arange(n) + 0.5
    cos_t = 1.0 - k / n
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = GOLDEN_ANGLE * np.arange(n)
    local = np.column_stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    return local @ np.stack([e1, e2, a])


def light_visibility(points: np.ndarray, directions: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(K, L) 1 where the ray from each point towards each directional light leaves the mesh unblocked.

    Rays are cast with open3d's BVH (Embree); start points should be offset a little off the surface.
    """
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(V, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.uint32)))
    K, L = len(points), len(directions)
    rays = np.empty((K, L, 6), dtype=np.float32)
    rays[:, :, :3] = points[:, None, :]
    rays[:, :, 3:] = directions[None, :, :]
    hit = scene.test_occlusions(o3d.core.Tensor(rays.reshape(-1, 6))).numpy().reshape(K, L)
    return (~hit).astype(np.float64)


def lambert_light_matrix(normals: np.ndarray, directions: np.ndarray, visibility: np.ndarray | None = None,
                         ambient: bool = True) -> np.ndarray:
    """The shading part of Eq. 7's matrix: ``max(0, n_k . d_l) * vis_kl`` (K, L), plus a column of ones
    (the ambient term) when ``ambient``. Each colour channel's rows are this times the sample's albedo."""
    G = np.clip(normals @ directions.T, 0.0, None)
    if visibility is not None:
        G = G * visibility
    if ambient:
        G = np.hstack([G, np.ones((len(G), 1))])
    return G


def fast_nnls(AtA: np.ndarray, Atb: np.ndarray, tol: float = 1e-10, max_iter: int | None = None) -> np.ndarray:
    """Fast non-negative least squares (Bro & de Jong 1997): Lawson-Hanson's active set on the normal equations.

    Works on the (L, L) cross-product matrices only, so each of the three colour channels of Eq. 7
    reuses one ``A^T A`` of the shading matrix; same minimiser as ``scipy.optimize.nnls(A, b)`` up to
    rounding (the agreement and the speed-up are measured in benchmarks/bench_garment_lighting.py).
    """
    n = len(Atb)
    max_iter = 3 * n if max_iter is None else max_iter
    x = np.zeros(n)
    passive = np.zeros(n, dtype=bool)
    w = Atb - AtA @ x
    scale = max(float(np.abs(Atb).max()), 1e-300)
    for _ in range(max_iter):
        candidates = ~passive & (w > tol * scale)
        if not candidates.any():
            break
        passive[np.argmax(np.where(candidates, w, -np.inf))] = True
        while True:
            idx = np.flatnonzero(passive)
            z = np.zeros(n)
            z[idx] = _solve_spd(AtA[np.ix_(idx, idx)], Atb[idx])
            if np.all(z[idx] > 0):
                x = z
                break
            neg = idx[z[idx] <= 0]
            alpha = np.min(x[neg] / (x[neg] - z[neg]))
            x = x + alpha * (z - x)
            passive &= x > tol * scale * 1e-3
            x[~passive] = 0.0
        w = Atb - AtA @ x
    return x


def _solve_spd(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    try:
        c = scipy.linalg.cho_factor(M, check_finite=False)
        return scipy.linalg.cho_solve(c, r, check_finite=False)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(M, r, rcond=None)[0]


def solve_lights(G: np.ndarray, albedo: np.ndarray, observed: np.ndarray, solver: str = "fast_nnls",
                 sparsity: float = 0.0, n_penalised: int | None = None) -> np.ndarray:
    """Eq. 7 per colour channel: light colours (L', 3) >= 0 with ``A_c = albedo_c * G`` and ``b_c`` the pixels.

    ``solver``: ``nnls`` (scipy's Lawson-Hanson on A, as the paper), ``fast_nnls`` (the same active
    set on the normal equations, Bro & de Jong) or ``lstsq`` (unconstrained; to show why the constraint
    matters). ``sparsity`` > 0 (``fast_nnls`` only) minimises ``||A x - b||^2 / (2 K) + sparsity * sum(x)``
    over the first ``n_penalised`` columns (default all; the ambient column is left free by the callers):
    an L1 penalty on the total light power, in squared pixel units per row.
    """
    if solver not in SOLVERS:
        raise InputError(f"unknown lighting solver {solver!r}; valid: {', '.join(SOLVERS)}")
    if not (np.isfinite(sparsity) and sparsity >= 0):
        raise InputError(f"lighting sparsity must be a finite number >= 0, got {sparsity}")
    if sparsity > 0 and solver != "fast_nnls":
        raise InputError(f"lighting sparsity needs the fast_nnls solver, not {solver!r}")
    # One BLAS thread: these systems are small (L = 401 columns) and OpenBLAS threads on a busy machine
    # spin (a 1500 x 401 lstsq: 7.3 s with 2 threads under load, 0.26 s with one).
    with threadpool_limits(limits=1, user_api="blas"):
        return _solve_lights(G, albedo, observed, solver, sparsity, n_penalised)


def _solve_lights(G: np.ndarray, albedo: np.ndarray, observed: np.ndarray, solver: str, sparsity: float = 0.0,
                  n_penalised: int | None = None) -> np.ndarray:
    X = np.zeros((G.shape[1], 3))
    penalty = np.zeros(G.shape[1])
    penalty[:G.shape[1] if n_penalised is None else n_penalised] = sparsity * len(G)
    for c in range(3):
        A = G * albedo[:, c:c + 1]
        b = observed[:, c]
        if solver == "nnls":
            X[:, c], _ = scipy.optimize.nnls(A, b, maxiter=50 * A.shape[1])
        elif solver == "fast_nnls":
            X[:, c] = fast_nnls(A.T @ A, A.T @ b - penalty)
        else:
            X[:, c] = np.linalg.lstsq(A, b, rcond=None)[0]
    return X


def dominant_light_direction(directions: np.ndarray, colors: np.ndarray, cone_deg: float = 25.0) -> np.ndarray:
    """Direction of the strongest light: the intensity-weighted mean of the lights within ``cone_deg``
    of the brightest one (NNLS splits a light between neighbouring grid directions; this recovers it
    between them)."""
    power = np.clip(colors, 0.0, None).sum(1)
    if not np.any(power > 0):
        raise InputError("no light has positive intensity; the scene's lighting could not be estimated")
    top = int(np.argmax(power))
    near = directions @ directions[top] >= np.cos(np.radians(cone_deg))
    d = (power[near, None] * directions[near]).sum(0)
    return d / np.linalg.norm(d)


def estimate_lighting(points: np.ndarray, normals: np.ndarray, albedo: np.ndarray, observed: np.ndarray,
                      view_axis: np.ndarray, n_lights: int = N_LIGHTS, shadows: bool = False,
                      mesh: tuple[np.ndarray, np.ndarray] | None = None, solver: str = "fast_nnls",
                      ambient: bool = True, sparsity: float = 0.0) -> Lighting:
    """Scene illumination of one frame, Eq. 7 of Garment Replacement in Monocular Video.

    ``points``/``normals`` (K, 3) body surface samples seen by K pixels, ``albedo`` (K, 3) their
    reflectance, ``observed`` (K, 3) the pixel colours (linear, [0, 1]); ``view_axis`` the unit
    direction from the body towards the camera (the hemisphere's axis, §5.2 "aligned with the camera
    orientation"). With ``shadows`` each light's visibility is ray cast against ``mesh`` = (V, F).
    ``sparsity`` > 0 adds the L1 penalty of :func:`solve_lights` on the directional lights (never on the
    ambient). Returns the lights with non-zero colour and the ambient term.
    """
    K = len(points)
    for name, arr in (("normals", normals), ("albedo", albedo), ("observed", observed)):
        if np.shape(arr) != (K, 3):
            raise InputError(f"estimate_lighting: {name} must be ({K}, 3), got {np.shape(arr)}")
    if K < 10:
        raise InputError(f"estimate_lighting needs at least 10 body pixels, got {K}; is the person in view?")
    directions = golden_spiral_hemisphere(n_lights, view_axis)
    vis = None
    if shadows:
        if mesh is None:
            raise InputError("estimate_lighting with shadows needs the body mesh (V, F)")
        vis = light_visibility(points + 2e-3 * normals, directions, *mesh)
    G = lambert_light_matrix(normals, directions, vis, ambient)
    X = solve_lights(G, albedo, observed, solver, sparsity, n_penalised=len(directions))
    amb = X[-1] if ambient else np.zeros(3)
    lights = X[:-1] if ambient else X
    active = lights.sum(1) > 1e-9
    if solver == "lstsq":  # negative lights stay (to measure the unconstrained solution)
        active = np.abs(lights).sum(1) > 1e-9
        return _unchecked_lighting(directions[active], lights[active], amb)
    return Lighting(directions[active], lights[active], np.clip(amb, 0.0, None))


def _unchecked_lighting(directions, colors, ambient) -> Lighting:
    obj = object.__new__(Lighting)
    object.__setattr__(obj, "directions", directions)
    object.__setattr__(obj, "colors", colors)
    object.__setattr__(obj, "ambient", ambient)
    return obj


def visible_vertex_colors(frames: list[np.ndarray], posed_vertices: list[np.ndarray], F: np.ndarray, camera,
                          min_cos: float = 0.3) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame: (ids of the body vertices it sees, their pixel colours (k, 3) in [0, 1]).

    Visible: in front of the rendered body's depth (1 cm tolerance), inside the image, facing the camera
    at more than ``acos(min_cos)``.
    """
    from bodystudio.capture.render import render, vertex_normals_area_weighted

    if len(frames) != len(posed_vertices) or not frames:
        raise InputError(f"estimate_albedo needs one posed mesh per frame, got {len(frames)} frames and "
                         f"{len(posed_vertices)} meshes")
    out = []
    for image, V in zip(frames, posed_vertices, strict=True):
        res = render(V, F, camera)
        uv, z = camera.project_with_depth(V)
        uv = np.nan_to_num(uv, nan=-1.0)
        col = np.round(uv[:, 0]).astype(np.int64)
        row = np.round(uv[:, 1]).astype(np.int64)
        inside = (z > 0) & (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
        N = vertex_normals_area_weighted(V, F)
        view = camera.center[None] - V
        view /= np.linalg.norm(view, axis=1, keepdims=True)
        ok = np.flatnonzero(inside & (np.einsum("nd,nd->n", N, view) > min_cos))
        zbuf = res.depth[row[ok], col[ok]]
        ids = ok[(zbuf > 0) & (z[ok] <= zbuf + 0.01)]
        scale = 255.0 if image.dtype == np.uint8 else 1.0
        out.append((ids, image[row[ids], col[ids]].astype(np.float64) / scale))
    return out


def estimate_albedo(frames: list[np.ndarray], posed_vertices: list[np.ndarray], F: np.ndarray, camera,
                    min_cos: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex albedo as the mean colour over time, §5.1 of Garment Replacement in Monocular Video.

    Each frame's visible vertices (``visible_vertex_colors``) contribute their pixel colour. Returns
    ``(albedo (n, 3) in [0, 1], count (n,))``; vertices never seen get the mean of the seen ones and count 0.
    """
    n = len(posed_vertices[0]) if posed_vertices else 0
    total = np.zeros((n, 3))
    count = np.zeros(n)
    for ids, colors in visible_vertex_colors(frames, posed_vertices, F, camera, min_cos):
        total[ids] += colors
        count[ids] += 1
    seen = count > 0
    if not seen.any():
        raise InputError("estimate_albedo: no body vertex is visible in any frame; check the camera and poses")
    albedo = np.zeros((n, 3))
    albedo[seen] = total[seen] / count[seen, None]
    albedo[~seen] = albedo[seen].mean(0)
    return albedo, count


def chromaticity_groups(albedo: np.ndarray, seen: np.ndarray, max_groups: int = 6, merge: float = 0.03,
                        seed: int = 0) -> np.ndarray:
    """Vertices of one material: k-means on the chromaticity ``(r, g) / (r + g + b)`` of the mean colour, §5.1.

    §5.1 of Garment Replacement assumes that "for a fixed surface point only its intensity values should
    change over time due to changes in surface orientation but not its chromaticity"; so vertices of one
    chromaticity are taken as one material (skin, a plain shirt, hair) whose brightness differences are
    shading. ``max_groups`` k-means centres (deterministic ``seed``) are merged when closer than ``merge``.
    Returns (n,) labels 0..G-1 for the ``seen`` vertices and -1 for the others.
    """
    from scipy.cluster.vq import kmeans2

    albedo = np.asarray(albedo, dtype=np.float64)
    seen = np.asarray(seen, dtype=bool)
    labels = np.full(len(albedo), -1)
    if not seen.any():
        return labels
    chroma = (albedo[seen] / np.maximum(albedo[seen].sum(1, keepdims=True), 1e-6))[:, :2]
    k = int(min(max_groups, len(np.unique(np.round(chroma, 4), axis=0))))
    if k <= 1:
        labels[seen] = 0
        return labels
    centres, lab = kmeans2(chroma, k, seed=seed, minit="++")
    root = np.arange(len(centres))
    for i in range(len(centres)):
        for j in range(i + 1, len(centres)):
            if np.linalg.norm(centres[i] - centres[j]) < merge:
                root[root == root[j]] = root[i]
    labels[seen] = np.unique(root[lab], return_inverse=True)[1]
    return labels


def vertex_shading(V: np.ndarray, F: np.ndarray, lighting: Lighting, camera=None, shadows: bool = False) -> np.ndarray:
    """Per-vertex irradiance (n, 3) ``ambient + sum_l vis_l max(0, n . d_l) c_l`` of a posed mesh."""
    from bodystudio.capture.render import vertex_normals_area_weighted

    N = vertex_normals_area_weighted(V, F)
    vis = light_visibility(V + 2e-3 * N, lighting.directions, V, F) if shadows and len(lighting.directions) else None
    G = lambert_light_matrix(N, lighting.directions, vis, ambient=False)
    return lighting.ambient[None] + G @ lighting.colors


def estimate_albedo_and_lighting(frames: list[np.ndarray], posed_vertices: list[np.ndarray], F: np.ndarray, camera,
                                 iterations: int = 3, shadows: bool = False, min_cos: float = 0.3,
                                 pixel_masks: list[np.ndarray] | None = None, **lighting_options
                                 ) -> tuple[np.ndarray, list[Lighting]]:
    """§5.1's albedo refined by alternating with Eq. 7's per-frame lights (our extension, measured).

    Starts from the mean colour (``estimate_albedo``); then each round estimates every frame's lights
    with the current albedo and re-solves each vertex's albedo as the least-squares ratio of its
    observed colours to its shading over the frames that see it, ``a_v = sum_t I_vt S_vt / sum_t S_vt^2``.
    Albedo and light intensity share one global scale (the classic ambiguity); the albedo keeps the
    mean of the mean-colour start. Returns ``(albedo (n, 3), lights per frame)``.
    """
    observations = visible_vertex_colors(frames, posed_vertices, F, camera, min_cos)
    albedo, count = estimate_albedo(frames, posed_vertices, F, camera, min_cos)
    seen = count > 0
    anchor = albedo[seen].mean(0)
    lights: list[Lighting] = []
    for _ in range(int(iterations)):
        lights = [frame_lighting(img, V, F, camera, albedo, shadows=shadows,
                                 pixel_mask=None if pixel_masks is None else pixel_masks[t], **lighting_options)
                  for t, (img, V) in enumerate(zip(frames, posed_vertices, strict=True))]
        num = np.zeros_like(albedo)
        den = np.zeros_like(albedo)
        for (ids, colors), V, light in zip(observations, posed_vertices, lights, strict=True):
            S = vertex_shading(V, F, light, shadows=shadows)[ids]
            num[ids] += colors * S
            den[ids] += S * S
        ok = seen & np.all(den > 1e-12, axis=1)
        albedo[ok] = num[ok] / den[ok]
        albedo *= anchor / np.maximum(albedo[seen].mean(0), 1e-12)
        albedo = np.clip(albedo, 0.0, None)
    return albedo, lights


def surface_samples(image: np.ndarray, V: np.ndarray, F: np.ndarray, camera, vertex_albedo: np.ndarray,
                    max_samples: int = 4000, erode_px: int = 2, seed: int = 0, pixel_mask: np.ndarray | None = None):
    """Pixels of the body model in one frame for Eq. 7: ``(points, normals, albedo, observed)``, each (K, 3).

    The body is rasterised into ``camera``; its silhouette is eroded by ``erode_px`` (edge pixels mix
    the background), up to ``max_samples`` pixels are drawn at random (``seed``), and each gets its
    surface point, normal (towards the camera), interpolated ``vertex_albedo`` and the frame's colour
    in [0, 1]. ``pixel_mask`` (H, W) bool restricts the samples further (e.g. to the actor's matte).
    """
    import cv2

    from bodystudio.capture.render import render, vertex_normals_area_weighted

    V = np.asarray(V, dtype=np.float64)
    if image.shape[:2] != (camera.height, camera.width):
        raise InputError(f"frame is {image.shape[1]}x{image.shape[0]} but the camera {camera.width}x{camera.height}")
    result = render(V, F, camera)
    mask = result.mask.astype(np.uint8)
    if erode_px > 0:
        mask = cv2.erode(mask, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8))
    if pixel_mask is not None:
        mask &= np.asarray(pixel_mask, dtype=bool)
    rows, cols = np.nonzero(mask)
    if len(rows) > max_samples:
        pick = np.sort(np.random.default_rng(seed).choice(len(rows), max_samples, replace=False))
        rows, cols = rows[pick], cols[pick]
    tri = F[result.triangle_id[rows, cols]]
    b = result.barycentric[rows, cols].astype(np.float64)
    points = np.einsum("kj,kjd->kd", b, V[tri])
    N = vertex_normals_area_weighted(V, F)
    normals = np.einsum("kj,kjd->kd", b, N[tri])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    flip = np.einsum("kd,kd->k", normals, points - camera.center) > 0
    normals[flip] *= -1
    albedo = np.einsum("kj,kjd->kd", b, vertex_albedo[tri])
    observed = image[rows, cols].astype(np.float64) / (255.0 if image.dtype == np.uint8 else 1.0)
    return points, normals, albedo, observed


def vertex_samples(image: np.ndarray, V: np.ndarray, F: np.ndarray, camera, vertex_albedo: np.ndarray,
                   min_cos: float = 0.3, erode_px: int = 2):
    """Eq. 7's rows per visible body vertex instead of per pixel: ``(points, normals, albedo, observed)``.

    The vertices a frame sees (``visible_vertex_colors``) with their normals and the pixel colour at
    their projection, leaving out vertices within ``erode_px`` of the silhouette (their pixel mixes the
    background). The pixel nearest a vertex also mixes its neighbours' albedo where triangles span few
    pixels, so these rows are noisier than ``surface_samples``' (measured in docs/garment.md).
    """
    import cv2

    from bodystudio.capture.render import render, vertex_normals_area_weighted

    V = np.asarray(V, dtype=np.float64)
    ((ids, colors),) = visible_vertex_colors([image], [V], F, camera, min_cos)
    if erode_px > 0:
        inner = cv2.erode(render(V, F, camera).mask.astype(np.uint8),
                          np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)) > 0
        uv = camera.project(V[ids])
        keep = inner[np.round(uv[:, 1]).astype(np.int64), np.round(uv[:, 0]).astype(np.int64)]
        ids, colors = ids[keep], colors[keep]
    N = vertex_normals_area_weighted(V, F)
    return V[ids], N[ids], vertex_albedo[ids], colors


def frame_lighting(image: np.ndarray, V: np.ndarray, F: np.ndarray, camera, vertex_albedo: np.ndarray,
                   n_lights: int = N_LIGHTS, shadows: bool = False, solver: str = "fast_nnls",
                   ambient: bool = True, max_samples: int = 4000, seed: int = 0,
                   pixel_mask: np.ndarray | None = None, sampling: str = "pixel") -> Lighting:
    """Eq. 7 for one video frame: the lights that make the body model with ``vertex_albedo`` look like ``image``.

    ``sampling``: ``pixel`` (rows are body pixels, ``surface_samples``) or ``vertex`` (rows are visible
    vertices, ``vertex_samples``; ``pixel_mask`` is then ignored).
    """
    if sampling == "pixel":
        points, normals, albedo, observed = surface_samples(image, V, F, camera, vertex_albedo, max_samples,
                                                            seed=seed, pixel_mask=pixel_mask)
    elif sampling == "vertex":
        points, normals, albedo, observed = vertex_samples(image, V, F, camera, vertex_albedo)
    else:
        raise InputError(f"unknown lighting sampling {sampling!r}; valid: pixel, vertex")
    centre = np.asarray(V, dtype=np.float64).mean(0)
    axis = camera.center - centre
    return estimate_lighting(points, normals, albedo, observed, axis / np.linalg.norm(axis), n_lights, shadows,
                             (V, F), solver, ambient)
