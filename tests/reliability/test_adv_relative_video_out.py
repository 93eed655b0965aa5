"""A relative ``--out`` video (adversarial pass): ``mirror run --out sub/o.mp4`` printed ``sub/o.mp4`` with
exit 0 but wrote the videos inside the run folder (``RUN/sub/o.mp4``, RunWriter's reading of a relative
path); ``garment render`` did the same. The video is now where the user's working directory says."""

from __future__ import annotations

import json

import pytest

from bodystudio.cli.main import main


@pytest.fixture(scope="module")
def kinect_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("advrel") / "kinect"
    assert main(["synth", "session", str(out), "--cameras", "1", "--frames", "1", "--resolution", "160x120",
                 "--template", "2k", "--seed", "1", "--kinect", "v1"]) == 0
    return out


@pytest.fixture(scope="module")
def source_body(tmp_path_factory):
    """A mean-shape source body of the 2k model (the numbers do not matter here, only where the video goes)."""
    import numpy as np

    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.mirror.init import SourceBody, refit_skeleton, save_source_body

    model = load_statistical_model("2k", progress=False)
    c = np.zeros(model.n_components)
    path = tmp_path_factory.mktemp("advsrc") / "source_body.npz"
    save_source_body(path, SourceBody(c, model.vertices(c), refit_skeleton(model, c), (0,), 1.0))
    return path


def test_mirror_run_relative_out_lands_in_the_cwd(kinect_session, source_body, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "videos").mkdir()
    capsys.readouterr()
    assert main(["mirror", "run", str(kinect_session), "--out", "videos/o.mp4", "--run", "run",
                 "--source", str(source_body), "--accept-implausible"]) == 0  # a mean body: not the actor
    assert (tmp_path / "videos" / "o.mp4").stat().st_size > 0
    assert (tmp_path / "videos" / "o_side_by_side.mp4").stat().st_size > 0
    assert not (tmp_path / "run" / "videos").exists()
    doc = json.loads((tmp_path / "run" / "run.json").read_text())
    assert doc["videos"]["output"] == "videos/o.mp4"


@pytest.fixture(scope="module")
def garment_fit_dir(tmp_path_factory):
    """The oracle fit of a 2-frame 120x160 synthetic garment session (as test_garment_render_inputs)."""
    from bodystudio.garment.composite import ground_truth_fit, perturbed_fit
    from bodystudio.garment.fitfile import save_garment_fit
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("advgr")
    session = synth_garment_session(root / "session", subject_seed=3, n_frames=2, resolution=(120, 160),
                                    template="2k", texture_size=64, seed=2)
    save_garment_fit(root / "fit", perturbed_fit(ground_truth_fit(session), pose_deg=0.0, translation_m=0.0), "test")
    return root / "fit"


def test_garment_render_relative_out_lands_in_the_cwd(garment_fit_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "videos").mkdir()
    assert main(["garment", "render", str(garment_fit_dir), "--out", "videos/g.mp4", "--no-flow"]) == 0
    assert (tmp_path / "videos" / "g.mp4").stat().st_size > 0
    assert not (garment_fit_dir / "render" / "videos").exists()
