"""``mirror init --silhouette-shape --frames 1`` (adversarial pass 3): the shape was refined against one
silhouette instead of six, and the summary said only ``silhouette_shape: true``. It now records how many
silhouettes were used (``silhouette_frames``; 0 without the option)."""

from __future__ import annotations

import json

from bodystudio.cli.main import main


def test_summary_says_how_many_silhouettes(tmp_path, capsys):
    s = tmp_path / "s"
    assert main(["synth", "mirror", str(s), "--subject-seed", "3", "--frames", "12", "--no-walk-in"]) == 0
    assert main(["mirror", "init", str(s), "--resolution", "2k", "--frames", "1", "--silhouette-shape"]) == 0
    summary = json.loads((s / "mirror" / "source_body.json").read_text())
    assert summary["silhouette_shape"] is True and summary["silhouette_frames"] == 1
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["silhouette_frames"] == 1
    assert main(["mirror", "init", str(s), "--resolution", "2k", "--frames", "1", "--force"]) == 0
    assert json.loads((s / "mirror" / "source_body.json").read_text())["silhouette_frames"] == 0
