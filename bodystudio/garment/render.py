"""Garment rendering with the estimated lights and a depth buffer (§6 of Garment Replacement in Monocular Video).

The paper renders the simulated garment in Mental Ray with the reconstructed point lights, "along with
the pixel color, we also render into a separate depth buffer which we later use for depth-based
compositing" (§6, §7.3). Here the body and the garment are rasterised together by the capture
renderer's numba z-buffer (``capture.render.render``), so body parts in front of the garment (an arm
across the chest) hide it; the garment's colour comes from its texture (bilinear lookup of the
interpolated UVs) under Lambert shading by directional lights plus ambient (the model of §5.2), with
optional cast shadows (a ray towards each light from every visible surface point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bodystudio.capture.render import SKIN_COLOR, render, vertex_normals_area_weighted
from bodystudio.errors import InputError
from bodystudio.garment.garments import Garment, sample_texture
from bodystudio.garment.lighting import Lighting, light_visibility
from bodystudio.geometry.camera import Camera


@dataclass(frozen=True, eq=False)
class GarmentRender:
    """Render layers of one frame (H, W): what a compositor gets from the 3D pass.

    ``image`` uint8 RGB over the background; ``garment_mask`` visible garment pixels; ``body_mask``
    visible body (skin) pixels; ``depth`` camera z (m) of the nearest surface, 0 where empty;
    ``garment_depth`` / ``body_depth`` each surface rendered alone (0 where absent), for compositing
    after image-space warps (§7.3); ``garment_rgb`` float32 linear colour of the garment alone.
    """

    image: np.ndarray
    garment_mask: np.ndarray
    body_mask: np.ndarray
    depth: np.ndarray
    garment_depth: np.ndarray
    body_depth: np.ndarray
    garment_rgb: np.ndarray


def lambert_radiance(normals: np.ndarray, albedo: np.ndarray, lighting: Lighting,
                     visibility: np.ndarray | None = None) -> np.ndarray:
    """Eq. 7's shading model: ``albedo * (ambient + sum_l vis_l max(0, n . d_l) c_l)``, (K, 3)."""
    cos = np.clip(normals @ lighting.directions.T, 0.0, None)  # (K, L)
    if visibility is not None:
        cos = cos * visibility
    return albedo * (lighting.ambient[None] + cos @ lighting.colors)


def _pixel_attributes(result, F: np.ndarray, rows, cols, attr: np.ndarray) -> np.ndarray:
    tri = F[result.triangle_id[rows, cols]]
    b = result.barycentric[rows, cols].astype(np.float64)
    return np.einsum("kj,kjd->kd", b, attr[tri])


def shade_visible_surface(result, V: np.ndarray, F: np.ndarray, N: np.ndarray, camera: Camera, lighting: Lighting,
                          select: np.ndarray, albedo_at, shadows: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Radiance (K, 3) of the ``select``ed covered pixels of a rasterisation, and their (K, 2) (row, col).

    ``albedo_at(rows, cols)`` gives each pixel's albedo; normals are interpolated, turned towards the
    camera (two-sided), and with ``shadows`` each light is tested for occlusion by ``(V, F)``.
    """
    rows, cols = np.nonzero(select)
    if len(rows) == 0:
        return np.zeros((0, 3)), np.zeros((0, 2), dtype=np.int64)
    P = _pixel_attributes(result, F, rows, cols, V)
    n = _pixel_attributes(result, F, rows, cols, N)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    flip = np.einsum("kd,kd->k", n, P - camera.center) > 0
    n[flip] *= -1
    vis = light_visibility(P + 1e-3 * n, lighting.directions, V, F) if shadows else None
    return lambert_radiance(n, albedo_at(rows, cols), lighting, vis), np.stack([rows, cols], axis=1)


def render_body(V: np.ndarray, F: np.ndarray, camera: Camera, lighting: Lighting, albedo: np.ndarray,
                shadows: bool = False):
    """Linear radiance image (H, W, 3) float64 of a mesh with per-vertex ``albedo`` under ``lighting``
    (0 where empty), and its rasterisation (``capture.render.RenderResult``)."""
    V = np.asarray(V, dtype=np.float64)
    result = render(V, F, camera)
    N = vertex_normals_area_weighted(V, F)
    image = np.zeros((camera.height, camera.width, 3))
    rgb, rc = shade_visible_surface(result, V, F, N, camera, lighting, result.mask,
                                    lambda r, c: _pixel_attributes(result, F, r, c, albedo), shadows)
    image[rc[:, 0], rc[:, 1]] = rgb
    return image, result


def render_garment(body_V: np.ndarray, body_F: np.ndarray, garment: Garment, garment_V: np.ndarray,
                   camera: Camera, lighting: Lighting, background: np.ndarray | None = None,
                   body_albedo: np.ndarray | None = None, shadows: bool = False) -> GarmentRender:
    """Render the posed body wearing the posed garment into ``camera`` under ``lighting``.

    ``body_albedo`` (n_body, 3) in [0, 1] (default: a flat skin colour); ``background`` (H, W, 3)
    uint8 (default black). ``shadows`` casts shadows of body and garment from every light.
    """
    body_V = np.asarray(body_V, dtype=np.float64)
    garment_V = np.asarray(garment_V, dtype=np.float64)
    if garment_V.shape != garment.vertices.shape:
        raise InputError(f"posed garment vertices must be {garment.vertices.shape}, got {garment_V.shape}")
    H, W = camera.height, camera.width
    if background is None:
        image = np.zeros((H, W, 3), dtype=np.uint8)
    else:
        image = np.array(background, dtype=np.uint8, copy=True)
        if image.shape != (H, W, 3):
            raise InputError(f"background must be ({H}, {W}, 3) for camera {camera.name}, got {image.shape}")
    nb = len(body_V)
    V = np.vstack([body_V, garment_V])
    F = np.vstack([body_F, garment.faces + nb])
    both = render(V, F, camera)
    body_alone = render(body_V, body_F, camera)
    garment_alone = render(garment_V, garment.faces, camera)
    garment_mask = both.mask & (both.triangle_id >= len(body_F))
    body_mask = both.mask & ~garment_mask

    N = np.vstack([vertex_normals_area_weighted(body_V, body_F), garment.normals(garment_V)])
    if body_albedo is None:
        body_albedo = np.tile(np.asarray(SKIN_COLOR, dtype=np.float64), (nb, 1))
    out = image.astype(np.float64) / 255.0
    garment_rgb = np.zeros((H, W, 3), dtype=np.float32)
    body_attr = np.vstack([body_albedo, np.zeros_like(garment_V)])
    uv_attr = np.vstack([np.zeros((nb, 2)), garment.uv])
    rgb, rc = shade_visible_surface(both, V, F, N, camera, lighting, body_mask,
                                    lambda r, c: _pixel_attributes(both, F, r, c, body_attr), shadows)
    out[rc[:, 0], rc[:, 1]] = rgb
    rgb, rc = shade_visible_surface(
        both, V, F, N, camera, lighting, garment_mask,
        lambda r, c: sample_texture(garment.texture, _pixel_attributes(both, F, r, c, uv_attr)), shadows)
    out[rc[:, 0], rc[:, 1]] = rgb
    garment_rgb[rc[:, 0], rc[:, 1]] = rgb
    image = np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8)
    depth = both.depth
    return GarmentRender(image, garment_mask, body_mask, depth, garment_alone.depth, body_alone.depth, garment_rgb)


@dataclass(frozen=True, eq=False)
class GarmentLayer:
    """The garment rendered on its own (§7.3's layer G, whole even where the body hides it) and the body's
    own depth (§7.3's B): what the image-space refinement warps before the depth test.

    ``rgb`` float32 (H, W, 3) linear garment colour (0 where absent); ``mask`` garment coverage; ``depth`` its
    camera z (m, 0 where absent); ``body_image`` float32 (H, W, 3) the body alone shaded with its albedo (the
    image optical flow compares with the video, §7.1); ``body_mask`` / ``body_depth`` its coverage and depth.
    """

    rgb: np.ndarray
    mask: np.ndarray
    depth: np.ndarray
    body_image: np.ndarray
    body_mask: np.ndarray
    body_depth: np.ndarray


def render_garment_layer(body_V: np.ndarray, body_F: np.ndarray, garment: Garment, garment_V: np.ndarray,
                         camera: Camera, lighting: Lighting, body_albedo: np.ndarray | None = None,
                         shadows: bool = False) -> GarmentLayer:
    """Render the garment and the body as separate layers with depth (§6: "we also render into a separate
    depth buffer which we later use for depth-based compositing").

    Unlike :func:`render_garment` (one z-buffer for both), the garment layer keeps the cloth hidden behind an
    arm, so that the depth test can be made after the image-space warps of §7. With ``shadows`` the garment
    is shadowed by body and garment, the body by itself only: the body layer stands for the actor as the
    video shows them (their own clothes are in ``body_albedo``), the image §7.1's flow compares with.
    """
    body_V = np.asarray(body_V, dtype=np.float64)
    garment_V = np.asarray(garment_V, dtype=np.float64)
    if garment_V.shape != garment.vertices.shape:
        raise InputError(f"posed garment vertices must be {garment.vertices.shape}, got {garment_V.shape}")
    H, W = camera.height, camera.width
    nb = len(body_V)
    if body_albedo is None:
        body_albedo = np.tile(np.asarray(SKIN_COLOR, dtype=np.float64), (nb, 1))
    V_all = np.vstack([body_V, garment_V])
    F_all = np.vstack([body_F, garment.faces + nb])

    def shade(result, V, F, N, albedo_at, occluders):
        rows, cols = np.nonzero(result.mask)
        if len(rows) == 0:
            return np.zeros((0, 3)), rows, cols
        P = _pixel_attributes(result, F, rows, cols, V)
        n = _pixel_attributes(result, F, rows, cols, N)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        n[np.einsum("kd,kd->k", n, P - camera.center) > 0] *= -1
        vis = light_visibility(P + 1e-3 * n, lighting.directions, *occluders) if shadows else None
        return lambert_radiance(n, albedo_at(rows, cols), lighting, vis), rows, cols

    body = render(body_V, body_F, camera)
    body_image = np.zeros((H, W, 3), dtype=np.float32)
    rgb, r, c = shade(body, body_V, body_F, vertex_normals_area_weighted(body_V, body_F),
                      lambda rr, cc: _pixel_attributes(body, body_F, rr, cc, body_albedo), (body_V, body_F))
    body_image[r, c] = rgb
    cloth = render(garment_V, garment.faces, camera)
    garment_rgb = np.zeros((H, W, 3), dtype=np.float32)
    rgb, r, c = shade(cloth, garment_V, garment.faces, garment.normals(garment_V),
                      lambda rr, cc: sample_texture(garment.texture,
                                                    _pixel_attributes(cloth, garment.faces, rr, cc, garment.uv)),
                      (V_all, F_all))
    garment_rgb[r, c] = rgb
    return GarmentLayer(garment_rgb, cloth.mask, cloth.depth, body_image, body.mask, body.depth)
