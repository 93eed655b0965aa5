"""``muscle model build --sex-slopes``: the women's own slopes (the shape term's interaction ``(1 - sex) z``;
docs/muscle.md, "Women's own slopes").

Refused in one line before any work, nothing written, where it cannot be learned (no training women, no
regularization); otherwise it reaches ``learn_arm_model`` (off without the flag), the summary line says so, and
``muscle model info`` reports it.
"""

import json
from types import SimpleNamespace

import pytest

from bodystudio.cli.main import main

from .conftest import run_bad


@pytest.mark.parametrize("args, phrase", [
    (["--sex-slopes", "--women", "0"], "--sex-slopes: the women's own slopes are learned from the training women; "
                                       "give --women > 0"),
    (["--sex-slopes", "--regularization", "0"], "--sex-slopes --regularization 0: the women's own slopes need a "
                                                "regularization > 0"),
])
def test_model_build_bad_sex_slopes(tmp_path, capsys, args, phrase):
    run_bad(["muscle", "model", "build", "--out", tmp_path / "m.npz", *args], capsys, phrase)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, slopes", [([], False), (["--sex-slopes"], True)])
def test_model_build_passes_the_sex_slopes_on(tmp_path, capsys, monkeypatch, args, slopes):
    """The flag reaches ``learn_arm_model`` (stubbed: the CLI's wiring) and the summary line."""
    import bodystudio.muscle.model as model_mod
    import bodystudio.muscle.synthetic as syn

    asked = []
    monkeypatch.setattr(syn, "training_dataset", lambda *a, **k: ([], []))
    monkeypatch.setattr(model_mod, "learn_arm_model", lambda samples, template, q, sex_slopes: asked.append(
        sex_slopes) or SimpleNamespace(subjects=[0] * 15, template_key="stub"))
    monkeypatch.setattr(model_mod, "save_arm_model", lambda path, model: path.write_text("stub"))
    monkeypatch.setattr("bodystudio.cli.muscle._arm_template", lambda resolution, side: None)
    assert main(["muscle", "model", "build", "--out", str(tmp_path / "m.npz"), *args]) == 0
    assert asked == [slopes]
    assert ("the women's own slopes" in capsys.readouterr().out) == slopes


def test_model_info_reports_the_sex_slopes(tmp_path, capsys):
    from bodystudio.muscle.model import save_arm_model
    from tests.muscle.test_sex_slopes import _model

    for slopes in (False, True):
        save_arm_model(tmp_path / f"m{slopes}.npz", _model(slopes))
        assert main(["muscle", "model", "info", str(tmp_path / f"m{slopes}.npz")]) == 0
        assert json.loads(capsys.readouterr().out)["sex_slopes"] is slopes
