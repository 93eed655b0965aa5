"""The mirror in the viewer and the report: before/after frames (input | mirror | truth) and the source body."""

import json
import shutil

import numpy as np
import pytest

from bodystudio.capture.session import open_session
from tests.mirror.synth_case import small_mirror_session, write_fake_run


@pytest.fixture(scope="module")
def mirror_session(tmp_path_factory):
    """A copy of the small mirror session with a source body (the true one) and a run whose output is
    the truth with a white square painted in (so the mirror panel is recognisable)."""
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror.init import SourceBody, refit_skeleton, save_source_body

    path = tmp_path_factory.mktemp("mirror-view") / "session"
    shutil.copytree(small_mirror_session(), path)
    session = open_session(path)
    actors = session.gt_mirror_actors
    model = load_statistical_model("6k", progress=False)
    c = np.asarray(actors["source_coeffs"][0], np.float64)
    save_source_body(path / "mirror" / "source_body.npz",
                     SourceBody(c, actors["source_rest_vertices"][0], refit_skeleton(model, c), (10,), 1.0))

    def output(f):
        img = f.gt_target_rgb.copy()
        img[200:260, 300:360] = 255
        return img

    write_fake_run(session, path / "mirror" / "run", output, lambda f: f.gt_person == 1,
                   lambda f: f.gt_target_person == 1)
    return session


def test_mirror_session_and_run_open_as_mirror_views(mirror_session):
    from bodystudio.viewer.mirror import before_after_panels, before_after_strip, mirror_frames
    from bodystudio.viewer.views import open_viewable

    item = open_viewable(mirror_session.path)
    assert item.kind == "mirror" and item.data.source_path is not None
    run_item = open_viewable(mirror_session.path / "mirror" / "run")
    assert run_item.kind == "mirror" and run_item.data.session.path == item.data.session.path
    view = item.data
    assert mirror_frames(view, 3) == [10, 12, 13]  # the run's ok frames with the actor, evenly spread
    panels = before_after_panels(view, 12)
    assert [c.split(" ")[0] for c, _ in panels] == ["input", "mirror", "truth"]
    frame = mirror_session.frame(12)
    assert np.array_equal(panels[0][1], frame.kinect_rgb) and np.array_equal(panels[2][1], frame.gt_target_rgb)
    assert (panels[1][1][200:260, 300:360] == 255).all()  # the run's output, not the input
    strip = before_after_strip(view, 12)
    assert strip.shape == (480, 3 * 640, 3) and (strip[220, 640 + 330] == 255).all()
    # before the run: input and truth only
    shutil.move(mirror_session.path / "mirror" / "run", mirror_session.path / "run_aside")
    try:
        assert [c for c, _ in before_after_panels(open_viewable(mirror_session.path).data, 12)] == \
            ["input", "truth (edited body)"]
    finally:
        shutil.move(mirror_session.path / "run_aside", mirror_session.path / "mirror" / "run")


def test_view_screenshot_shows_strip_and_source_body(mirror_session, tmp_path, drawn):
    from PIL import Image

    from bodystudio.cli.main import main

    shot = tmp_path / "mirror.png"
    assert main(["view", str(mirror_session.path), "--frame", "12", "--screenshot", str(shot), "--size",
                 "640x480"]) == 0
    img = np.asarray(Image.open(shot).convert("RGB"))
    assert drawn(img).mean() > 0.2  # the strip and the body cover a good part of the picture
    html = tmp_path / "mirror.html"
    assert main(["view", str(mirror_session.path / "mirror" / "run"), "--html", str(html)]) == 0
    assert '"texture"' in html.read_text()  # the before/after strip travels as a texture


def test_view_mirror_bad_frame_is_one_line(mirror_session, tmp_path, capsys):
    from bodystudio.cli.main import main

    assert main(["view", str(mirror_session.path), "--frame", "999", "--screenshot", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--frame 999: not a frame" in err[0]
    run = tmp_path / "foreign_run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"format": "bodystudio-mirror-run", "session": str(tmp_path / "gone")}))
    assert main(["view", str(run), "--screenshot", str(tmp_path / "y.png")]) == 2
    assert "the run's session" in capsys.readouterr().err


def test_report_has_a_mirror_section_with_frames_and_eval_json(mirror_session, tmp_path):
    from bodystudio.viewer.report import write_report

    out = tmp_path / "report.html"
    result = write_report(mirror_session.path, out, with_3d=False)
    assert len(result.mirrors) == 1
    section = result.mirrors[0]
    assert len(section.strips) == 3 and section.note is None
    assert section.scores["warp_iou"] == 1.0 and section.scores["init_mass_err_kg"] < 1e-6
    text = out.read_text()
    assert "Mirror: before / after" in text and "eval JSON" in text and "psnr_person" in text
    assert text.count('alt="session frame') == 3
    # the run's frames are in the mirror section, not among the screenshots
    assert not any("frames/" in name or "masks/" in name for name, _ in result.screenshots)
    # a saved eval.json of this run and source body is shown as it is
    from bodystudio.mirror.init import load_source_body, source_fingerprint

    ids = {"run_id": json.loads((mirror_session.path / "mirror" / "run" / "run.json").read_text())["run"]["run_id"],
           "source_fingerprint": source_fingerprint(load_source_body(mirror_session.path / "mirror" /
                                                                     "source_body.npz"))}
    saved = {"warp_iou": 0.5, "psnr_person": None, "psnr_person_identical": True, **ids}
    (mirror_session.path / "mirror" / "eval.json").write_text(json.dumps(saved))
    try:
        assert write_report(mirror_session.path, out, with_3d=False).mirrors[0].scores == saved
        # an eval.json written before `eval mirror` printed strict JSON: Infinity becomes null + the flag
        (mirror_session.path / "mirror" / "eval.json").write_text(
            json.dumps(ids)[:-1] + ', "psnr_person": Infinity, "warp_iou": 0.9}')
        scores = write_report(mirror_session.path, out, with_3d=False).mirrors[0].scores
        assert scores == {"psnr_person": None, "warp_iou": 0.9, "psnr_person_identical": True, **ids}
        # one of another run (or without the ids: older): re-scored, and the section says so
        (mirror_session.path / "mirror" / "eval.json").write_text(json.dumps({**saved, "run_id": "0123"}))
        section = write_report(mirror_session.path, out, with_3d=False).mirrors[0]
        assert section.scores["warp_iou"] == 1.0 and "scores an earlier run" in section.note
    finally:
        (mirror_session.path / "mirror" / "eval.json").unlink()


def test_view_and_report_show_each_run_players_body(mirror_session, tmp_path):
    """A run of ``--player 2`` showed player 1's body (``source_body.npz``) and the report checked a saved eval.json
    against it; the view now shows each run player's own body (``source_body_playerN.npz``), side by side for a
    run of several players, and the report checks the run's first player's body."""
    from bodystudio.mirror.init import load_source_body, save_source_body, source_fingerprint
    from bodystudio.viewer.mirror import open_mirror_view, scene_for_mirror, source_body_mesh
    from bodystudio.viewer.report import _scores_of_this_run
    from bodystudio.viewer.scene import make_plotter

    work = tmp_path / "s"
    shutil.copytree(mirror_session.path, work, ignore=shutil.ignore_patterns("run"))
    body1 = load_source_body(work / "mirror" / "source_body.npz")
    body2 = type(body1)(body1.coeffs + 0.5, body1.vertices * 1.1, body1.skeleton, body1.frames_used,
                        body1.residual_mm)
    save_source_body(work / "mirror" / "source_body_player2.npz", body2, player=2)
    fp1, fp2 = source_fingerprint(body1), source_fingerprint(body2)
    assert fp1 != fp2
    session = open_session(work)
    truth = (lambda f: f.gt_target_rgb, lambda f: f.gt_person == 1, lambda f: f.gt_target_person == 1)

    write_fake_run(session, work / "mirror" / "run", *truth, player=2,
                   extra={"players": [2], "source_fingerprint": fp2, "source_fingerprints": {"2": fp2}})
    view = open_mirror_view(work)
    assert view.source_path == work / "mirror" / "source_body_player2.npz"
    assert np.allclose(source_body_mesh(view).vertices, body2.vertices)
    plotter = scene_for_mirror(view, 12, plotter=make_plotter(off_screen=True))
    try:
        assert "source-body" in plotter.actors and "source body of player 2" in plotter.actors["title"].GetText(2)
        shown = np.asarray(plotter.actors["source-body"].GetMapper().GetInput().GetPoints().GetData())
        assert np.allclose(shown, body2.vertices, atol=1e-5)  # player 2's body, not player 1's
    finally:
        plotter.close()
    run_id = json.loads((work / "mirror" / "run" / "run.json").read_text())["run"]["run_id"]
    assert _scores_of_this_run({"run_id": run_id, "source_fingerprint": fp2}, view)
    assert not _scores_of_this_run({"run_id": run_id, "source_fingerprint": fp1}, view)

    shutil.rmtree(work / "mirror" / "run")
    write_fake_run(session, work / "mirror" / "run", *truth, player=1,
                   extra={"players": [1, 2], "source_fingerprint": fp1, "source_fingerprints": {"1": fp1, "2": fp2}})
    view = open_mirror_view(work)
    assert [p for p, _ in view.source_paths] == [1, 2] and view.source_path == work / "mirror" / "source_body.npz"
    plotter = scene_for_mirror(view, 12, plotter=make_plotter(off_screen=True))
    try:
        assert {"source-body", "source-body-player2"} <= set(plotter.actors)
        first = np.asarray(plotter.actors["source-body"].GetMapper().GetInput().GetPoints().GetData())
        second = np.asarray(plotter.actors["source-body-player2"].GetMapper().GetInput().GetPoints().GetData())
        assert np.allclose(first - first.mean(0), body1.vertices - body1.vertices.mean(0), atol=1e-5)
        assert np.allclose(second - second.mean(0), body2.vertices - body2.vertices.mean(0), atol=1e-5)
        assert second.mean(0)[0] - first.mean(0)[0] > 0.5  # side by side
        assert "source bodies of players 1, 2" in plotter.actors["title"].GetText(2)
    finally:
        plotter.close()
    # player 2's body re-initialised after the run: left out, and the title says whose
    save_source_body(work / "mirror" / "source_body_player2.npz", body1, player=2)
    plotter = scene_for_mirror(open_mirror_view(work), 12, plotter=make_plotter(off_screen=True))
    try:
        assert "source-body" in plotter.actors and "source-body-player2" not in plotter.actors
        assert "source body of player 2 changed" in plotter.actors["title"].GetText(2)
    finally:
        plotter.close()
