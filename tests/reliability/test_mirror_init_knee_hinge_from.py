"""The init's ``knee_hinge_from`` (mir12ac) and the unposing benchmark's ``--knee-hinge-from`` refuse a bad value with
one line naming it, before any work and without writing anything."""

import numpy as np
import pytest

from benchmarks.mirror_init_unpose_pose import main
from bodystudio.errors import InputError
from bodystudio.mirror.init import initialise_from_observations


@pytest.fixture(scope="module")
def model():
    from bodystudio.body.statistical import load_statistical_model

    return load_statistical_model("2k", progress=False)


@pytest.mark.parametrize("value", ["ik", "SDK", "", None, 3])
def test_bad_knee_hinge_from_is_refused(model, value):
    with pytest.raises(InputError, match=r"knee_hinge_from must be 'refined' \(the previous pass's refined poses\) "
                                         r"or 'sdk' \(the SDK joints' knee angle\), got") as err:
        initialise_from_observations([], model, view_point=np.zeros(3), knee_hinge_weight=3000.0,
                                     knee_hinge_from=value)
    assert "\n" not in str(err.value)


def test_the_benchmark_refuses_an_unknown_knee_hinge_source(tmp_path, capsys):
    s = tmp_path / "S57"
    (s / "gt" / "mirror").mkdir(parents=True)
    (s / "gt" / "mirror" / "actors.npz").write_bytes(b"")
    with pytest.raises(SystemExit) as exc:
        main([str(s), "--knee-hinge-weight", "3000", "--knee-hinge-from", "ik", "--shadow", str(tmp_path / "W"),
              "--name", "knee.npz"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--knee-hinge-from: invalid choice: 'ik'" in err and "'sdk'" in err
    assert not (tmp_path / "W").exists()


@pytest.mark.parametrize("frames", [3, [np.zeros((25, 3))], "frames"])
def test_bad_knee_frames_are_refused(model, frames):
    with pytest.raises(InputError, match=r"knee_frames must be frames of SDK joints with joints, tracked and version "
                                         r"\(knee_joint_frames\(session, observations\)\), got a") as err:
        initialise_from_observations([], model, view_point=np.zeros(3), knee_frames=frames)
    assert "\n" not in str(err.value)
