"""The readers of ``mirror init``'s source body and an interrupted ``mirror init --force`` (adversarial pass 3):
``mirror init`` writes the body and its summary as one unit (RunWriter), but ``load_source_body`` did not look
at that unit's commit record, so a write killed after its commit point (the new body moved in, the summary
still the old one's, or the reverse) was read by ``mirror run`` / ``eval mirror`` / the viewer with exit 0.
Now every reader refuses it with one line naming ``bodystudio recover``; after the recover it reads again."""

from __future__ import annotations

import json
import shutil

import pytest

from bodystudio.cli.main import main
from bodystudio.errors import BodyStudioError
from bodystudio.mirror.init import load_source_body

from .conftest import run_bad


@pytest.fixture(scope="module")
def initialised(tmp_path_factory):
    s = tmp_path_factory.mktemp("adv3src") / "s"
    assert main(["synth", "mirror", str(s), "--subject-seed", "3", "--frames", "12", "--no-walk-in"]) == 0
    assert main(["mirror", "init", str(s), "--resolution", "2k", "--frames", "1"]) == 0
    return s


def _interrupt_after_commit_point(session, tmp_path):
    """A copy of ``session`` as ``mirror init --force`` killed after writing its commit record."""
    s = tmp_path / "s"
    shutil.copytree(session, s)
    staging = s / "mirror" / ".source_body.npz.staging"
    staging.mkdir()
    shutil.copy(s / "mirror" / "source_body.npz", staging / "source_body.npz")
    plan = {"moves": ["source_body.npz"], "deletes": [], "manifest_name": "source_body.json",
            "manifest": json.loads((s / "mirror" / "source_body.json").read_text())}
    (staging / "commit.json").write_text(json.dumps(plan))
    return s


def test_readers_refuse_an_unfinished_init_until_recovered(initialised, tmp_path, capsys):
    s = _interrupt_after_commit_point(initialised, tmp_path)
    body = s / "mirror" / "source_body.npz"
    with pytest.raises(BodyStudioError, match="interrupted while committing; run `bodystudio recover"):
        load_source_body(body)
    capsys.readouterr()
    run_bad(["mirror", "run", s, "--taller", "0.1", "--out", tmp_path / "o.mp4"], capsys, "bodystudio recover")
    assert not (s / "mirror" / "run").exists() and not (tmp_path / "o.mp4").exists()
    assert main(["recover", str(body)]) == 0
    assert not (s / "mirror" / ".source_body.npz.staging").exists()
    assert load_source_body(body).vertices.shape[1] == 3
