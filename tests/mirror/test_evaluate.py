"""Mirror evaluation: the true target scores perfectly, the unwarped input does not; foreign runs are refused."""

import types

import numpy as np
import pytest

from bodystudio.capture.session import open_session
from bodystudio.errors import BodyStudioError, InputError
from bodystudio.mirror.evaluate import (
    image_scores,
    init_scores,
    mask_iou,
    psnr_from_sse,
    read_mirror_run,
    ssim_map,
)
from tests.mirror.synth_case import small_mirror_session, write_fake_run


@pytest.fixture(scope="module")
def session():
    return open_session(small_mirror_session())


def truth_run(session, path, **kw):
    return write_fake_run(session, path, lambda f: f.gt_target_rgb, lambda f: f.gt_person == 1,
                          lambda f: f.gt_target_person == 1, **kw)


def test_true_target_frames_score_perfectly(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run")
    scores = image_scores(session, run_dir, read_mirror_run(session, run_dir))
    assert scores["frames_scored"] == 4 and scores["frames_passed_through"] == 0
    assert scores["warp_iou"] == 1.0 and scores["fg_iou"] == 1.0
    assert scores["psnr_person"] == float("inf") and scores["ssim_person"] == pytest.approx(1.0, abs=1e-12)
    # the SDK's raw player mask is only close (measured 0.85)
    assert 0.75 < scores["fg_iou_raw"] < 0.95


def test_unwarped_input_scores_clearly_worse(session, tmp_path):
    run_dir = write_fake_run(session, tmp_path / "run", lambda f: f.kinect_rgb, lambda f: f.gt_person == 1,
                             lambda f: f.gt_person == 1)
    scores = image_scores(session, run_dir, read_mirror_run(session, run_dir))
    # +15 cm (~ +10 % height, mass held: taller and thinner): measured warp_iou 0.62, psnr 16 dB, ssim 0.60
    assert scores["warp_iou"] < 0.8 and scores["warp_iou"] == pytest.approx(scores["warp_iou_unwarped"])
    assert scores["psnr_person"] < 22.0 and scores["ssim_person"] < 0.8


def test_frames_of_the_edit_ramp_are_not_scored(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run", extra={"ramp_frames": 12})
    scores = image_scores(session, run_dir, read_mirror_run(session, run_dir))
    # every frame of the fake run is "ok": the 12th (frame 11) completes the ramp
    assert scores["frames_ramping"] == 11 and scores["scored_frames"] == [11, 12, 13]
    run_dir = truth_run(session, tmp_path / "run2", extra={"ramp_frames": 30})
    with pytest.raises(InputError, match="never reached the whole edit"):
        image_scores(session, run_dir, read_mirror_run(session, run_dir))


def test_metric_helpers():
    a = np.zeros((20, 20), bool)
    a[5:15, 5:15] = True
    b = np.roll(a, 5, axis=1)
    assert mask_iou(a, b) == pytest.approx(50 / 150) and mask_iou(a, a) == 1.0 and mask_iou(~a & a, a & ~a) == 1.0
    assert psnr_from_sse(0.0, 10) == float("inf")
    assert psnr_from_sse(10 * 255.0**2 / 100.0, 10) == pytest.approx(20.0)
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 50, 3)).astype(np.uint8)
    assert np.allclose(ssim_map(img, img), 1.0)
    noisy = np.clip(img + rng.normal(0, 25, img.shape), 0, 255)
    assert 0.2 < ssim_map(img, noisy).mean() < 0.95
    # a constant offset keeps structure and contrast: only the luminance term drops a little
    assert ssim_map(img, np.clip(img.astype(float) + 10, 0, 255)).mean() > ssim_map(img, noisy).mean()


def test_init_scores_against_the_true_body(session):
    actors = session.gt_mirror_actors
    V = actors["source_rest_vertices"][0]
    exact = init_scores(session, types.SimpleNamespace(vertices=V, faces=actors["faces"]))
    assert exact["init_stature_err_mm"] < 1e-6 and exact["init_mass_err_kg"] < 1e-6
    scaled = V * np.array([1.0, 1.01, 1.0])
    off = init_scores(session, types.SimpleNamespace(vertices=scaled))  # faces from the template
    assert off["init_stature_err_mm"] == pytest.approx(exact["true_stature_m"] * 10.0, rel=0.02)
    assert off["init_mass_err_kg"] == pytest.approx(0.01 * exact["true_mass_kg"], rel=0.2)


def test_refuses_runs_that_do_not_belong(session, tmp_path):
    other = tmp_path / "elsewhere"
    run_dir = truth_run(session, tmp_path / "a", session_path=other)
    with pytest.raises(InputError, match="made from session"):
        read_mirror_run(session, run_dir)
    run_dir = truth_run(session, tmp_path / "b", edits={"taller": 0.05})
    with pytest.raises(InputError, match="edits"):
        read_mirror_run(session, run_dir)
    run_dir = truth_run(session, tmp_path / "c", player=2)
    with pytest.raises(InputError, match="player"):
        read_mirror_run(session, run_dir)


def test_refuses_incomplete_runs(session, tmp_path):
    run_dir = truth_run(session, tmp_path / "run")
    (run_dir / "masks" / "warped" / "00012.png").unlink()
    with pytest.raises(BodyStudioError, match="incomplete") as info:
        read_mirror_run(session, run_dir)
    assert "\n" not in str(info.value)
    run_dir = truth_run(session, tmp_path / "run2")
    (run_dir / "frames" / "00011.png").write_bytes(b"not this run")
    with pytest.raises(BodyStudioError, match="does not belong"):
        read_mirror_run(session, run_dir)
    run_dir = truth_run(session, tmp_path / "run3")
    (run_dir / ".staging").mkdir()
    (run_dir / ".staging" / "commit.json").write_text("{}")
    with pytest.raises(InputError, match="interrupted"):
        read_mirror_run(session, run_dir)
    with pytest.raises(InputError, match="no such run folder"):
        read_mirror_run(session, tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="never committed"):
        read_mirror_run(session, tmp_path / "empty")


def test_full_evaluation_with_the_true_source_body(session, tmp_path):
    from bodystudio.body.skeleton import Skeleton
    from bodystudio.mirror.evaluate import evaluate_mirror

    actors = session.gt_mirror_actors
    names = tuple(session.gt_subject["bone_names"])
    from bodystudio.body import build_body

    parents = build_body(resolution="6k").skeleton
    skeleton = Skeleton(names, parents.parents, actors["source_heads"][0], actors["source_tails"][0], parents.rolls)
    source = types.SimpleNamespace(vertices=actors["source_rest_vertices"][0], faces=actors["faces"],
                                   skeleton=skeleton)
    run_dir = truth_run(session, tmp_path / "run")
    scores = evaluate_mirror(session, run_dir, source=source)
    assert scores["warp_iou"] == 1.0 and scores["init_stature_err_mm"] < 1e-6
    # the IK against noisy SDK joints (1 cm noise, 3 % bone jitter) with the true skeleton: measured 17 mm
    assert 5.0 < scores["joint_err_mm"] < 26.0
    assert scores["ms_per_frame"] == {"foreground": 2.0, "warp": 1.0}


def _strict_json(text):
    """json.loads that refuses NaN / Infinity / -Infinity (RFC 8259 has none of them)."""
    import json

    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


def test_strict_json_scores():
    from bodystudio.mirror.evaluate import strict_json_scores

    out = strict_json_scores({"psnr_person": float("inf"), "joint_err_mm": float("nan"), "ms": {"a": np.float32(2)},
                              "n": np.int64(3)})
    assert out == {"psnr_person": None, "psnr_person_identical": True, "joint_err_mm": None, "ms": {"a": 2.0}, "n": 3}
    assert strict_json_scores({"psnr_person": 31.5})["psnr_person_identical"] is False


def test_eval_mirror_cli_prints_strict_json(session, tmp_path, capsys):
    """`eval mirror` on output identical to the target: PSNR is null + psnr_person_identical, parsed strictly."""
    import shutil

    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.cli.main import main
    from bodystudio.mirror.init import SourceBody, refit_skeleton, save_source_body

    path = tmp_path / "session"
    shutil.copytree(session.path, path)
    copy = open_session(path)
    actors = copy.gt_mirror_actors
    model = load_statistical_model("6k", progress=False)
    c = np.asarray(actors["source_coeffs"][0], np.float64)
    save_source_body(path / "mirror" / "source_body.npz",
                     SourceBody(c, actors["source_rest_vertices"][0], refit_skeleton(model, c), (10,), 1.0))
    run_dir = truth_run(copy, tmp_path / "run")
    capsys.readouterr()
    assert main(["eval", "mirror", str(path), "--run", str(run_dir)]) == 0
    scores = _strict_json(capsys.readouterr().out)
    assert scores["psnr_person"] is None and scores["psnr_person_identical"] is True
    assert scores["warp_iou"] == 1.0 and scores["init_mass_err_kg"] < 1e-6
    assert isinstance(scores["joint_err_mm"], float)
    # a real (finite) PSNR stays a number with the flag false
    run_dir = write_fake_run(copy, tmp_path / "unwarped", lambda f: f.kinect_rgb, lambda f: f.gt_person == 1,
                             lambda f: f.gt_person == 1)
    assert main(["eval", "mirror", str(path), "--run", str(run_dir)]) == 0
    scores = _strict_json(capsys.readouterr().out)
    assert 10.0 < scores["psnr_person"] < 22.0 and scores["psnr_person_identical"] is False
