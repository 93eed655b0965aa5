"""Bad input to the muscle commands (synth arm, muscle capture / model, eval muscle): one line, exit 2, nothing written.

Each case: the command line, a phrase of the one-line message, and that the output path does not exist
afterwards (no half-written folder, no staging leftovers beside it).
"""

import shutil

import numpy as np
import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


def nothing_beside(folder, allowed=()):
    left = sorted(p.name for p in folder.iterdir() if p.name not in allowed)
    assert left == [], left


@pytest.fixture(scope="module")
def arm_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("arm") / "session"
    assert main(["synth", "arm", str(out), "--subject-seed", "5", "--frames", "3", "--resolution", "2k"]) == 0
    return out


def rewrite_depth(session_path, tmp_path, make):
    """A copy of the session with every depth frame replaced by ``make(depth)``."""
    from bodystudio.capture.session import SessionWriter, open_session

    copy = tmp_path / "bad_session"
    shutil.copytree(session_path, copy)
    s = open_session(copy)
    depths = {fid: s.frame(fid).kinect_depth_m for fid in s.frame_ids}
    with SessionWriter(copy, update=True) as w:
        for fid, d in depths.items():
            w.write_kinect_depth(fid, make(d))
    return copy


@pytest.mark.parametrize("args, phrase", [
    (["--motion", "wave"], "--motion 'wave': valid: elbow_flex, abduction, pronation"),
    (["--kinect", "v3"], "--kinect 'v3': valid: v1, v2"),
    (["--frames", "0"], "--frames 0: must be in [1, 2000]"),
    (["--frames", "5000"], "--frames 5000: must be in [1, 2000]"),
    (["--distance", "0.1"], "--distance 0.1: must be in [0.5, 3] m"),
    (["--distance", "nan"], "--distance nan: must be in"),
    (["--distance", "12"], "--distance 12.0: must be in"),
    (["--resolution", "13k"], "--resolution '13k': valid: 6k, 2k, full"),
    (["--subject-seed", "-1"], "--subject-seed -1: must be in"),
])
def test_synth_arm_bad_options(tmp_path, capsys, args, phrase):
    out = tmp_path / "s"
    run_bad(["synth", "arm", out, *(["--subject-seed", "1"] if "--subject-seed" not in args else []), *args],
            capsys, phrase)
    nothing_beside(tmp_path)


def test_synth_arm_onto_existing_output(tmp_path, capsys):
    (tmp_path / "taken").write_text("x")
    run_bad(["synth", "arm", tmp_path / "taken", "--subject-seed", "1"], capsys, "already exists")
    assert (tmp_path / "taken").read_text() == "x"
    (tmp_path / "folder").mkdir()
    run_bad(["synth", "arm", tmp_path / "folder", "--subject-seed", "1"], capsys, "already exists")


def test_synth_arm_unwritable_output(capsys):
    run_bad(["synth", "arm", "/sys/arm_session", "--subject-seed", "1"], capsys, "cannot write in /sys")


@pytest.mark.parametrize("args, phrase", [
    ([], "needs --model MODEL.npz"),
    (["--no-model", "--no-refine"], "choose one"),
    (["--model", "missing.npz"], "no such file"),
    (["--no-model", "--resolution", "13k"], "--resolution '13k': valid"),
    (["--no-model", "--side", "middle"], "--side 'middle': valid: left, right"),
    (["--no-model", "--frames", "0"], "--frames 0: must be in"),
    (["--no-model", "--frames", "9"], "--frames 9: "),
    (["--no-model", "--shape", "bmi=20,muscularity=0.5,height_m=1.7,arm_length_m=0.5"], "--shape needs the model"),
    (["--model", "missing.npz", "--shape", "bmi=20"], "--shape: needs bmi, muscularity"),
    (["--no-model", "--no-sequence-fit"], "the sequence fit is a model step"),
])
def test_capture_bad_options(arm_session, tmp_path, capsys, args, phrase):
    out = tmp_path / "cap"
    run_bad(["muscle", "capture", arm_session, "--out", out, *args], capsys, phrase)
    nothing_beside(tmp_path)


def test_capture_onto_existing_or_unwritable_output(arm_session, tmp_path, capsys):
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "keep.txt").write_text("previous")
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--no-model"], capsys, "already exists")
    assert (tmp_path / "cap" / "keep.txt").read_text() == "previous"
    run_bad(["muscle", "capture", arm_session, "--out", "/sys/cap", "--no-model"], capsys, "cannot write in /sys")


def test_capture_of_a_missing_session(tmp_path, capsys):
    run_bad(["muscle", "capture", tmp_path / "nope", "--out", tmp_path / "cap", "--no-model"], capsys, "nope")
    nothing_beside(tmp_path)


@pytest.mark.parametrize("make, phrase", [
    (lambda d: np.zeros_like(d), "no arm in range"),  # empty depth
    (lambda d: np.where(d > 0, d + 3.0, 0.0), "no arm in range"),  # everything 3 m farther: out of range
    (lambda d: d[::2, ::2], "but the depth camera"),  # wrong resolution for the calibration
])
def test_capture_of_unusable_depth(arm_session, tmp_path, capsys, make, phrase):
    bad = rewrite_depth(arm_session, tmp_path, make)
    out = tmp_path / "cap"
    run_bad(["muscle", "capture", bad, "--out", out, "--no-model"], capsys, phrase)
    nothing_beside(tmp_path, allowed=("bad_session",))


def test_capture_with_a_model_for_another_template(arm_session, tiny_arm_model_path, tmp_path, capsys):
    for extra, phrase in ((["--resolution", "6k"], "model was built for arm template 2k-left"),
                          (["--side", "right"], "model was built for arm template 2k-left")):
        run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--model", tiny_arm_model_path, *extra],
                capsys, phrase)
    nothing_beside(tmp_path)


@pytest.mark.parametrize("content, phrase", [
    (b"", "not a bodystudio arm model"),
    (b"PK\x03\x04 truncated zip", "not a bodystudio arm model"),
    (b"\x93NUMPY junk", "not a bodystudio arm model"),
])
def test_junk_model_file(arm_session, tmp_path, capsys, content, phrase):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(content)
    run_bad(["muscle", "capture", arm_session, "--out", tmp_path / "cap", "--model", junk], capsys, phrase)
    run_bad(["muscle", "model", "info", junk], capsys, phrase)
    run_bad(["muscle", "model", "extend", junk, tmp_path, "--out", tmp_path / "m2.npz"], capsys, phrase)
    nothing_beside(tmp_path, allowed=("junk.npz",))


@pytest.mark.parametrize("args, phrase", [
    (["--subjects", "1"], "--subjects 1: must be in [2, 100]"),
    (["--poses", "0"], "--poses 0: must be in"),
    (["--shapes", "11"], "--shapes 11: must be in"),
    (["--regularization", "-1"], "--regularization -1.0: must be in"),
    (["--regularization", "inf"], "--regularization inf: must be in"),
    (["--resolution", "4k"], "--resolution '4k': valid"),
    (["--side", "both"], "--side 'both': valid"),
])
def test_model_build_bad_options(tmp_path, capsys, args, phrase):
    run_bad(["muscle", "model", "build", "--out", tmp_path / "m.npz", *args], capsys, phrase)
    nothing_beside(tmp_path)


def test_model_build_bad_output(tmp_path, capsys):
    run_bad(["muscle", "model", "build", "--out", tmp_path / "m.txt"], capsys, "is a .npz file")
    (tmp_path / "m.npz").write_text("previous")
    run_bad(["muscle", "model", "build", "--out", tmp_path / "m.npz"], capsys, "already exists")
    assert (tmp_path / "m.npz").read_text() == "previous"
    run_bad(["muscle", "model", "build", "--out", "/sys/m.npz"], capsys, "cannot write in /sys")


@pytest.fixture(scope="module")
def nicp_capture(arm_session, tmp_path_factory):
    out = tmp_path_factory.mktemp("cap") / "nicp"
    assert main(["muscle", "capture", str(arm_session), "--out", str(out), "--no-model"]) == 0
    return out


@pytest.mark.parametrize("args, phrase", [
    (["--shape", "bmi=31"], "--shape: needs bmi, muscularity, height_m, arm_length_m"),
    (["--shape", "bmi=abc,muscularity=0.3,height_m=1.6,arm_length_m=0.5"], "NAME=VALUE"),
    (["--shape", "weight=80"], "names are bmi, muscularity"),
    (["--shape", "bmi=31,muscularity=3,height_m=1.6,arm_length_m=0.5"], "--shape muscularity 3.0: must be in"),
    (["--stride", "0"], "--stride 0: must be in"),
])
def test_model_extend_bad_options(tiny_arm_model_path, nicp_capture, tmp_path, capsys, args, phrase):
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, nicp_capture, "--out", tmp_path / "m2.npz", *args],
            capsys, phrase)
    nothing_beside(tmp_path)


def test_model_extend_needs_one_shape_per_capture(tiny_arm_model_path, nicp_capture, tmp_path, capsys):
    """One --shape for two captures would give both subjects the same measured shape: refused."""
    shape = "bmi=24,muscularity=0.4,height_m=1.75,arm_length_m=0.55"
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, nicp_capture, nicp_capture, "--out",
             tmp_path / "m2.npz", "--shape", shape], capsys, "--shape: 1 given for 2 captures")
    nothing_beside(tmp_path)


def test_model_extend_bad_captures(tiny_arm_model_path, nicp_capture, tmp_path, capsys):
    out = tmp_path / "m2.npz"
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, tmp_path / "none", "--out", out], capsys,
            "no such arm capture folder")
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, nicp_capture, "--out", out], capsys,
            "captured with --no-model")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "params.json").write_text("{not json")
    run_bad(["muscle", "model", "extend", tiny_arm_model_path, tmp_path / "junk", "--out", out], capsys, "junk")
    nothing_beside(tmp_path, allowed=("junk",))


def test_eval_muscle_bad_folders(nicp_capture, tmp_path, capsys):
    run_bad(["eval", "muscle", tmp_path / "none"], capsys, "no such arm capture folder")
    (tmp_path / "empty").mkdir()
    run_bad(["eval", "muscle", tmp_path / "empty"], capsys, "empty")
    run_bad(["eval", "muscle", nicp_capture, "--session", tmp_path / "gone"], capsys, "gone")
    # a capture whose meshes were lost
    broken = tmp_path / "broken"
    shutil.copytree(nicp_capture, broken)
    (broken / "meshes" / "00001.ply").unlink()
    run_bad(["eval", "muscle", broken], capsys, "broken")


def test_eval_muscle_of_a_session_without_truth(nicp_capture, arm_session, tmp_path, capsys):
    """A capture scored against a session of another template (the truth has other vertices)."""
    other = tmp_path / "s6k"
    assert main(["synth", "arm", str(other), "--subject-seed", "5", "--frames", "3", "--resolution", "6k"]) == 0
    capsys.readouterr()
    run_bad(["eval", "muscle", nicp_capture, "--session", other], capsys, "captured from another recording")
    # a capture written before the recording's fingerprint existed reaches the template check
    import json

    old = tmp_path / "old_capture"
    shutil.copytree(nicp_capture, old)
    params = json.loads((old / "params.json").read_text())
    del params["session_fingerprint"]
    (old / "params.json").write_text(json.dumps(params))
    run_bad(["eval", "muscle", old, "--session", other], capsys, "template")


def test_capture_without_the_sequence_fit_runs_and_differs(arm_session, tiny_arm_model_path, tmp_path):
    """--no-sequence-fit is the pipeline before the whole-sequence pose fit: it runs and gives other meshes."""
    meshes = {}
    for name, extra in (("with", []), ("without", ["--no-sequence-fit"])):
        out = tmp_path / name
        assert main(["muscle", "capture", str(arm_session), "--out", str(out), "--model", str(tiny_arm_model_path),
                     *extra]) == 0
        meshes[name] = (out / "meshes" / "00002.ply").read_bytes()
    assert meshes["with"] != meshes["without"]


def test_eval_muscle_refuses_another_recordings_truth(nicp_capture, arm_session, tmp_path, capsys):
    """A capture scored against another recording of the same template (another subject) would print a
    meaningless score with exit 0; it is refused. A copy of its own session (moved, renamed) still scores."""
    other = tmp_path / "other"
    assert main(["synth", "arm", str(other), "--subject-seed", "6", "--frames", "3", "--resolution", "2k"]) == 0
    capsys.readouterr()
    run_bad(["eval", "muscle", nicp_capture, "--session", other], capsys, "captured from another recording")
    copy = tmp_path / "moved"
    shutil.copytree(arm_session, copy)
    assert main(["eval", "muscle", str(nicp_capture), "--session", str(copy)]) == 0
    assert '"median_mm"' in capsys.readouterr().out
