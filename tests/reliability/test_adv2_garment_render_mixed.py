"""A garment render folder holding a frame of another render (adversarial pass, round 2): ``eval garment``
scored it and ``view`` / ``report`` showed it as this render, exit 0; render.json's checksums were not read.
Now the render is refused naming the file (eval: one line, exit 2; view and report: the render is not shown
and the note says why)."""

from __future__ import annotations

import shutil

import pytest

from .conftest import assert_clean_error, run_inprocess


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The oracle fit of a 2-frame 120x160 synthetic garment session (2k body) rendered with its target."""
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit, render_garment_video
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("adv2grender")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=2, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    save_garment_fit(root / "fit", perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0), "test")
    target = session.gt_garment["target"]
    render_garment_video(root / "fit", target["name"], target["pattern"], root / "o.mp4", seed=target["seed"],
                         texture_size=64)
    return root


def test_a_render_with_a_swapped_frame_is_refused(rendered, tmp_path, capfd):
    from bodystudio.viewer.garment import open_garment_view

    fit = shutil.copytree(rendered / "fit", tmp_path / "fit")
    assert run_inprocess(["eval", "garment", fit], capfd).rc == 0  # the intact render is scored
    frames = sorted((fit / "render" / "frames").glob("*.png"))
    shutil.copy(frames[0], frames[1])  # frame 1 is now frame 0's image
    assert_clean_error(run_inprocess(["eval", "garment", fit], capfd), 2, "does not belong to run")
    view = open_garment_view(fit)
    assert view.render is None and any("render not shown" in n and "does not belong" in n for n in view.notes)


def test_render_onto_the_fits_source_video_is_refused(rendered, tmp_path, capfd):
    """``garment render FIT --out clip.mp4`` where clip.mp4 is the video the fit was made from: the render
    replaced the user's input clip (and the fit then refused its changed source). Refused before any work."""
    from dataclasses import replace

    from bodystudio.garment.fitfile import load_garment_fit, save_garment_fit

    clip = tmp_path / "clip.mp4"
    clip.write_bytes(b"the user's recording")
    fit = tmp_path / "fit"
    save_garment_fit(fit, replace(load_garment_fit(rendered / "fit"), source=str(clip)), "test")
    result = run_inprocess(["garment", "render", fit, "--out", clip], capfd)
    assert_clean_error(result, 2, "is the fit's source video")
    assert clip.read_bytes() == b"the user's recording" and not (fit / "render").exists()
