"""§7 image-space refinement: flow correction, the silhouette RBF warp (Eq. 9), depth compositing, and the
whole chain on a small synthetic case with a perturbed oracle fit (the errors of a real fit)."""

import numpy as np
import pytest

from bodystudio.capture.session import LAYER_GARMENT
from bodystudio.garment import refine


@pytest.fixture(scope="module")
def refine_case(tmp_path_factory):
    """6 walk frames at 240x320 (2k body), a perturbed oracle fit, and each frame's garment layer."""
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment_layer
    from bodystudio.garment.synthetic import synth_garment_session

    out = tmp_path_factory.mktemp("refine") / "session"
    session = synth_garment_session(out, subject_seed=4, n_frames=6, resolution=(240, 320), template="2k",
                                    texture_size=128, seed=1)
    fit = perturbed_fit(ground_truth_fit(session), seed=0)
    body = fit.body()
    g = session.gt_garment
    cloth = dress(body, g["target"]["name"], g["target"]["pattern"], g["texture_size"], g["target"]["seed"])
    frames = []
    for i, fid in enumerate(fit.frame_ids):
        f = session.frame(int(fid))
        V, _ = body.pose(fit.pose(i))
        layer = render_garment_layer(V, body.faces, cloth, pose_garment(cloth, body, fit.pose(i)), fit.camera,
                                     fit.lighting, fit.albedo, shadows=True)
        frames.append((f.images["cam_00"], fit.masks[i], layer, f.gt_target_layers["cam_00"] == LAYER_GARMENT))
    return session, fit, frames


def _mean_iou(frames, **options):
    from bodystudio.garment.composite import refine_and_composite

    full, plain = [], []
    for image, mask, layer, truth in frames:
        r = refine_and_composite(image, mask, layer, **options)
        full.append((r.garment_mask & truth).sum() / (r.garment_mask | truth).sum())
        plain.append((r.unrefined_mask & truth).sum() / (r.unrefined_mask | truth).sum())
    return float(np.mean(full)), float(np.mean(plain))


def test_refinement_raises_garment_iou(refine_case):
    """Measured, §7 without the hem matte: unrefined 0.81, full 0.968, without flow 0.897, without RBF 0.943, without
    depth 0.932; with the hem matte and the flow arbitrated by the video (gar13f): full 0.9925, without flow 0.964,
    without RBF 0.982, without depth 0.9896 (the depth test's margin here is 0.003, bound 0.002)."""
    _, _, frames = refine_case
    full, unrefined = _mean_iou(frames)
    full_no_hem, _ = _mean_iou(frames, hem=False)
    assert unrefined < 0.85  # the perturbation is large enough to matter
    assert full_no_hem >= 0.95 and full_no_hem >= unrefined + 0.10
    assert full >= full_no_hem + 0.01  # the hem matte earns its place
    for option in ("flow", "rbf", "depth"):  # each step earns its place: a skipped one loses IoU
        ablated, _ = _mean_iou(frames, hem=False, **{option: False})
        assert ablated <= full_no_hem - 0.01, (option, ablated, full_no_hem)
        ablated, _ = _mean_iou(frames, **{option: False})
        assert ablated <= full - (0.02 if option == "flow" else 0.005 if option == "rbf" else 0.002), (
            option, "with the hem matte", ablated, full)


def test_oracle_fit_composites_exactly(refine_case):
    """The true fit's garment layer, depth-composited without warps, is the true target layer."""
    from bodystudio.garment.composite import ground_truth_fit, refine_and_composite
    from bodystudio.garment.garments import dress, pose_garment
    from bodystudio.garment.render import render_garment_layer

    session, _, frames = refine_case
    fit = ground_truth_fit(session)
    body = fit.body()
    g = session.gt_garment
    cloth = dress(body, g["target"]["name"], g["target"]["pattern"], g["texture_size"], g["target"]["seed"])
    V, _ = body.pose(fit.pose(0))
    layer = render_garment_layer(V, body.faces, cloth, pose_garment(cloth, body, fit.pose(0)), fit.camera,
                                 fit.lighting, fit.albedo, shadows=True)
    r = refine_and_composite(frames[0][0], fit.masks[0], layer, flow=False, rbf=False, hem=False)
    truth = frames[0][3]
    assert (r.garment_mask ^ truth).sum() <= 0.002 * truth.sum()
    # the hem matte on the exact composite: the video's colours re-segment the hem bands, a few pixels off
    hem = refine_and_composite(frames[0][0], fit.masks[0], layer, flow=False, rbf=False)
    assert hem.hem_applied and (hem.garment_mask ^ truth).sum() <= 0.01 * truth.sum()  # measured 21 of 4080
    target = session.frame(0).gt_target["cam_00"].astype(int)
    assert np.median(np.abs(r.image.astype(int) - target)[truth]) <= 1  # same colours as the true render


def test_flow_correction_recovers_a_shift(refine_case):
    """The actor is the render moved by (5, -3) px: §7.1's backward field maps them back within 0.5 px."""
    _, _, frames = refine_case
    _, _, layer, _ = frames[2]
    shift = np.float32([[1, 0, 5], [0, 1, -3]])
    import cv2

    body8 = np.clip(np.round(layer.body_image * 255), 0, 255).astype(np.uint8)
    H, W = layer.body_mask.shape
    actor = cv2.warpAffine(body8, shift, (W, H))
    person = cv2.warpAffine(layer.body_mask.astype(np.uint8), shift, (W, H)) > 0
    field = refine.garment_motion_correction(actor, person, layer.body_image, layer.body_mask, layer.mask)
    inner = cv2.warpAffine(layer.mask.astype(np.uint8), shift, (W, H)) > 0
    inner = cv2.erode(inner.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    err = np.abs(np.median(field[inner], axis=0) - [-5, 3])
    assert err.max() < 0.5, np.median(field[inner], axis=0)


def test_rbf_warp_maps_boundary_points_onto_targets():
    """Eq. 9 solved as an interpolation: the field equals each displacement at its target; it falls off."""
    rng = np.random.default_rng(0)
    angles = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    targets = np.column_stack([100 + 40 * np.cos(angles), 80 + 30 * np.sin(angles)]).round()
    targets = np.unique(targets, axis=0)
    disp = rng.normal(0, 3, size=targets.shape) + [2.0, -1.0]
    field = refine.silhouette_rbf_warp(targets, disp, (200, 220))
    t = targets.astype(int)
    assert np.abs(field[t[:, 1], t[:, 0]] - disp).max() < 1e-3
    # the Gaussian falloff: 30 px from the silhouette (the ellipse's centre) the warp has faded out
    assert np.abs(field[80, 100]).max() < 0.05 and np.abs(field[0, 0]).max() == 0
    # warping a one-pixel image: the pixel at target + displacement lands on the target
    k = 7
    src = np.zeros((200, 220), np.float32)
    sx, sy = targets[k] + disp[k]
    x0, y0 = int(np.floor(sx)), int(np.floor(sy))
    src[y0:y0 + 2, x0:x0 + 2] = 1.0
    assert refine.warp_image(src, field)[int(targets[k, 1]), int(targets[k, 0])] == pytest.approx(1.0)
    # Shepard-normalised weights (the paper's printed form) would not be exact: residual > 0.5 px
    w = refine.inverse_multiquadric(np.linalg.norm(targets[:, None] - targets[None], axis=2))
    shepard = (w @ disp) / w.sum(1, keepdims=True)
    assert np.abs(shepard - disp).max() > 0.5


def test_matched_silhouette_pairs_lie_on_both_silhouettes():
    garment = np.zeros((120, 120), bool)
    garment[30:90, 30:90] = True
    person = np.zeros_like(garment)
    person[33:87, 35:92] = True  # the actor's torso: 3 px in at top/bottom, 5 px in left, 2 px out right
    pts = refine.outer_silhouette(garment, np.zeros_like(garment))
    src, tgt = refine.match_silhouettes(pts, person)
    assert len(src) > 40
    assert refine.mask_boundary(person)[tgt[:, 1].astype(int), tgt[:, 0].astype(int)].all()
    assert np.abs(src - tgt).max() <= 6
    field = refine.silhouette_rbf_warp(tgt, src - tgt, garment.shape)
    warped = refine.warp_image(garment, field)
    iou_before = (garment & person).sum() / (garment | person).sum()
    iou_after = (warped & person).sum() / (warped | person).sum()
    assert iou_after > 0.97 > iou_before


def test_depth_compositing_keeps_a_front_arm_in_front(garment_body, garments):
    from bodystudio.body import Pose
    from bodystudio.capture.motion import world_to_local_rotvecs
    from bodystudio.garment.garments import pose_garment
    from bodystudio.garment.lighting import Lighting
    from bodystudio.garment.render import render_garment, render_garment_layer
    from bodystudio.geometry.camera import Camera

    world = np.zeros((garment_body.skeleton.n_bones, 3))
    world[garment_body.skeleton.index("upperarm_r")] = (-0.6, 0.0, 0.8)
    world[garment_body.skeleton.index("lowerarm_r")] = (0.0, 1.6, 0.0)
    pose = Pose(world_to_local_rotvecs(garment_body.skeleton, world), np.zeros(3))
    camera = Camera.look_at("front", (0.0, 1.2, 2.5), (0, 1.1, 0), fx=500, width=240, height=320)
    shirt = garments["tshirt"]
    V, _ = garment_body.pose(pose)
    gV = pose_garment(shirt, garment_body, pose)
    light = Lighting.single((0.3, 0.8, 0.5), 0.7, 0.3)
    layer = render_garment_layer(V, garment_body.faces, shirt, gV, camera, light)
    frame = np.full((320, 240, 3), 7, np.uint8)
    image, shown = refine.depth_composite(frame, layer.rgb, layer.mask, layer.depth, layer.body_depth)
    arm = layer.mask & (layer.body_depth > 0) & (layer.body_depth < layer.depth)
    assert arm.sum() > 800  # the forearm covers part of the shirt
    assert not shown[arm].any() and (image[arm] == 7).all()  # the actor's own pixels stay in front
    truth = render_garment(V, garment_body.faces, shirt, gV, camera, light).garment_mask
    assert (shown ^ truth).sum() <= 0.002 * truth.sum()  # same visibility as one z-buffer for both
    _, over = refine.depth_composite(frame, layer.rgb, layer.mask, layer.depth, layer.body_depth, use_depth=False)
    assert over[arm].all()  # the ablation paints the shirt over the arm


def test_composite_errors_of_the_oracle_render(refine_case, tmp_path):
    """The true fit rendered without warps scores garment_iou ~1 and a high PSNR; the perturbed one does not."""
    from bodystudio.garment.composite import composite_errors, ground_truth_fit, render_garment_video
    from bodystudio.garment.fitfile import save_garment_fit

    session, fit, _ = refine_case
    target = session.gt_garment["target"]
    scores = {}
    for name, f in (("oracle", ground_truth_fit(session)), ("perturbed", fit)):
        save_garment_fit(tmp_path / name, f, "test")
        doc = render_garment_video(tmp_path / name, target["name"], target["pattern"], None, flow=False, rbf=False,
                                   seed=target["seed"], texture_size=session.gt_garment["texture_size"],
                                   min_frame_iou=0.0)
        assert doc["frame_ids"] == list(range(6)) and doc["n_flow_applied"] == 0  # flow=False: no correction
        scores[name] = composite_errors(tmp_path / name, session)
    assert np.all(ground_truth_fit(session).silhouette_iou > 0.95) and np.all(fit.silhouette_iou < 0.8)
    assert scores["oracle"]["garment_iou"] > 0.995 and scores["oracle"]["psnr_person"] > 35
    assert scores["oracle"]["ssim_person"] > 0.97
    assert scores["perturbed"]["garment_iou"] < 0.9 and scores["perturbed"]["psnr_person"] < 25


def test_render_reads_frames_from_a_video_source(refine_case, tmp_path):
    """A fit of a plain video file (the gfit CLI's other source) renders from the decoded frames."""
    from dataclasses import replace

    import imageio_ffmpeg

    from bodystudio.garment.composite import render_garment_video, source_frames
    from bodystudio.garment.fitfile import save_garment_fit

    session, fit, _ = refine_case
    video = tmp_path / "actor.mp4"
    frames = [session.frame(i).images["cam_00"] for i in range(6)]
    w = imageio_ffmpeg.write_frames(str(video), (240, 320), fps=30, macro_block_size=8, quality=9,
                                    ffmpeg_log_level="error")
    w.send(None)
    for f in frames:
        w.send(np.ascontiguousarray(f))
    w.close()
    video_fit = replace(fit, source=str(video), frame_ids=np.arange(6)[::-1].copy(),
                        rotations=fit.rotations[::-1].copy(), translations=fit.translations[::-1].copy(),
                        masks=fit.masks[::-1].copy())
    decoded = list(source_frames(video_fit))
    assert len(decoded) == 6 and all(np.abs(d.astype(int) - f.astype(int)).mean() < 6
                                     for d, f in zip(decoded, frames[::-1], strict=True))
    save_garment_fit(tmp_path / "fit", video_fit, "test")
    doc = render_garment_video(tmp_path / "fit", "tshirt", "checks", tmp_path / "out.mp4", min_frame_iou=0.0)
    assert doc["frame_ids"] == [5, 4, 3, 2, 1, 0] and (tmp_path / "out.mp4").stat().st_size > 1000


def test_median_outlier_removal_drops_spikes_only():
    """§7.1's outlier median: isolated wrong vectors in a smooth field are dropped, the rest kept."""
    yy, xx = np.mgrid[0:60, 0:80].astype(np.float32)
    flow = np.dstack([0.05 * xx, -0.03 * yy + 2])
    rng = np.random.default_rng(1)
    spikes = np.zeros((60, 80), bool)
    spikes[rng.integers(3, 57, 40), rng.integers(3, 77, 40)] = True
    flow[spikes] += [6.0, -5.0]
    valid = np.ones((60, 80), bool)
    kept = refine.median_outlier_removal(flow, valid)
    assert not kept[spikes].any() and kept[~spikes].mean() > 0.99


def test_domain_transform_fills_and_stops_at_edges():
    """The normalised domain-transform fill: a sparse field spreads over its region and not across an edge."""
    guide = np.zeros((60, 80, 3), np.uint8)
    guide[:, 40:] = 255
    field = np.zeros((60, 80, 2), np.float32)
    field[:, :40] = [3.0, -1.0]
    field[:, 40:] = [-2.0, 4.0]
    valid = np.zeros((60, 80), bool)
    valid[::7, 3:37:7] = True
    valid[::7, 43:77:7] = True
    out = refine.domain_transform_smoothing(field, valid, guide)
    assert np.abs(out[:, :38] - [3.0, -1.0]).max() < 0.05 and np.abs(out[:, 42:] - [-2.0, 4.0]).max() < 0.05
