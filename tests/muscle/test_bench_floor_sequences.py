"""``benchmarks.muscle_floor`` (the model's floor against the training set) and ``benchmarks.muscle_sequences``
(capture settings side by side on held-out sequences): their parts that the measurements rest on."""

from types import SimpleNamespace

import numpy as np
import pytest


def test_the_floor_oracles_rest_mesh_is_the_truths():
    """``own rest``: the subject's rest mesh posed with its own skin weights, joints and the truth's muscle at that
    pose gives the truth's mesh exactly, so what the oracle row leaves is the model's pose term and skinning."""
    from benchmarks.muscle_floor import subject_parts
    from bodystudio.muscle.arm import ArmPose, pose_arm
    from bodystudio.muscle.synthetic import (
        MuscleVariation,
        muscle_displacement,
        sample_arm_subject,
        subject_arm_samples,
    )

    subject = sample_arm_subject(5)
    rest, weights, joints, T = subject_parts(subject)
    sample = subject_arm_samples(subject, "6k", n_shapes=0, n_poses=1, seed=4)[0]
    v = MuscleVariation.from_seed(subject.seed)
    posed_muscle = muscle_displacement(T, subject, sample.pose, v) - muscle_displacement(T, subject, ArmPose.rest(), v)
    np.testing.assert_allclose(pose_arm(rest + posed_muscle, weights, joints, sample.pose), sample.vertices,
                               atol=1e-9)
    # the rest mesh carries the muscle at rest (a bulge-free template would be millimetres off the truth)
    assert np.abs(rest - T.vertices).max() > 1e-4


def test_sequence_variants_by_name_and_by_fields():
    from benchmarks.muscle_sequences import VARIANTS, parse_variant

    assert parse_variant("default") == ("default", {})
    assert parse_variant("unpinned") == ("unpinned", {"sequence_pinned_se_m": 0.0})
    name, options = parse_variant("a0t10")
    assert name == "a0t10" and options == VARIANTS["a0t10"] and options["norm_limit"] == 0.05
    from bodystudio.muscle.capture import PINNED_SEQUENCE

    assert options == PINNED_SEQUENCE  # the measured variant is the pinned sequences' setting
    assert parse_variant("w:sequence_tracker_weight=3.0,norm_limit=0.2") == (
        "w", {"sequence_tracker_weight": 3.0, "norm_limit": 0.2})
    with pytest.raises(ValueError, match="unknown variant 'nope'"):
        parse_variant("nope")


def test_muscle_sequences_refuses_an_unknown_variant_in_one_line(tmp_path, capsys):
    from benchmarks.muscle_sequences import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--variant", "nope"])
    assert exc.value.code == 2
    assert "unknown variant 'nope'" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "w").exists()


@pytest.mark.parametrize("item", ["504", "504:x", "504:0:1", "a:0"])
def test_muscle_sequences_refuses_a_bad_session_in_one_line(item, tmp_path, capsys):
    from benchmarks.muscle_sequences import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), "--session", item])
    assert exc.value.code == 2
    assert f"--session {item!r}: needs SUBJECT:NOISE_SEED" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "w").exists()


@pytest.mark.parametrize("args", [["--sessions", "504:0"], ["--sessions", "504:0:a"], ["--train", "10"],
                                  ["--train", "10x3x4x5"], ["--norm-limit", "1.5"]])
def test_muscle_floor_refuses_bad_arguments_in_one_line(args, tmp_path, capsys):
    from benchmarks.muscle_floor import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path / "w"), *args])
    assert exc.value.code == 2
    assert args[0] in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "w").exists()


def test_muscle_rest_ceiling_refuses_a_bad_session_in_one_line(tmp_path, capsys):
    from benchmarks.muscle_rest_ceiling import main

    with pytest.raises(SystemExit) as exc:
        main(["--work", str(tmp_path), "--session", "504"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "SUBJECT:NOISE_SEED" in err[-1] and not list(tmp_path.iterdir())


@pytest.mark.parametrize("flag, known, suffix", [([], "measured", ""), (["--no-shape"], None, "_noshape")])
def test_muscle_sequences_no_shape_fits_the_shape(flag, known, suffix, tmp_path, monkeypatch, capsys):
    """``--no-shape``: the capture gets no measured shape (``muscle capture`` without ``--shape``: the sex taken as
    male), under its own file name, so both runs of one session sit side by side (docs/muscle.md, "Women in the
    capture"); the capture and its model stubbed."""
    import json

    import benchmarks.bench_muscle as bm
    import benchmarks.muscle_energy as energy
    import benchmarks.muscle_sequences as seq

    given = []
    monkeypatch.setattr(bm, "_template", lambda: None)
    monkeypatch.setattr(bm, "truth_template", lambda subject: None)
    monkeypatch.setattr(seq, "typed_shape", lambda subject: "measured")
    monkeypatch.setattr(energy, "work_model", lambda work, template: None)
    monkeypatch.setattr(seq, "session_of", lambda work, s, n, f, fps=30.0: ("subject", "session"))
    captured = SimpleNamespace(shape=SimpleNamespace(sex=0.0), sex_fit={"chosen": "female"} if flag else None)
    monkeypatch.setattr(bm, "capture_and_score", lambda *a, known_shape: given.append(known_shape) or (
        captured, {k: 1.0 for k in seq.KEYS}))
    seq.main(["--work", str(tmp_path), "--session", "516:0", "--frames", "2", "--variant", "default", *flag])
    assert given == [known]
    row = json.loads((tmp_path / f"seq_516_s0_2_default{suffix}.json").read_text())
    assert row["variant"] == "default" + (" (no --shape)" if flag else "")
    assert ("(no --shape)" in capsys.readouterr().out) == bool(flag)
    assert row["sex"] == 0.0 and row["sex_fit"] == captured.sex_fit  # the run record: the sex used, its evidence


@pytest.mark.parametrize("gender, sex", [(0.89, 1.0), (0.5, 1.0), (0.07, 0.0), (0.49, 0.0)])
def test_muscle_sequences_gives_the_sex_as_a_user_types_it(gender, sex):
    """The runner's measured shape carries ``sex=male|female`` (MakeHuman's gender rounded), not the fractional
    gender: 508's 0.89 gave a man 11 % of a woman's offset in a model that knows women (docs/muscle.md)."""
    from benchmarks.bench_muscle import shape_of
    from benchmarks.muscle_sequences import typed_shape

    subject = SimpleNamespace(bmi=22.0, muscularity=0.5, height_m=1.7, arm_length_m=0.5, gender=gender)
    shape = typed_shape(subject)
    assert shape.sex == sex and (shape.bmi, shape.height_m, shape.arm_length_m) == (22.0, 1.7, 0.5)
    # the benchmark's own steps (compare, extension, pronation) give the same typed sex (mus11z; 502's 0.048 was
    # passed as it is)
    assert shape_of(subject) == shape
