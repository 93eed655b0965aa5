"""``garment fit --keyframes`` (adversarial pass): a point far outside the image ran the whole shape fit and
then failed with a misleading 'no body vertex is visible'; keyframes only on frames that are not fitted
(another --frames range, a typo) were silently ignored with exit 0. Both are now refused with one line,
before the shape fit, and nothing is written."""

import json

import pytest

from .conftest import run_bad


@pytest.fixture(scope="module")
def garment_session(tmp_path_factory):
    from bodystudio.garment.synthetic import synth_garment_session

    root = tmp_path_factory.mktemp("advkf")
    synth_garment_session(root / "session", subject_seed=3, n_frames=2, resolution=(120, 160), template="2k",
                          texture_size=64, seed=2)
    return root / "session"


@pytest.mark.parametrize("frames, phrase", [
    ({"0": {"hand_l": [1e9, 5]}}, "outside the 120x160 image"),
    ({"0": {"hand_l": [-3, 5]}}, "outside the 120x160 image"),
    ({"99": {"hand_l": [10, 5]}}, "no keyframe is on a fitted frame"),
])
def test_bad_keyframes_are_refused_before_the_fit(garment_session, tmp_path, capsys, frames, phrase):
    kf = tmp_path / "kf.json"
    kf.write_text(json.dumps({"frames": frames}))
    out = tmp_path / "fit"
    run_bad(["garment", "fit", garment_session, "--stature", "1.7", "--out", out, "--keyframes", kf], capsys, phrase)
    assert not out.exists()


def test_keyframes_on_frames_out_of_the_range_are_refused(garment_session, tmp_path, capsys):
    kf = tmp_path / "kf.json"
    kf.write_text(json.dumps({"frames": {"1": {"hand_l": [10, 5]}}}))
    run_bad(["garment", "fit", garment_session, "--stature", "1.7", "--out", tmp_path / "fit", "--frames", "0:1",
             "--keyframes", kf], capsys, "no keyframe is on a fitted frame (keyframes on [1], fitted 0..0)")
