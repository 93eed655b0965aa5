"""The garment stage in the viewer and the report: fitted body, garment, light arrows, before/after strips
(input | composite | truth) and the `eval garment` scores, also for incomplete fit folders."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest


@pytest.fixture(scope="module")
def garment_case(tmp_path_factory):
    """A 3-frame 120x160 synthetic garment session (2k body), its oracle fit with the lights turned 10 deg
    (pose and root exact, so every frame passes the fit's IoU gate) and the render of the target garment."""
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit, render_garment_video
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("garment-view")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=3, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    fit = perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0, light_deg=10.0)
    save_garment_fit(root / "fit", fit, "test")
    # the light is turned 10 deg about a random axis: its direction moves by this much (7.6 deg)
    light_err_deg = _angle_deg(fit.lighting.directions[0], session.gt_lighting["directions"][0])
    assert 5 < light_err_deg <= 10
    target = session.gt_garment["target"]
    render_garment_video(root / "fit", target["name"], target["pattern"], None, seed=target["seed"], texture_size=64)
    return {"root": root, "session": session, "fit_dir": root / "fit", "fit": fit, "light_err_deg": light_err_deg}


def _copy_fit(case, dest, render=True):
    shutil.copytree(case["fit_dir"], dest, ignore=None if render else shutil.ignore_patterns("render"))
    return dest


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_fit_and_render_folders_open_as_garment_views(garment_case):
    from bodystudio.viewer.garment import garment_choice, garment_frames
    from bodystudio.viewer.views import open_viewable

    item = open_viewable(garment_case["fit_dir"])
    assert item.kind == "garment" and item.data.render is not None and item.data.notes == ()
    via_render = open_viewable(garment_case["fit_dir"] / "render")
    assert via_render.kind == "garment" and via_render.data.fit_dir == garment_case["fit_dir"]
    assert garment_frames(item.data, 3) == [0, 1, 2] and garment_frames(item.data, 2) == [0, 2]
    target = garment_case["session"].gt_garment["target"]
    assert garment_choice(item.data) == (target["name"], target["pattern"], target["seed"], 64)
    # the render's garment first, then the session's target, then the default striped T-shirt
    other = {"garment": "skirt", "texture": "checks", "seed": 5, "texture_size": 32}
    assert garment_choice(replace(item.data, render=other)) == ("skirt", "checks", 5, 32)
    assert garment_choice(replace(item.data, render=None)) == (target["name"], target["pattern"], target["seed"], 64)
    assert garment_choice(replace(item.data, render=None, session=None)) == ("tshirt", "stripes", 0, 256)


def test_before_after_strip_is_input_composite_truth(garment_case):
    import cv2

    from bodystudio.viewer.garment import before_after_panels, before_after_strip, open_garment_view

    view = open_garment_view(garment_case["fit_dir"])
    panels = before_after_panels(view, 1)
    assert [c for c, _ in panels] == ["input", "composite", "truth"]
    frame = garment_case["session"].frame(1)
    composite = cv2.imread(str(garment_case["fit_dir"] / "render" / "frames" / "00001.png"))[..., ::-1]
    assert np.array_equal(panels[0][1], frame.images["cam_00"])
    assert np.array_equal(panels[1][1], composite) and not np.array_equal(composite, panels[0][1])
    assert np.array_equal(panels[2][1], frame.gt_target["cam_00"])
    strip = before_after_strip(view, 1)
    assert strip.shape == (320, 3 * 240, 3)  # 160-row video enlarged 2x for readable captions
    # below the caption each panel is its image, pixel for pixel
    assert np.array_equal(strip[40::2, 240:480:2], composite[20:])
    assert np.array_equal(strip[40::2, 480::2], frame.gt_target["cam_00"][20:])


def test_light_arrows_point_along_the_lights_scaled_by_power():
    from bodystudio.garment.lighting import Lighting
    from bodystudio.viewer.garment import ARROW_M, ARROW_OFFSET_M, light_arrows

    d = np.array([[0.0, 1.0, 1.0], [1.0, 0.2, 0.5], [-1.0, 0.5, 0.3], [0.0, 0.0, 1.0]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    colors = np.array([[0.1, 0.1, 0.1], [0.5, 0.4, 0.3], [0.001, 0.001, 0.001], [0.0, 0.0, 0.0]])
    origin = np.array([0.1, 1.2, -3.0])
    starts, vectors, power = light_arrows(Lighting(d, colors, np.full(3, 0.2)), origin)
    # brightest first, the 0.003 light (under 2 % of 1.2) and the dark one left out
    assert np.allclose(power, [1.2, 0.3])
    assert np.allclose(vectors / np.linalg.norm(vectors, axis=1, keepdims=True), d[[1, 0]], atol=1e-12)
    assert np.allclose(np.linalg.norm(vectors, axis=1), [ARROW_M, ARROW_M * 0.3 / 1.2])
    assert np.allclose(starts, origin + ARROW_OFFSET_M * d[[1, 0]])
    s, v, p = light_arrows(Lighting(d, np.zeros((4, 3)), np.full(3, 0.2)), origin)
    assert len(s) == len(v) == len(p) == 0


def test_true_lights_are_carried_camera_to_camera(garment_case):
    from bodystudio.geometry.camera import Camera
    from bodystudio.viewer.garment import open_garment_view, true_lighting_in_fit_frame

    view = open_garment_view(garment_case["fit_dir"])
    gt = garment_case["session"].gt_lighting
    d_true = np.asarray(gt["directions"], float)
    assert np.allclose(true_lighting_in_fit_frame(view).directions, d_true)  # the oracle's camera is the true one
    # a fit whose world is another camera's (here turned 45 deg about y): the same direction in camera axes
    cam = Camera.look_at("cam_00", (0.0, 1.0, 0.0), (1.0, 1.0, -1.0), fx=200, width=120, height=160)
    moved = replace(view, fit=replace(view.fit, camera=cam))
    d_fit = true_lighting_in_fit_frame(moved).directions
    cam_gt = garment_case["session"].cameras["cam_00"]
    assert np.allclose(d_fit @ cam.R.T, d_true @ cam_gt.R.T, atol=1e-12)
    assert _angle_deg(d_fit[0], d_true[0]) > 30  # the two worlds differ: an untransformed copy would fail


def _arrow_direction(plotter, name, start):
    import pyvista as pv

    P = np.asarray(pv.wrap(plotter.renderer.actors[name].GetMapper().GetInput()).points)
    tip = P[np.argmax(np.linalg.norm(P - start, axis=1))]
    return tip - start


def test_scene_arrows_point_along_estimated_and_true_lights(garment_case):
    from bodystudio.garment.evaluate import principal_light_direction
    from bodystudio.viewer.garment import (
        ARROW_OFFSET_M,
        fitted_scene,
        light_origin,
        open_garment_view,
        scene_for_garment,
    )
    from bodystudio.viewer.scene import make_plotter

    view = open_garment_view(garment_case["fit_dir"])
    plotter = scene_for_garment(view, 1, make_plotter(window_size=(480, 360)))
    names = set(plotter.renderer.actors)
    assert {"fitted-body", "garment", "lights-estimated", "lights-true", "garment-strip"} <= names
    origin = light_origin(fitted_scene(view, 1).body_vertices)
    est = view.fit.lighting
    d_est = principal_light_direction(est.directions, est.colors)
    d_true = np.asarray(garment_case["session"].gt_lighting["directions"][0], float)
    a_est = _arrow_direction(plotter, "lights-estimated", origin + ARROW_OFFSET_M * d_est)
    a_true = _arrow_direction(plotter, "lights-true", origin + ARROW_OFFSET_M * d_true)
    assert _angle_deg(a_est, d_est) < 0.5 and _angle_deg(a_true, d_true) < 0.5
    assert abs(_angle_deg(a_est, a_true) - garment_case["light_err_deg"]) < 0.5  # the fit's lights were turned
    # the garment mesh carries its cloth texture; the body its albedo colours
    assert plotter.renderer.actors["garment"].GetTexture() is not None
    mapper = plotter.renderer.actors["fitted-body"].GetMapper()
    mapper.Update()
    rgb = np.asarray(mapper.GetInput().GetPointData().GetArray("rgb")).astype(float)
    albedo = garment_case["fit"].albedo
    assert rgb.shape == albedo.shape and np.corrcoef(rgb.ravel(), albedo.ravel())[0, 1] > 0.99
    plotter.close()


def test_view_cli_screenshot_and_html(garment_case, tmp_path, drawn):
    from PIL import Image

    from bodystudio.cli.main import main

    shot = tmp_path / "g.png"
    assert main(["view", str(garment_case["fit_dir"]), "--frame", "2", "--screenshot", str(shot),
                 "--size", "640x480"]) == 0
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert drawn(img).mean() > 0.1
    orange = (img[..., 0] > 200) & (img[..., 1] > 90) & (img[..., 1] < 190) & (img[..., 2] < 80)
    assert orange.sum() > 50  # the estimated light arrows are in view



def test_view_html_carries_every_frame_and_draws_in_chromium(garment_case, tmp_path, chromium):
    import base64
    import json
    import re

    from bodystudio.cli.main import main
    from bodystudio.viewer.garment import fitted_scene, open_garment_view

    html = tmp_path / "g.html"
    assert main(["view", str(garment_case["fit_dir"] / "render"), "--html", str(html), "--frame", "1"]) == 0
    text = html.read_text()
    payload = json.loads(re.search(r'id="view3d-data">(.*?)</script>', text, re.S).group(1).replace("<\\/", "</"))
    assert [f["id"] for f in payload["frames"]] == [0, 1, 2] and payload["start"] == 1
    view = open_garment_view(garment_case["fit_dir"])
    for f in payload["frames"]:  # each frame carries its own posed body, textured garment, arrows and strip
        objects = {o["name"]: o for o in f["objects"]}
        assert {"fitted-body", "garment", "lights-estimated", "lights-true", "garment-strip"} <= set(objects)
        assert "texture" in objects["garment"] and "texture" in objects["garment-strip"]
        V = np.frombuffer(base64.b64decode(objects["fitted-body"]["positions"]), "<f4").reshape(-1, 3)
        np.testing.assert_allclose(V, fitted_scene(view, f["id"]).body_vertices, atol=1e-5)
    page = chromium(html, size=(900, 800), screenshot=False)  # the page loads and draws; no picture checked
    assert page["console"] == [], page["console"]
    assert 'data-viewer-status="ok"' in page["dom"]


def test_view_bad_frame_is_one_line(garment_case, tmp_path, capsys):
    from bodystudio.cli.main import main

    assert main(["view", str(garment_case["fit_dir"]), "--frame", "9", "--screenshot", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--frame 9: not a frame of the fit" in err[0]
    assert not (tmp_path / "x.png").exists()


def test_report_garment_section_has_frames_and_scores(garment_case, tmp_path):
    from bodystudio.viewer.report import write_report

    out = tmp_path / "report.html"
    result = write_report(garment_case["root"], out, with_3d=False)
    assert len(result.garments) == 1
    section = result.garments[0]
    assert [c for c, _ in section.strips] == ["fit frame 0", "fit frame 1", "fit frame 2"] and section.notes == []
    s = section.scores
    assert abs(s["light_dir_err_deg"] - garment_case["light_err_deg"]) < 1e-6  # computed by eval garment's code
    assert s["stature_err_mm"] < 1e-6 and s["joint_err_px"] < 1e-6
    assert s["garment_iou"] > 0.9 and s["psnr_person"] > 25 and len(s["garment_iou_per_frame"]) == 3
    text = out.read_text()
    assert "Garment: before / after" in text and "fit: eval garment" in text and "garment_iou" in text
    assert text.count('alt="fit frame') == 3
    assert not any("render/" in name or "masks/" in name for name, _ in result.screenshots)
    # a saved eval.json of this fit and render is shown as it is (an Infinity PSNR as null)
    from bodystudio.garment.evaluate import scored_run_ids

    ids = scored_run_ids(garment_case["fit_dir"])
    assert ids["render_run_id"] is not None
    (garment_case["fit_dir"] / "eval.json").write_text(json.dumps(ids)[:-1] +
                                                        ', "garment_iou": 0.5, "psnr_person": Infinity}')
    try:
        scores = write_report(garment_case["fit_dir"], out, with_3d=False).garments[0].scores
        assert scores == {"garment_iou": 0.5, "psnr_person": None, **ids}
        # one of an earlier render (or without the ids: older): re-scored, and the section says so
        (garment_case["fit_dir"] / "eval.json").write_text(json.dumps({**ids, "render_run_id": "0123",
                                                                        "garment_iou": 0.5}))
        section = write_report(garment_case["fit_dir"], out, with_3d=False).garments[0]
        assert section.scores["garment_iou"] > 0.9 and any("earlier fit or render" in n for n in section.notes)
    finally:
        (garment_case["fit_dir"] / "eval.json").unlink()


def test_report_and_view_without_render_say_so(garment_case, tmp_path, capsys):
    from bodystudio.cli.main import main
    from bodystudio.viewer.garment import before_after_panels, open_garment_view
    from bodystudio.viewer.report import write_report

    fit_dir = _copy_fit(garment_case, tmp_path / "fit", render=False)
    view = open_garment_view(fit_dir)
    assert view.render is None and any("no render yet: run 'bodystudio garment render" in n for n in view.notes)
    assert [c for c, _ in before_after_panels(view, 0)] == ["input", "truth"]
    result = write_report(fit_dir, tmp_path / "r.html", with_3d=False)
    g = result.garments[0]
    assert len(g.strips) == 3 and g.notes[0] == "strips lack: composite (no render)"
    assert "garment_iou" not in g.scores and abs(g.scores["light_dir_err_deg"] - garment_case["light_err_deg"]) < 1e-6
    assert "no render yet" in (tmp_path / "r.html").read_text()
    assert main(["view", str(fit_dir), "--screenshot", str(tmp_path / "v.png")]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_report_with_damaged_render_or_gone_source_does_not_crash(garment_case, tmp_path):
    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit
    from bodystudio.viewer.report import write_report

    damaged = _copy_fit(garment_case, tmp_path / "damaged")
    (damaged / "render" / "render.json").write_text("{ not json")
    g = write_report(damaged, tmp_path / "a.html", with_3d=True).garments[0]
    assert any(n.startswith("render not shown:") and "render.json" in n for n in g.notes)
    assert len(g.strips) == 3 and "garment_iou" not in g.scores  # input | truth, the fit still scored

    gone = tmp_path / "gone"
    save_garment_fit(gone, replace(load_garment_fit(garment_case["fit_dir"]), source=str(tmp_path / "no-video.mp4")))
    result = write_report(gone, tmp_path / "b.html", with_3d=True)
    g = result.garments[0]
    assert g.strips == [] and g.scores is None
    assert any("no-video.mp4 is gone" in n for n in g.notes) and any("not scored" in n for n in g.notes)
    assert any("no render yet" in n for n in g.notes)
    assert result.has_3d  # the fitted body and its lights still make a 3D view

    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "fit.json").write_text('{"format": "bodystudio-garment-fit", "version": 1}')
    g = write_report(broken, tmp_path / "c.html", with_3d=True).garments[0]
    assert g.strips == [] and len(g.notes) == 1 and g.notes[0].startswith("not shown:")
    assert "damaged garment fit" in (tmp_path / "c.html").read_text()


def test_time_slider_swaps_the_fitted_frame(garment_case):
    from bodystudio.viewer.garment import add_garment_time_slider, fitted_scene, open_garment_view, scene_for_garment
    from bodystudio.viewer.scene import make_plotter

    view = open_garment_view(garment_case["fit_dir"])
    plotter = scene_for_garment(view, 0, make_plotter(window_size=(320, 240)))
    add_garment_time_slider(plotter, view, 0)
    (slider,) = plotter.widgets.slider_widgets

    def garment_points():
        mapper = plotter.renderer.actors["garment"].GetMapper()
        mapper.Update()
        return np.asarray(mapper.GetInput().GetPoints().GetData()).copy()

    np.testing.assert_allclose(garment_points(), fitted_scene(view, 0).garment_vertices, atol=1e-6)
    assert np.abs(fitted_scene(view, 2).garment_vertices - garment_points()).max() > 0.003  # the actor moved
    slider.GetRepresentation().SetValue(2.0)
    slider.InvokeEvent("EndInteractionEvent")
    np.testing.assert_allclose(garment_points(), fitted_scene(view, 2).garment_vertices, atol=1e-6)
    assert "frame 2" in plotter.renderer.actors["title"].GetText(2)
    plotter.iren._key_press_event_callbacks["p"][0]()
    assert "frame 1" in plotter.renderer.actors["title"].GetText(2)
    plotter.close()


def test_fit_of_a_video_shows_its_frames_without_truth(garment_case, tmp_path):
    """A fit whose source is a video file (no session, no ground truth): the input panel is the video's frame
    (frame ids are frame numbers), there is no truth panel and the report says why there are no scores."""
    from bodystudio.fileio import Mp4Writer
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.viewer.garment import before_after_panels, open_garment_view
    from bodystudio.viewer.report import write_report

    session = garment_case["session"]
    video = tmp_path / "clip.mp4"
    writer = Mp4Writer(video, (120, 160), 30.0)
    for fid in session.frame_ids:
        writer.write(session.frame(fid).images["cam_00"])
    writer.close()
    fit_dir = tmp_path / "fit"
    save_garment_fit(fit_dir, replace(garment_case["fit"], source=str(video)))
    shutil.copytree(garment_case["fit_dir"] / "render", fit_dir / "render")
    view = open_garment_view(fit_dir)
    assert view.session is None and view.has_source and view.notes == ()
    panels = before_after_panels(view, 2)
    assert [c for c, _ in panels] == ["input", "composite"]
    err = np.abs(panels[0][1].astype(int) - session.frame(2).images["cam_00"].astype(int))
    assert err.mean() < 6  # the video's frame 2 (H.264), not another frame
    assert np.abs(panels[0][1].astype(int) - session.frame(0).images["cam_00"].astype(int)).mean() > err.mean()
    g = write_report(fit_dir, tmp_path / "r.html", with_3d=False).garments[0]
    assert len(g.strips) == 3 and g.scores is None
    assert g.notes == ["strips lack: truth (not a synthetic garment session)",
                       "not scored: the fit's source is not a session folder; `eval garment` needs a synthetic "
                       "session (`bodystudio synth garment`)"]
