"""``mirror run`` on a session whose Kinect colour images were exported mirrored left-right (adversarial pass 4).

The registration check refused it, but named kinect/calibration.json and "re-calibrate the Kinect", which cannot fix
it. When the depth misses the colour image's edges the check now also searches the colour images flipped; if they
fit flipped, the one line names the mirrored colour stream and the fix (re-import it unmirrored). A registered session
pays nothing for it (the flipped search runs only past the warning threshold)."""

from __future__ import annotations

import shutil

import cv2
import pytest

from bodystudio.capture.faults import restamp
from bodystudio.errors import ImplausibleResultError


@pytest.fixture(scope="module")
def mirror_session(tmp_path_factory):
    from bodystudio.mirror.synthetic import synth_mirror_session

    S = tmp_path_factory.mktemp("adv4mirrgb") / "S"
    synth_mirror_session(S, subject_seed=5, n_frames=11, walk_in=False)  # the actor in place from frame 10
    return S


def test_mirrored_colour_images_are_named(mirror_session, tmp_path):
    from bodystudio.capture.session import open_session
    from bodystudio.mirror.plausibility import check_registration

    clean = check_registration(open_session(mirror_session))
    assert clean["ok"] and "offset_mirrored_px" not in clean
    S = shutil.copytree(mirror_session, tmp_path / "S")
    for p in sorted((S / "kinect" / "rgb").glob("*.png")):
        cv2.imwrite(str(p), cv2.imread(str(p), cv2.IMREAD_UNCHANGED)[:, ::-1])
        restamp(S, f"kinect/rgb/{p.name}")
    with pytest.raises(ImplausibleResultError, match="kinect/rgb: the colour images are mirrored left-right") as err:
        check_registration(open_session(S))
    assert "re-import the Kinect colour stream unmirrored" in str(err.value) and "calibration" not in str(err.value)
    accepted = check_registration(open_session(S), accept_implausible=True)
    assert not accepted["ok"] and accepted["offset_mirrored_px"] <= 4.0 < accepted["offset_px"]
