"""Analytic checks of garment/composite.py (§6-7 of Garment Replacement): tiny inputs, exact answers, no body model.

Written for mutation testing (issue 17). The end-to-end render of tests/garment/test_refine.py and the CLI
catalogue of tests/reliability/test_garment_render_inputs.py take seconds per run; these check each piece on
its own in well under a second: the silhouette IoU, the albedo with known lights (§5.1), the oracle fit's
perturbation, the §7 chain on a two-layer toy frame (compositing keeps the nearer layer), the render loop with
stand-ins for the 3D pass, reading frames from a video, SSIM written out, and the refusals.
"""

import json
import re
from dataclasses import dataclass, field
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import scipy.ndimage
from scipy.spatial.transform import Rotation

from bodystudio.errors import FileFormatError, InputError
from bodystudio.garment import composite as cp
from bodystudio.garment import refine
from bodystudio.garment.fitfile import MIN_FRAME_IOU
from bodystudio.garment.garments import GARMENTS, PATTERNS
from bodystudio.garment.lighting import Lighting, vertex_shading, visible_vertex_colors
from bodystudio.geometry.camera import Camera


def exact(message):
    """A ``pytest.raises(match=...)`` pattern for exactly this message."""
    return "^" + re.escape(str(message)) + "$"


def icosphere(subdivisions=3, radius=0.5):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


def front_camera(size=64):
    return Camera.look_at("cam_00", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fx=2.4 * size, width=size, height=size)


class Ball:
    """A stand-in body: a ball that the pose translates (rotations ignored)."""

    def __init__(self, radius=0.5):
        self.vertices, self.faces = icosphere(3, radius)
        self.n_vertices = len(self.vertices)

    def pose(self, pose):
        return self.vertices + np.asarray(pose.translation), None


# ------------------------------------------------------------------------------------------ fit quality


def test_body_silhouette_iou_is_intersection_over_union_per_frame():
    from bodystudio.capture.render import render

    ball, cam = Ball(), front_camera()
    sil = render(ball.vertices, ball.faces, cam).mask
    left = sil.copy()
    left[:, 32:] = False
    outside = np.zeros_like(sil)
    outside[:5, :5] = True
    masks = np.stack([sil, left, outside, sil | outside])
    rot = np.zeros((4, 2, 3))
    iou = cp.body_silhouette_iou(ball, rot, np.zeros((4, 3)), cam, masks)
    assert iou.shape == (4,)
    assert iou[0] == 1.0 and iou[2] == 0.0
    assert iou[1] == pytest.approx(left.sum() / sil.sum(), abs=1e-12)
    assert iou[3] == pytest.approx(sil.sum() / (sil.sum() + 25), abs=1e-12)
    # the pose moves the body: a ball moved out of view overlaps nothing, and an empty union scores 0
    gone = cp.body_silhouette_iou(ball, rot[:2], np.array([[0.0, 0.0, 0.0], [9.0, 0.0, 0.0]]), cam,
                                  np.stack([sil, np.zeros_like(sil)]))
    assert np.array_equal(gone, [1.0, 0.0])


# ------------------------------------------------------------------------------------------ §5.1 with known lights


def side_wall():
    """A 2 x 2 m square at x = 1.5 (outside the camera's view) between the ball and a light along +x."""
    V = np.array([[1.5, -1.0, -1.0], [1.5, 1.0, -1.0], [1.5, 1.0, 1.0], [1.5, -1.0, 1.0]])
    return V, np.array([[0, 1, 2], [0, 2, 3]])


def ball_and_wall():
    V, F = icosphere()
    WV, WF = side_wall()
    return np.vstack([V, WV]), np.vstack([F, WF + len(V)]), len(V)


def test_observed_albedo_divides_out_the_shadowed_shading():
    """Every ball vertex facing the light is shadowed by the wall: its shading is the ambient alone, so the
    albedo of a frame of constant colour c is c / ambient (Lambert without the shadow would give less)."""
    V, F, nb = ball_and_wall()
    cam = front_camera()
    light = Lighting.single([1.0, 0.0, 0.0], 0.8, 0.4)
    frame = np.full((cam.height, cam.width, 3), [0.24, 0.12, 0.6])
    albedo = cp.observed_albedo([frame], [V], F, cam, light)
    ((ids, _),) = visible_vertex_colors([frame], [V], F, cam, 0.05)
    assert len(ids) > 100 and np.all(ids < nb)
    assert np.allclose(albedo[ids], [0.6, 0.3, 1.0], atol=1e-12)  # 0.6 / 0.4 = 1.5 clipped to 1
    unseen = np.setdiff1d(np.arange(len(V)), ids)
    assert np.allclose(albedo[unseen], [0.6, 0.3, 1.5], atol=1e-12)  # the unclipped mean of the seen


def test_observed_albedo_is_the_least_squares_ratio_over_frames():
    V, F, nb = ball_and_wall()
    cam = front_camera()
    light = Lighting.single([0.0, 0.6, 0.8], 0.7, 0.2)  # from above the camera: the ball is partly lit
    turned = V @ Rotation.from_rotvec([0, 0.5, 0]).as_matrix().T
    frames = [np.full((cam.height, cam.width, 3), [0.3, 0.2, 0.1]), np.full((cam.height, cam.width, 3), 0.5)]
    fallback = np.full((len(V), 3), 0.77)
    albedo = cp.observed_albedo(frames, [V, turned], F, cam, light, fallback, min_cos=0.2)
    num, den = np.zeros((len(V), 3)), np.zeros((len(V), 3))
    for (ids, colors), Vt in zip(visible_vertex_colors(frames, [V, turned], F, cam, 0.2), [V, turned], strict=True):
        S = vertex_shading(Vt, F, light, shadows=True)[ids]
        num[ids] += colors * S
        den[ids] += S * S
    seen = den.min(1) > 1e-6
    assert 100 < seen.sum() < nb
    assert np.allclose(albedo[seen], np.clip(num[seen] / den[seen], 0, 1), atol=1e-12)
    assert np.all(albedo[~seen] == 0.77) and np.all(fallback == 0.77)  # the fallback is copied, not written
    assert np.abs(albedo[seen] - 0.77).min() > 1e-6
    # a grazing min_cos sees more vertices than the default of visible_vertex_colors
    wide = cp.observed_albedo(frames, [V, turned], F, cam, light, fallback)
    assert (wide != 0.77).any(1).sum() > seen.sum()


def test_observed_albedo_without_any_seen_vertex_is_grey():
    V, F = icosphere()
    cam = front_camera()
    frame = np.full((cam.height, cam.width, 3), 0.3)
    albedo = cp.observed_albedo([frame], [V + [0.0, 0.0, 9.0]], F, cam, Lighting.single([0, 0, 1]))
    assert albedo.shape == (len(V), 3) and np.all(albedo == 0.5)


# ------------------------------------------------------------------------------------------ oracle fit errors


@dataclass
class ToyFit:
    rotations: np.ndarray
    translations: np.ndarray
    lighting: object
    silhouette_iou: np.ndarray
    camera: object
    masks: np.ndarray
    warnings: tuple = ()
    ball: Ball = field(default_factory=Ball)

    def body(self):
        return self.ball


def toy_fit(n=3, bones=4, lighting=True):
    from bodystudio.capture.render import render

    rng = np.random.default_rng(0)
    cam = front_camera(48)
    ball = Ball()
    sil = render(ball.vertices, ball.faces, cam).mask
    light = Lighting([[0, 0, 1], [0, 1, 1], [1, 0, 0]], [[0.5, 0.5, 0.5], [0.2, 0.1, 0.0], [0.1, 0.1, 0.1]],
                     [0.2, 0.2, 0.2]) if lighting else None
    return ToyFit(rng.normal(scale=0.5, size=(n, bones, 3)), np.zeros((n, 3)), light,
                  np.ones(n), cam, np.stack([sil] * n), ("oracle",), ball)


def test_perturbed_fit_turns_every_bone_moves_the_root_and_turns_the_lights_by_the_given_amounts():
    fit = toy_fit()
    out = cp.perturbed_fit(fit, seed=4, pose_deg=5.0, translation_m=0.03, light_deg=12.0)
    n, B, _ = fit.rotations.shape
    rel = Rotation.from_rotvec(out.rotations.reshape(-1, 3)) * Rotation.from_rotvec(fit.rotations.reshape(-1, 3)).inv()
    assert np.allclose(np.degrees(rel.magnitude()), 5.0, atol=1e-9)
    axes = rel.as_rotvec() / rel.magnitude()[:, None]
    assert np.abs(axes.mean(0)).max() < 0.6 and len(np.unique(axes.round(6), axis=0)) == n * B  # random, each anew
    shift = out.translations - fit.translations
    assert np.allclose(np.linalg.norm(shift, axis=1), 0.03, atol=1e-12)
    assert not np.allclose(shift[0], shift[1])
    # one rotation of 12 deg for all lights; colours and ambient unchanged
    R, _ = Rotation.align_vectors(out.lighting.directions, fit.lighting.directions)
    assert np.degrees(R.magnitude()) == pytest.approx(12.0, abs=1e-9)
    assert np.allclose(R.apply(fit.lighting.directions), out.lighting.directions, atol=1e-12)
    assert np.array_equal(out.lighting.colors, fit.lighting.colors)
    assert np.array_equal(out.lighting.ambient, fit.lighting.ambient)
    # the IoU is measured anew on the moved body (the toy body only moves with the root, 3 cm: still overlaps)
    want = cp.body_silhouette_iou(fit.ball, out.rotations, out.translations, fit.camera, fit.masks)
    assert np.array_equal(out.silhouette_iou, want) and np.all(want < 1.0) and np.all(want > 0.5)
    assert out.warnings == ("perturbed oracle fit: 5 deg per bone, 3 cm root, lights 12 deg (seed 4)",)
    assert fit.warnings == ("oracle",) and fit.silhouette_iou.tolist() == [1.0, 1.0, 1.0]


def test_perturbed_fit_is_reproducible_per_seed_and_zero_is_the_identity():
    fit = toy_fit()
    a = cp.perturbed_fit(fit, seed=1)
    b = cp.perturbed_fit(fit, seed=1)
    c = cp.perturbed_fit(fit, seed=2)
    assert np.array_equal(a.rotations, b.rotations) and np.array_equal(a.translations, b.translations)
    assert np.array_equal(a.lighting.directions, b.lighting.directions)
    assert not np.allclose(a.rotations, c.rotations)
    rel = Rotation.from_rotvec(a.rotations.reshape(-1, 3)) * Rotation.from_rotvec(fit.rotations.reshape(-1, 3)).inv()
    assert np.allclose(np.degrees(rel.magnitude()), 3.0, atol=1e-9)  # the defaults: 3 deg, 1.5 cm, 10 deg
    assert np.allclose(np.linalg.norm(a.translations - fit.translations, axis=1), 0.015, atol=1e-12)
    R, _ = Rotation.align_vectors(a.lighting.directions, fit.lighting.directions)
    assert np.degrees(R.magnitude()) == pytest.approx(10.0, abs=1e-9)
    assert a.warnings == ("perturbed oracle fit: 3 deg per bone, 1.5 cm root, lights 10 deg (seed 1)",)
    zero = cp.perturbed_fit(fit, pose_deg=0.0, translation_m=0.0, light_deg=0.0)
    assert np.allclose(zero.rotations, fit.rotations, atol=1e-12)
    assert np.allclose(zero.translations, fit.translations, atol=1e-15)
    assert np.allclose(zero.lighting.directions, fit.lighting.directions, atol=1e-15)
    assert np.allclose(zero.silhouette_iou, 1.0)
    dark = cp.perturbed_fit(toy_fit(lighting=False))
    assert dark.lighting is None


# ------------------------------------------------------------------------------------------ §7 on a toy frame


def toy_layer(H=40, W=48):
    """A body square (depth 2 m) with a garment on its lower part (depth 1.9 m, whole: also behind the arm) and
    an arm strip across it in front of the garment (body depth 1.5 m)."""
    body_mask = np.zeros((H, W), bool)
    body_mask[8:32, 10:38] = True
    g_mask = np.zeros((H, W), bool)
    g_mask[14:32, 10:38] = True  # trousers: the sides and the bottom are silhouette, the top a hem on the skin
    body_depth = np.where(body_mask, 2.0, 0.0).astype(np.float32)
    body_depth[18:22, 5:43] = 1.5  # the arm, in front of the garment
    body_mask[18:22, 5:43] = True
    g_depth = np.where(g_mask, 1.9, 0.0).astype(np.float32)
    rgb = np.zeros((H, W, 3), np.float32)
    rgb[g_mask] = [0.2, 0.4, 0.6]
    body_image = (body_mask[..., None] * np.full(3, 0.5)).astype(np.float32)
    return SimpleNamespace(rgb=rgb, mask=g_mask, depth=g_depth, body_image=body_image, body_mask=body_mask,
                           body_depth=body_depth)


def test_compositing_keeps_the_nearer_layer_per_pixel():
    layer = toy_layer()
    H, W = layer.mask.shape
    frame = np.full((H, W, 3), 7, np.uint8)
    person = layer.body_mask.copy()
    out = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False)
    behind_arm = layer.mask & (layer.body_depth < layer.depth) & (layer.body_depth > 0)
    assert behind_arm.sum() == 4 * 28
    assert np.array_equal(out.garment_mask, layer.mask & ~behind_arm)
    assert np.array_equal(out.image[out.garment_mask], np.tile([51, 102, 153], (out.garment_mask.sum(), 1)))
    assert np.all(out.image[~out.garment_mask] == 7)
    assert np.array_equal(out.unrefined_mask, out.garment_mask)
    assert out.field.shape == (H, W, 2) and np.all(out.field == 0)
    assert set(out.timings_ms) == {"flow", "rbf", "composite"} and min(out.timings_ms.values()) >= 0
    # the ablation lays the garment over the arm
    flat = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False, depth=False)
    assert np.array_equal(flat.garment_mask, layer.mask)
    assert np.array_equal(flat.unrefined_mask, out.garment_mask)  # the plain 3D composite always uses depth


def test_rbf_refinement_is_the_silhouette_warp_of_eq_9_written_out():
    layer = toy_layer()
    H, W = layer.mask.shape
    frame = np.full((H, W, 3), 7, np.uint8)
    person = np.zeros((H, W), bool)
    person[8:34, 8:40] = True  # the actor is a little wider and longer than the fitted body
    for sigma in (None, 4.0):
        out = cp.refine_and_composite(frame, person, layer, flow=False, rbf=True, sigma_px=sigma)
        src, tgt = refine.match_silhouettes(refine.outer_silhouette(layer.mask, layer.body_mask), person)
        assert len(src) > 10
        kwargs = {} if sigma is None else {"sigma_px": sigma}
        field = refine.concatenate_warps(np.zeros((H, W, 2), np.float32),
                                         refine.silhouette_rbf_warp(tgt, src - tgt, (H, W), **kwargs))
        assert np.abs(field).max() > 0.5
        assert np.allclose(out.field, field, atol=1e-6)
        g_mask = refine.warp_image(layer.mask, field)
        image, shown = refine.depth_composite(frame, refine.warp_image(layer.rgb, field), g_mask,
                                              refine.warp_image(layer.depth, field, nearest=True),
                                              refine.warp_image(layer.body_depth, field, nearest=True))
        assert np.array_equal(out.garment_mask, shown) and np.array_equal(out.image, image)
        assert not np.array_equal(shown, out.unrefined_mask)
    default = cp.refine_and_composite(frame, person, layer, flow=False, rbf=True)
    assert not np.allclose(default.field, out.field)


def test_flow_refinement_uses_the_motion_correction_field():
    layer = toy_layer()
    H, W = layer.mask.shape
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(size=(H, W, 3)).astype(np.float32), (0, 0), 1.5)
    layer.body_image = np.where(layer.body_mask[..., None], 0.2 + 0.6 * texture, 0.0).astype(np.float32)
    shifted = np.roll(layer.body_image, (1, 2), axis=(0, 1))
    frame = np.clip(np.round(shifted * 255), 0, 255).astype(np.uint8)
    person = np.roll(layer.body_mask, (1, 2), axis=(0, 1))
    out = cp.refine_and_composite(frame, person, layer, flow=True, rbf=False)
    want = refine.garment_motion_correction(frame, person, layer.body_image, layer.body_mask, layer.mask)
    assert np.abs(want).max() > 0.5
    assert np.array_equal(out.field, want) and out.flow_applied
    # the gate's decision is reported (render.json's flow_applied): not asked for, or below what the flow resolves
    assert not cp.refine_and_composite(frame, person, layer, flow=False, rbf=False).flow_applied
    still = np.clip(np.round(layer.body_image * 255), 0, 255).astype(np.uint8)
    gated = cp.refine_and_composite(still, layer.body_mask, layer, flow=True, rbf=False)
    assert not gated.flow_applied and not gated.field.any()


def test_default_lighting_is_a_white_light_from_the_camera():
    cam = front_camera()
    light = cp.default_lighting(cam)
    assert np.allclose(light.directions, [[0, 0, 1]]) and np.allclose(light.colors, 0.7)
    assert np.allclose(light.ambient, 0.3)


# ------------------------------------------------------------------------------------------ frames in / out


def test_png_is_rgb_and_grey():
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0] = 200
    rgb[1, 2] = [1, 2, 3]
    back = cv2.imdecode(np.frombuffer(cp._png(rgb), np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(back[..., ::-1], rgb)
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5)
    assert np.array_equal(cv2.imdecode(np.frombuffer(cp._png(grey), np.uint8), cv2.IMREAD_UNCHANGED), grey)


def write_video(path, values, size=(32, 24)):
    from bodystudio.fileio import Mp4Writer

    w = Mp4Writer(path, size, 10.0)
    for v in values:
        w.write(np.full((size[1], size[0], 3), v, np.uint8))
    w.close()


def test_source_frames_read_a_video_in_the_fits_order(tmp_path):
    values = [10, 50, 90, 130, 170, 210]
    write_video(tmp_path / "clip.mp4", values)
    fit = SimpleNamespace(source="clip.mp4", frame_ids=np.array([3, 1, 1, 4, 0]), camera=SimpleNamespace(name="c"))
    frames = list(cp.source_frames(fit, tmp_path))  # a relative source is found next to the fit folder
    assert [f.shape for f in frames] == [(24, 32, 3)] * 5 and all(f.dtype == np.uint8 for f in frames)
    means = [float(f.mean()) for f in frames]
    assert np.allclose(means, [130, 50, 50, 170, 10], atol=4), means
    fit.source = str(tmp_path / "clip.mp4")
    assert len(list(cp.source_frames(fit))) == 5
    fit.frame_ids = np.array([5])  # the last frame
    assert abs(float(next(cp.source_frames(fit)).mean()) - 210) < 4


def test_source_frames_refuse_missing_sources_and_frames(tmp_path):
    write_video(tmp_path / "clip.mp4", [10, 50, 90])
    fit = SimpleNamespace(source=str(tmp_path / "clip.mp4"), frame_ids=np.array([1, 7, 9]),
                          camera=SimpleNamespace(name="c"))
    with pytest.raises(FileFormatError, match=exact(f"{tmp_path}/clip.mp4: frame 7 of the fit is missing from the "
                                                    "video (it has fewer frames); rerun 'bodystudio garment fit'")):
        list(cp.source_frames(fit))
    fit.source = str(tmp_path / "gone.mp4")
    gone = "gone.mp4: the fit's source video or session is gone; restore it or rerun 'bodystudio garment fit'"
    with pytest.raises(InputError, match=exact(f"{tmp_path}/{gone}")):
        list(cp.source_frames(fit, tmp_path))
    fit.source = "gone.mp4"  # relative, and not next to the fit either
    with pytest.raises(InputError, match=exact(f"{tmp_path}/{gone}")):
        list(cp.source_frames(fit, tmp_path))
    with pytest.raises(InputError, match=exact(gone)):
        list(cp.source_frames(fit))
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all")
    fit.source = str(tmp_path / "junk.mp4")
    with pytest.raises(FileFormatError, match=exact(f"{tmp_path}/junk.mp4: cannot read the video (Could not load meta "
                                                    "information); check the file")):
        list(cp.source_frames(fit))


# ------------------------------------------------------------------------------------------ the render loop


def person_of(layer):
    """The actor's matte: the fitted body one pixel wider on each side (the RBF warp has something to do)."""
    return cv2.dilate(layer.body_mask.astype(np.uint8), np.ones((1, 3), np.uint8)) > 0


def stand_in_render(monkeypatch, frames, iou, lighting=None):
    """A fit over ``frames`` whose 3D pass is :func:`toy_layer` (the garment, body and dressing stand-ins)."""
    import bodystudio.garment.garments as garments
    import bodystudio.garment.render as render

    H, W = frames[0].shape[:2]
    calls = {"render": [], "dress": [], "layer": [], "frames": [], "staged": [], "render_dir": []}

    def fake_layer(V, F, cloth, garment_V, camera, lighting, albedo, shadows):
        if calls["render_dir"]:
            calls["staged"].append(sorted(p.name for p in calls["render_dir"][0].iterdir()))
        calls["render"].append((lighting, albedo, shadows))
        calls["layer"].append((V, F, cloth, garment_V, camera))
        return toy_layer(H, W)

    def fake_dress(body, garment, texture, size, seed):
        calls["dress"].append((garment, texture, size, seed))
        return "cloth"

    monkeypatch.setattr(render, "render_garment_layer", fake_layer)
    monkeypatch.setattr(garments, "dress", fake_dress)
    monkeypatch.setattr(garments, "pose_garment", lambda cloth, body, pose: ("garment_V", cloth, body, pose))

    def fake_frames(fit, fit_dir):
        calls["frames"].append((fit, fit_dir))
        return iter(frames)

    monkeypatch.setattr(cp, "source_frames", fake_frames)
    n = len(frames)
    body = SimpleNamespace(n_vertices=5, faces="faces", pose=lambda pose: (("V", pose), None))
    fit = SimpleNamespace(frame_ids=np.arange(n) * 3 + 2, camera=SimpleNamespace(height=H, width=W,
                                                                                 center=np.array([0.0, 0.0, 2.0])),
                          silhouette_iou=np.asarray(iou, float), lighting=lighting, albedo=np.zeros((5, 3)),
                          fps=12.0, source="toy", masks=np.stack([person_of(toy_layer(H, W))] * n),
                          body=lambda: body, pose=lambda i: ("pose", i))
    return fit, calls


def test_render_loop_composites_fitted_frames_and_passes_the_others_through(tmp_path, monkeypatch):
    H, W = 40, 48
    frames = [np.full((H, W, 3), 10 * (i + 1), np.uint8) for i in range(3)]
    fit, calls = stand_in_render(monkeypatch, frames, [0.9, 0.5, 0.95])
    calls["render_dir"].append(tmp_path / "fit" / "render")
    doc = cp.render_garment_video(tmp_path / "fit", "skirt", "checks", fit=fit, seed=3, texture_size=32,
                                  shadows=False, min_frame_iou=0.8)
    assert calls["staged"][0] == [".lock", ".staging"]  # the run folder's lock and staging while it renders
    assert sorted(p.name for p in (tmp_path / "fit" / "render").iterdir()) == ["frames", "garment_masks",
                                                                               "render.json"]
    assert calls["dress"] == [("skirt", "checks", 32, 3)]
    assert len(calls["render"]) == 2  # the passed-through frame is not rendered
    assert calls["frames"] == [(fit, tmp_path / "fit")]
    body = fit.body()
    assert calls["layer"] == [(("V", ("pose", i)), "faces", "cloth", ("garment_V", "cloth", body, ("pose", i)),
                               fit.camera) for i in (0, 2)]
    light, albedo, shadows = calls["render"][0]
    assert np.allclose(light.directions, [[0, 0, 1]]) and np.allclose(light.ambient, 0.3)  # the default lights
    assert albedo is fit.albedo and shadows is False
    assert doc["format"] == "bodystudio-garment-render" and doc["version"] == 1
    assert doc["garment"] == "skirt" and doc["texture"] == "checks" and doc["seed"] == 3 and doc["texture_size"] == 32
    assert doc["options"] == {"flow": True, "rbf": True, "depth": True, "hem": True, "shadows": False}
    assert doc["min_frame_iou"] == 0.8 and doc["n_passed_through"] == 1 and doc["video"] is None
    assert doc["frame_ids"] == [2, 5, 8] and doc["fit"] == str(tmp_path / "fit")
    assert [f["status"] for f in doc["frames"]] == ["ok", "passed_through", "ok"]
    assert [f["frame"] for f in doc["frames"]] == [2, 5, 8]
    assert doc["frames"][1]["garment_px"] == 0 and doc["frames"][0]["garment_px"] > 300
    assert set(doc["frames"][0]["ms"]) == {"render", "flow", "rbf", "composite", "write"}
    assert set(doc["frames"][1]["ms"]) == {"write"}
    assert set(doc["ms_per_frame"]) == {"render", "flow", "rbf", "composite", "write"}
    assert doc["ms_per_frame_statistic"] == "median" and doc["wall_s"] >= 0
    out = tmp_path / "fit" / "render"
    assert json.loads((out / "render.json").read_text())["frames"] == doc["frames"]
    for fid, frame in zip((2, 5, 8), frames, strict=True):
        img = cv2.imread(str(out / "frames" / f"{fid:05d}.png"))[..., ::-1]
        mask = cv2.imread(str(out / "garment_masks" / f"{fid:05d}.png"), cv2.IMREAD_GRAYSCALE)
        assert set(np.unique(mask)) <= {0, 255}
        if fid == 5:
            assert np.array_equal(img, frame) and not mask.any()
        else:
            assert (mask == 255).sum() == doc["frames"][[2, 5, 8].index(fid)]["garment_px"]
            assert np.all(img[mask == 0] == frame[mask == 0]) and np.any(img[mask == 255] != frame[mask == 255])
    loaded = cp.load_render(tmp_path / "fit")
    assert loaded["frames"] == doc["frames"]


def test_render_loop_options_lights_and_video(tmp_path, monkeypatch):
    H, W = 40, 48
    frames = [np.full((H, W, 3), 60, np.uint8)] * 2
    lights = Lighting.single([0, 1, 0], 0.5, 0.1)
    fit, calls = stand_in_render(monkeypatch, frames, [MIN_FRAME_IOU, 0.9], lighting=lights)  # >= passes
    fit.albedo = np.zeros((4, 3))  # not one per body vertex: the render falls back to its own
    video = tmp_path / "out.mp4"
    doc = cp.render_garment_video(tmp_path / "fit", fit=fit, out_video=video, flow=False, rbf=False, depth=False,
                                  hem=False)
    assert calls["dress"] == [("tshirt", "stripes", 512, 0)]
    light, albedo, shadows = calls["render"][0]
    assert light is lights and albedo is None and shadows is True
    assert doc["options"] == {"flow": False, "rbf": False, "depth": False, "hem": False, "shadows": True}
    assert doc["n_hem_applied"] == 0 and not any(f["hem_applied"] for f in doc["frames"])
    assert doc["video"] == str(video) and video.read_bytes()[4:8] == b"ftyp"
    assert doc["min_frame_iou"] == MIN_FRAME_IOU and doc["n_passed_through"] == 0
    assert all(f["garment_px"] == toy_layer(H, W).mask.sum() for f in doc["frames"])  # no depth test


@pytest.mark.parametrize("kwargs, error, phrase", [
    ({"garment": "cape"}, InputError, "--garment 'cape': valid: " + ", ".join(GARMENTS)),
    ({"texture": "tartan"}, InputError, "--texture 'tartan': valid: " + ", ".join(PATTERNS)),
    ({"seed": -1}, InputError, "--seed -1: must be in [0, 2^32)"),
    ({"texture_size": 8}, InputError, "texture size 8 must lie in [16, 4096]"),
    ({"texture_size": 15}, InputError, "texture size 15 must lie in [16, 4096]"),
    ({"texture_size": 4097}, InputError, "texture size 4097 must lie in [16, 4096]"),
    ({"min_frame_iou": 0.99}, InputError, "{fit}: no frame of the fit matches the person's silhouette (IoU >= 0.99); "
                                          "rerun 'bodystudio garment fit' (nothing to render)"),
])
def test_render_refuses_bad_options_before_writing(tmp_path, monkeypatch, kwargs, error, phrase):
    frames = [np.full((40, 48, 3), 60, np.uint8)]
    fit, calls = stand_in_render(monkeypatch, frames, [0.9])
    with pytest.raises(error, match=exact(phrase.format(fit=tmp_path / "fit"))):
        cp.render_garment_video(tmp_path / "fit", fit=fit, **kwargs)
    assert not (tmp_path / "fit" / "render").exists() and calls["render"] == []


def test_render_refuses_a_frame_of_another_size(tmp_path, monkeypatch):
    fit, _ = stand_in_render(monkeypatch, [np.full((40, 48, 3), 60, np.uint8)], [0.9])
    monkeypatch.setattr(cp, "source_frames", lambda fit, fit_dir: iter([np.zeros((40, 50, 3), np.uint8)]))
    with pytest.raises(FileFormatError, match=exact("toy: frame 2 is 50x40, the fit's camera 48x40; rerun 'bodystudio "
                                                    "garment fit'")):
        cp.render_garment_video(tmp_path / "fit", fit=fit)
    assert not (tmp_path / "fit" / "render" / "render.json").exists()


def test_check_render_options():
    assert cp.check_render_options("skirt", "checks", None) is None
    assert str(cp.check_render_options("skirt", "checks", "a/b/OUT.MP4", seed=2**32 - 1)) == "a/b/OUT.MP4"
    assert cp.check_render_options("skirt", "checks", None, seed=0) is None
    with pytest.raises(InputError, match=exact("--out x.avi: the video must be an .mp4 file")):
        cp.check_render_options("skirt", "checks", "x.avi")
    for seed in (2**32, 1.5, -1):
        with pytest.raises(InputError, match=exact(f"--seed {seed}: must be in [0, 2^32)")):
            cp.check_render_options("skirt", "checks", None, seed=seed)


def test_load_render_refuses_missing_damaged_and_foreign_files(tmp_path):
    path = tmp_path / "render" / "render.json"
    with pytest.raises(FileFormatError, match=exact(f"{path}: not found; run 'bodystudio garment render {tmp_path} "
                                                    "--out OUT.mp4' first")):
        cp.load_render(tmp_path)
    (tmp_path / "render").mkdir()
    (tmp_path / "render" / "render.json").write_text("{not json")
    with pytest.raises(FileFormatError, match=re.escape(f"{path}: unreadable (") + ".+"
                                              + re.escape("); rerun 'bodystudio garment render'") + "$"):
        cp.load_render(tmp_path)
    (tmp_path / "render" / "render.json").write_text('{"format": "bodystudio-garment-fit"}')
    foreign = f"{path}: not a garment render; rerun 'bodystudio garment render'"
    with pytest.raises(FileFormatError, match=exact(foreign)):
        cp.load_render(tmp_path)
    (tmp_path / "render" / "render.json").write_text('{"format": "bodystudio-garment-render", "x": 1}')
    assert cp.load_render(tmp_path) == {"format": "bodystudio-garment-render", "x": 1}


# ------------------------------------------------------------------------------------------ evaluation


def ssim_reference(a, b):
    """Wang et al. 2004 written out: Gaussian window sigma 1.5 (13 taps, mirrored border), 8-bit constants."""
    a, b = a.astype(np.float64), b.astype(np.float64)

    def blur(x):
        sigma = (1.5, 1.5, 0) if x.ndim == 3 else 1.5
        return scipy.ndimage.gaussian_filter(x, sigma, mode="mirror", truncate=4.0)

    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b, cov = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    s = (2 * mu_a * mu_b + c1) * (2 * cov + c2) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return s.mean(axis=2) if s.ndim == 3 else s


def test_ssim_map_is_wang_et_al_written_out():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, size=(20, 24, 3)).astype(np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-40, 40, size=a.shape), 0, 255).astype(np.uint8)
    got = cp.ssim_map(a, b)
    assert got.shape == (20, 24)
    assert np.abs(got - ssim_reference(a, b)).max() < 1e-9
    assert np.abs(cp.ssim_map(a[..., 0], b[..., 0]) - ssim_reference(a[..., 0], b[..., 0])).max() < 1e-9
    assert np.allclose(cp.ssim_map(a, a), 1.0)
    # flat images: SSIM is the luminance term (2 mu_a mu_b + c1) / (mu_a^2 + mu_b^2 + c1)
    c1 = (0.01 * 255) ** 2
    flat = cp.ssim_map(np.full((9, 9), 100.0), np.full((9, 9), 50.0))
    assert np.allclose(flat, (2 * 100 * 50 + c1) / (100**2 + 50**2 + c1))
    # a wider window is a different measure
    assert np.abs(cp.ssim_map(a, b, sigma=3.0) - got).max() > 1e-3


def test_render_target_mismatch():
    doc = {"garment": "skirt", "texture": "checks", "seed": 2}
    assert cp.render_target_mismatch(doc, None) == "the session has no gt/garment.json (not a 'synth garment' session)"
    gt = {"target": {"name": "skirt", "pattern": "checks", "seed": 2}}
    assert cp.render_target_mismatch(doc, gt) is None
    msg = cp.render_target_mismatch({**doc, "seed": 5}, gt)
    assert msg == ("rendered checks skirt with --seed 5 but the session's target is checks skirt with seed 2; "
                   "render with --garment skirt --texture checks --seed 2")
    assert cp.render_target_mismatch({**doc, "texture": "print"}, gt).startswith("rendered print skirt")
    assert cp.render_target_mismatch(doc, {}).endswith("--garment None --texture None --seed None")


def test_perturbed_fit_default_seed_is_zero():
    fit = toy_fit()
    assert np.array_equal(cp.perturbed_fit(fit).rotations, cp.perturbed_fit(fit, seed=0).rotations)


# ------------------------------------------------------------------------------------------ oracle fit / scoring


def stand_in_session(tmp_path, monkeypatch, appearance=True, fps=True):
    """A synthetic garment session's ground truth around a ball body (``build_body`` stood in)."""
    import bodystudio.body
    from bodystudio.body.pose import Pose

    built = []

    def fake_build_body(phenotype, local, resolution):
        built.append((phenotype, local, resolution))
        return Ball()

    monkeypatch.setattr(bodystudio.body, "build_body", fake_build_body)
    ball = Ball()
    cams = {"cam_00": front_camera(), "cam_01": Camera.look_at("cam_01", (0.5, 0.0, 3.0), (0, 0, 0), fx=150,
                                                                 width=64, height=64)}
    light = Lighting.single([0.0, 0.6, 0.8], 0.7, 0.3)
    frames = {}
    for k, fid in enumerate((4, 9)):
        t = np.array([0.05 * k, 0.0, 0.0])
        from bodystudio.capture.render import render

        masks = {name: render(ball.vertices + t, ball.faces, cam).mask for name, cam in cams.items()}
        images = {name: np.full((64, 64, 3), 40 + 100 * k, np.uint8) for name in cams}
        frames[fid] = SimpleNamespace(gt_pose=Pose(np.full((2, 3), 0.1 * k), t), masks=masks, images=images)
    session = SimpleNamespace(
        path=tmp_path / "session", camera_names=list(cams), cameras=cams, frame_ids=[4, 9],
        gt_subject={"bone_names": ["Root", "spine_02"], "phenotype": {"height": 0.6}, "local": {"neck": 0.2},
                    "template": "6k", "stature_m": 1.72},
        gt_lighting=light.to_dict(), gt_garment={"target": {"name": "skirt", "pattern": "checks", "seed": 3}},
        gt_appearance_albedo=np.full((ball.n_vertices, 3), 0.33) if appearance else None,
        metadata={"fps": 25.0} if fps else {}, frame=lambda fid: frames[fid])
    return session, built, light


def test_ground_truth_fit_is_the_sessions_truth(tmp_path, monkeypatch):
    from bodystudio.body.phenotype import Phenotype

    session, built, light = stand_in_session(tmp_path, monkeypatch)
    fit = cp.ground_truth_fit(session)
    assert len(built) == 1 and built[0][0] == Phenotype.from_dict({"height": 0.6})
    assert built[0][1] == {"neck": 0.2} and built[0][2] == "6k"
    assert fit.source == str(tmp_path / "session") and fit.fps == 25.0 and fit.camera is session.cameras["cam_00"]
    assert fit.frame_ids.dtype == np.int64 and fit.frame_ids.tolist() == [4, 9]
    assert fit.template == "6k" and fit.bone_names == ("Root", "spine_02") and fit.stature_m == 1.72
    assert fit.phenotype == {"height": 0.6} and fit.local == {"neck": 0.2}
    assert np.array_equal(fit.rotations, [np.zeros((2, 3)), np.full((2, 3), 0.1)])
    assert np.array_equal(fit.translations, [[0, 0, 0], [0.05, 0, 0]])
    f4, f9 = session.frame(4), session.frame(9)
    assert np.array_equal(fit.masks, [f4.masks["cam_00"], f9.masks["cam_00"]])
    assert np.allclose(fit.silhouette_iou, 1.0)  # the true pose covers the true mask
    assert np.array_equal(fit.lighting.directions, light.directions) and np.array_equal(fit.lighting.ambient,
                                                                                        light.ambient)
    ball = Ball()
    posed = [ball.vertices, ball.vertices + [0.05, 0, 0]]
    want = cp.observed_albedo([f4.images["cam_00"], f9.images["cam_00"]], posed, ball.faces, session.cameras["cam_00"],
                              light, session.gt_appearance_albedo)
    assert np.array_equal(fit.albedo, want) and np.any(fit.albedo != 0.33) and np.any(fit.albedo == 0.33)
    assert fit.warnings == ("oracle fit: the session's ground truth",)
    other = cp.ground_truth_fit(session, "cam_01")
    assert other.camera is session.cameras["cam_01"]
    assert np.array_equal(other.masks[1], f9.masks["cam_01"]) and not np.array_equal(other.masks[1], fit.masks[1])


def test_ground_truth_fit_without_appearance_or_fps(tmp_path, monkeypatch):
    session, _, light = stand_in_session(tmp_path, monkeypatch, appearance=False, fps=False)
    fit = cp.ground_truth_fit(session)
    assert fit.fps == 30.0
    ball = Ball()
    posed = [ball.vertices, ball.vertices + [0.05, 0, 0]]
    images = [session.frame(f).images["cam_00"] for f in (4, 9)]
    assert np.array_equal(fit.albedo, cp.observed_albedo(images, posed, ball.faces, session.cameras["cam_00"], light))


@pytest.mark.parametrize("missing", ["gt_subject", "gt_lighting", "gt_garment"])
def test_ground_truth_fit_needs_a_synthetic_garment_session(tmp_path, monkeypatch, missing):
    session, built, _ = stand_in_session(tmp_path, monkeypatch)
    setattr(session, missing, None)
    with pytest.raises(InputError, match=exact(f"{tmp_path}/session: not a synthetic garment session (no "
                                               "gt/phenotype.json, gt/lighting.json or gt/garment.json); make one "
                                               "with 'bodystudio synth garment'")):
        cp.ground_truth_fit(session)
    assert built == []


def scored_render(tmp_path, monkeypatch):
    """A stand-in render (frames 2, 5, 8; frame 5 passed through) and a session whose truth scores it."""
    from bodystudio.capture.session import LAYER_BODY, LAYER_GARMENT

    H, W = 40, 48
    frames = [np.full((H, W, 3), 10 * (i + 1), np.uint8) for i in range(3)]
    fit, _ = stand_in_render(monkeypatch, frames, [0.9, 0.5, 0.95])
    cp.render_garment_video(tmp_path / "fit", "skirt", "checks", fit=fit, seed=3, min_frame_iou=0.8)
    render_dir = tmp_path / "fit" / "render"
    layer = toy_layer(H, W)
    truth = {}
    rng = np.random.default_rng(0)
    for k, fid in enumerate((2, 5, 8)):
        labels = np.where(layer.body_mask, LAYER_BODY, 0).astype(np.uint8)
        labels[layer.mask] = LAYER_GARMENT
        labels[:, : 3 + 4 * k] = 0  # the true person differs per frame
        target = cv2.imread(str(render_dir / "frames" / f"{fid:05d}.png"))[..., ::-1].copy()
        if fid != 8:  # frame 8: the render is exactly right
            target = np.clip(target.astype(int) + rng.integers(-20, 20, size=target.shape), 0, 255).astype(np.uint8)
        truth[fid] = SimpleNamespace(gt_target_layers={"c": labels}, gt_target={"c": target})
    session = SimpleNamespace(gt_garment={"target": {"name": "skirt", "pattern": "checks", "seed": 3}},
                              camera_names=["c"], frame=lambda fid: truth[fid])
    return session, render_dir, truth


def test_composite_errors_are_iou_psnr_and_ssim_in_the_true_person(tmp_path, monkeypatch):
    from bodystudio.capture.session import LAYER_GARMENT

    session, render_dir, truth = scored_render(tmp_path, monkeypatch)
    got = cp.composite_errors(tmp_path / "fit", session)
    ious, psnrs, ssims = [], [], []
    for fid in (2, 5, 8):
        img = cv2.imread(str(render_dir / "frames" / f"{fid:05d}.png"))[..., ::-1]
        shown = cv2.imread(str(render_dir / "garment_masks" / f"{fid:05d}.png"), cv2.IMREAD_GRAYSCALE) > 127
        labels, target = truth[fid].gt_target_layers["c"], truth[fid].gt_target["c"]
        garment = labels == LAYER_GARMENT
        ious.append((shown & garment).sum() / (shown | garment).sum())
        person = labels > 0
        mse = np.mean((img[person].astype(float) - target[person]) ** 2)
        psnrs.append(10 * np.log10(255.0**2 / mse) if mse > 0 else np.inf)
        ssims.append(ssim_reference(img, target)[person].mean())
    assert ious[1] == 0.0 and 0 < ious[0] < 1 and psnrs[2] == np.inf and np.isfinite(psnrs[0])
    assert got["garment_iou"] == pytest.approx(np.mean(ious), abs=1e-12)
    assert got["garment_iou_per_frame"] == [round(v, 4) for v in ious]
    assert got["psnr_person"] == np.inf  # one exact frame
    assert got["psnr_person_per_frame"][:2] == [round(v, 2) for v in psnrs[:2]]
    assert got["ssim_person"] == pytest.approx(np.mean(ssims), abs=1e-9)
    assert got["render_options"] == {"flow": True, "rbf": True, "depth": True, "hem": True, "shadows": True}
    assert set(got["render_ms_per_frame"]) == {"render", "flow", "rbf", "composite", "write"}


def test_composite_errors_of_empty_regions_and_damaged_renders(tmp_path, monkeypatch):
    session, render_dir, truth = scored_render(tmp_path, monkeypatch)
    for fid in (2, 5, 8):
        truth[fid].gt_target_layers["c"] = np.zeros_like(truth[fid].gt_target_layers["c"])
    got = cp.composite_errors(tmp_path / "fit", session)
    assert got["garment_iou_per_frame"] == [0.0, 1.0, 0.0]  # no true garment: 0, unless none is shown either
    assert got["psnr_person"] == np.inf and got["ssim_person"] == 1.0
    truth[5].gt_target_layers["c"] = np.zeros((10, 10), np.uint8)
    with pytest.raises(FileFormatError, match=exact(f"{render_dir}: frame 5 is missing or damaged; rerun 'bodystudio "
                                                    "garment render'")):
        cp.composite_errors(tmp_path / "fit", session)
    truth[5].gt_target_layers["c"] = np.zeros((40, 48), np.uint8)
    (render_dir / "garment_masks" / "00008.png").unlink()  # refused by load_render's checksums of the run
    with pytest.raises(FileFormatError, match=r"garment_masks/00008.png: missing, but .*render.json lists it"):
        cp.composite_errors(tmp_path / "fit", session)


def test_composite_errors_refuse_a_render_of_another_target(tmp_path, monkeypatch):
    session, render_dir, _ = scored_render(tmp_path, monkeypatch)
    session.gt_garment = {"target": {"name": "skirt", "pattern": "checks", "seed": 4}}
    mismatch = cp.render_target_mismatch(cp.load_render(tmp_path / "fit"), session.gt_garment)
    with pytest.raises(InputError, match=exact(f"{render_dir}: {mismatch}; the session's truth cannot score this "
                                               "render")):
        cp.composite_errors(tmp_path / "fit", session)


def test_load_render_refuses_interrupted_writes(tmp_path):
    from bodystudio.runfolder import OutputLockedError

    render_dir = tmp_path / "render"
    (render_dir / ".staging").mkdir(parents=True)
    (render_dir / "render.json").write_text('{"format": "bodystudio-garment-render"}')
    (render_dir / ".staging" / "frames.png").write_bytes(b"x")
    with pytest.raises(FileFormatError, match=exact(f"{render_dir}/.staging: an interrupted write left 1 uncommitted "
                                                    "files")):
        cp.load_render(tmp_path)
    (render_dir / ".staging" / "commit.json").write_text("{}")
    with pytest.raises(OutputLockedError, match=exact(f"{render_dir}: a write was interrupted while committing; run "
                                                      f"`bodystudio recover {render_dir}` to finish it")):
        cp.load_render(tmp_path)


def test_render_manifest_names_the_command_the_stage_and_reads_the_fit_folder(tmp_path, monkeypatch):
    import imageio_ffmpeg

    import bodystudio.garment.fitfile as fitfile

    frames = [np.full((40, 48, 3), 60, np.uint8)] * 2
    fit, calls = stand_in_render(monkeypatch, frames, [0.9, 0.9])
    read = []
    monkeypatch.setattr(fitfile, "load_garment_fit", lambda d: read.append(d) or fit)
    body = fit.body()
    fit.body = lambda: body
    dressed = []
    import bodystudio.garment.garments as garments

    monkeypatch.setattr(garments, "dress", lambda b, *args: dressed.append(b) or "cloth")
    video = tmp_path / "v.mp4"
    doc = cp.render_garment_video(tmp_path / "fit", texture_size=16, out_video=video)
    assert read == [tmp_path / "fit"] and dressed == [body]
    assert doc["run"]["command"] == "bodystudio garment render"
    assert doc["run"]["producer"] == {"stage": "garment", "kind": "render"}
    assert sorted(doc["run"]["files"]) == ["../../v.mp4", "frames/00002.png", "frames/00005.png",
                                           "garment_masks/00002.png", "garment_masks/00005.png"]
    reader = imageio_ffmpeg.read_frames(str(video))
    assert next(reader)["fps"] == 12.0
    reader.close()
    doc = cp.render_garment_video(tmp_path / "fit", texture_size=4096, command="bodystudio eval garment")
    assert doc["run"]["command"] == "bodystudio eval garment" and doc["texture_size"] == 4096


def test_refinement_defaults_field_type_and_step_timings(monkeypatch):
    import time as time_module

    layer = toy_layer()
    H, W = layer.mask.shape
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(size=(H, W, 3)).astype(np.float32), (0, 0), 1.5)
    layer.body_image = np.where(layer.body_mask[..., None], 0.2 + 0.6 * texture, 0.0).astype(np.float32)
    frame = np.clip(np.round(np.roll(layer.body_image, (1, 2), axis=(0, 1)) * 255), 0, 255).astype(np.uint8)
    person = np.roll(layer.body_mask, (1, 2), axis=(0, 1))
    layer.mask = np.zeros_like(layer.mask)
    layer.mask[29:32, 10:38] = True  # a hem strip: the flow is kept only within 15 px of it
    layer.rgb = (layer.mask[..., None] * np.full(3, 0.3)).astype(np.float32)
    both = cp.refine_and_composite(frame, person, layer)
    flow = cp.refine_and_composite(frame, person, layer, rbf=False)
    want = refine.garment_motion_correction(frame, person, layer.body_image, layer.body_mask, layer.mask)
    assert np.array_equal(flow.field, want)
    anywhere = refine.garment_motion_correction(frame, person, layer.body_image, layer.body_mask)
    assert not np.allclose(want, anywhere, atol=1e-3)
    rbf = cp.refine_and_composite(frame, person, layer, flow=False)
    src, tgt = refine.match_silhouettes(refine.outer_silhouette(refine.warp_image(layer.mask, want),
                                                                refine.warp_image(layer.body_mask, want)), person)
    assert np.allclose(both.field, refine.concatenate_warps(want, refine.silhouette_rbf_warp(tgt, src - tgt, (H, W))),
                       atol=1e-6)
    assert not np.allclose(both.field, flow.field) and not np.allclose(both.field, rbf.field)
    plain = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False)
    assert plain.field.dtype == np.float32 and both.field.dtype == np.float32
    # the step timings are milliseconds between the step boundaries
    ticks = iter(np.arange(10.0, 100.0, 0.25))
    monkeypatch.setattr(time_module, "perf_counter", lambda: float(next(ticks)))
    timed = cp.refine_and_composite(frame, person, layer, flow=False, rbf=False)
    assert timed.timings_ms == {"flow": 250.0, "rbf": 250.0, "composite": 250.0}


def test_source_frames_of_a_session_folder(tmp_path, monkeypatch):
    import bodystudio.capture.session as session_module

    (tmp_path / "session").mkdir()
    opened = []

    def fake_open(path):
        opened.append(path)
        images = {fid: {"cam_00": np.full((4, 4, 3), fid, np.uint8), "cam_01": np.full((4, 4, 3), 100 + fid,
                                                                                         np.uint8)}
                  for fid in range(10)}
        return SimpleNamespace(camera_names=["cam_00", "cam_01"],
                               frame=lambda fid: SimpleNamespace(images=images[fid]))

    monkeypatch.setattr(session_module, "open_session", fake_open)
    fit = SimpleNamespace(source=str(tmp_path / "session"), frame_ids=np.array([3, 7]),
                          camera=SimpleNamespace(name="cam_01"))
    assert [int(f[0, 0, 0]) for f in cp.source_frames(fit)] == [103, 107]
    assert opened == [tmp_path / "session"]
    fit.camera.name = "webcam"  # a video's camera: the session's first
    assert [int(f[0, 0, 0]) for f in cp.source_frames(fit)] == [3, 7]
    # a relative source that exists from here is read from here, not next to the fit
    monkeypatch.chdir(tmp_path)
    fit.source = "session"
    list(cp.source_frames(fit, tmp_path / "elsewhere"))
    assert opened[-1] == cp.Path("session")


def test_check_render_options_names_the_video_in_destination_errors(tmp_path):
    (tmp_path / "out.mp4").mkdir()
    with pytest.raises(InputError, match=exact(f"video {tmp_path}/out.mp4: is a folder; give a file path")):
        cp.check_render_options("skirt", "checks", tmp_path / "out.mp4")


def test_composite_errors_open_a_session_path_and_see_small_errors(tmp_path, monkeypatch):
    import bodystudio.capture.session as session_module

    session, render_dir, truth = scored_render(tmp_path, monkeypatch)
    img = cv2.imread(str(render_dir / "frames" / "00008.png"))[..., ::-1].copy()
    img[20, 20, 0] ^= 1  # one grey level in one pixel: MSE below 1, PSNR finite
    truth[8].gt_target["c"] = img
    opened = []
    monkeypatch.setattr(session_module, "open_session", lambda p: opened.append(p) or session)
    got = cp.composite_errors(tmp_path / "fit", str(tmp_path / "session"))
    assert opened == [str(tmp_path / "session")]
    person = (truth[8].gt_target_layers["c"] > 0).sum()
    assert got["psnr_person_per_frame"][2] == round(10 * np.log10(255.0**2 / (1 / (3 * person))), 2)


def test_ground_truth_fit_opens_a_session_path_and_names_it_in_errors(tmp_path, monkeypatch):
    import bodystudio.capture.session as session_module

    session, _, _ = stand_in_session(tmp_path, monkeypatch)
    opened = []
    monkeypatch.setattr(session_module, "open_session", lambda p: opened.append(p) or session)
    fit = cp.ground_truth_fit(tmp_path / "session")
    assert opened == [tmp_path / "session"] and fit.frame_ids.tolist() == [4, 9]
    session.gt_lighting = {"directions": [[0, 0, 1]], "colors": [[1, 1, 1]]}  # no ambient
    with pytest.raises(FileFormatError, match="^" + re.escape(f"{tmp_path}/session: lights need 'directions'")):
        cp.ground_truth_fit(session)


def test_render_loop_runs_the_refinement_it_is_asked_for_and_times_each_step(tmp_path, monkeypatch):
    H, W = 40, 48
    frames = [np.full((H, W, 3), 10 * (i + 1), np.uint8) for i in range(3)]
    fit, calls = stand_in_render(monkeypatch, frames, [0.9, 0.5, 0.95])
    ticks = iter(100.0 + 0.123456 * np.arange(100))
    monkeypatch.setattr(cp, "time", SimpleNamespace(perf_counter=lambda: float(next(ticks))))
    doc = cp.render_garment_video(tmp_path / "fit", fit=fit, min_frame_iou=0.8)
    step = {"render": 123.46, "flow": 123.46, "rbf": 123.46, "composite": 123.46, "write": 123.46}  # ms, 2 decimals
    for f in (doc["frames"][0], doc["frames"][2]):
        assert f["ms"] == step
    assert doc["frames"][1]["ms"] == {"write": 123.46}
    assert doc["frames"][1]["flow_applied"] is False  # passed through
    assert doc["n_flow_applied"] == sum(f["flow_applied"] for f in doc["frames"])
    assert doc["ms_per_frame"] == step
    assert doc["wall_s"] == 2.47  # 21 clock readings 0.123456 s apart
    monkeypatch.undo()
    fit, calls = stand_in_render(monkeypatch, frames, [0.9, 0.5, 0.95])
    for options in ({}, {"flow": False}, {"rbf": False}):
        out = tmp_path / f"fit{len(options)}{list(options)}"
        cp.render_garment_video(out, fit=fit, min_frame_iou=0.8, **options)
        img = cv2.imread(str(out / "render" / "frames" / "00002.png"))[..., ::-1]
        kwargs = {"flow": True, "rbf": True, **options}
        want = cp.refine_and_composite(frames[0], fit.masks[0], toy_layer(H, W), kwargs["flow"], kwargs["rbf"], True)
        assert np.array_equal(img, want.image), options
    plain = cp.refine_and_composite(frames[0], fit.masks[0], toy_layer(H, W), False, False, True)
    assert not np.array_equal(plain.image, cp.refine_and_composite(frames[0], fit.masks[0], toy_layer(H, W)).image)
