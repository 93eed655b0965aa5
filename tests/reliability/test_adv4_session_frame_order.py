"""A session manifest whose ``frames`` repeat or reorder an id (a hand-merged session.json; adversarial pass 4).

The session writer sorts the ids, but the reader took any list: every stage then processed a repeated frame twice
and reordered frames out of time order (tracking from the wrong neighbour, smoothing across the wrong frames) with
exit 0. The reader now refuses it in one line naming session.json."""

from __future__ import annotations

import json

import pytest

from tests.reliability.conftest import assert_clean_error, run_inprocess


@pytest.mark.parametrize("frames, phrase", [([1, 0], "lists frame 0 after 1"), ([0, 0, 1], "lists frame 0 after 0")],
                         ids=["reordered", "repeated"])
def test_reordered_or_repeated_frame_ids_are_refused(studio, tmp_path, capfd, frames, phrase):
    S = studio.copy_session(tmp_path / "S")
    manifest = json.loads((S / "session.json").read_text())
    manifest["frames"] = frames
    (S / "session.json").write_text(json.dumps(manifest))
    result = run_inprocess(["capture", "verify", S], capfd)
    assert_clean_error(result, 2, f"{S / 'session.json'}: manifest field 'frames' {phrase}")
    out = run_inprocess(["reconstruct", S, "--template", "2k", "--outer", "1", "--inner", "1"], capfd)
    assert_clean_error(out, 2, "each frame id once, increasing")
    assert not (S / "reconstruct").exists()
