"""``muscle model build --women K``: training women besides the men (docs/muscle.md, "Women in the capture").

Bad counts are refused in one line before any work, nothing written; a good one reaches the training set as that
many women after the men (``training_dataset(n_women=K)``), the men as without it.
"""

import json

import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.mark.parametrize("args, phrase", [
    (["--women", "-1"], "--women -1: must be in [0, 100]"),
    (["--women", "101"], "--women 101: must be in [0, 100]"),
    (["--subjects", "1", "--women", "5"], "--subjects 1: must be in [2, 100]"),  # women do not stand in for men
    (["--subjects", "90", "--women", "20"], "--subjects 90 --women 20: 110 training subjects; at most 100"),
])
def test_model_build_bad_women(tmp_path, capsys, args, phrase):
    run_bad(["muscle", "model", "build", "--out", tmp_path / "m.npz", *args], capsys, phrase)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, men, women", [([], 10, 5), (["--women", "0"], 10, 0), (["--women", "3"], 10, 3),
                                              (["--subjects", "2", "--women", "1"], 2, 1)])
def test_model_build_passes_the_women_on(tmp_path, capsys, monkeypatch, args, men, women):
    """The counts reach ``training_dataset`` (the learning is stubbed: this is the CLI's wiring); the summary line
    says how many of each."""
    from types import SimpleNamespace

    import bodystudio.muscle.model as model_mod
    import bodystudio.muscle.synthetic as syn

    asked = []
    monkeypatch.setattr(syn, "training_dataset", lambda *a, **k: asked.append((a, k)) or ([], []))
    monkeypatch.setattr(model_mod, "learn_arm_model", lambda samples, template, q, sex_slopes: SimpleNamespace(
        subjects=[0] * (men + women), template_key="stub"))
    monkeypatch.setattr(model_mod, "save_arm_model", lambda path, model: path.write_text(json.dumps(model.subjects)))
    monkeypatch.setattr("bodystudio.cli.muscle._arm_template", lambda resolution, side: None)
    out = tmp_path / "m.npz"
    assert main(["muscle", "model", "build", "--out", str(out), *args]) == 0
    (a, k), = asked
    assert a[1] == men and k == {"n_women": women}
    assert f"({men} men, {women} women)" in capsys.readouterr().out
