"""`bodystudio body ...` through the real CLI entry point: outputs, and one-line errors with exit code 2."""

import json

import numpy as np
import pytest

from bodystudio.cli.main import main
from bodystudio.geometry.mesh import load_mesh


def test_export_writes_a_posed_mesh(tmp_path, capsys):
    pose = tmp_path / "pose.json"
    pose.write_text(json.dumps({"rotations": {"lowerarm_l": [1.5708, 0, 0]}, "translation": [0, 0, 0]}))
    rest, bent = tmp_path / "rest.ply", tmp_path / "bent.obj"
    assert main(["body", "export", str(rest), "--gender", "1", "--resolution", "2k"]) == 0
    assert main(["body", "export", str(bent), "--gender", "1", "--resolution", "2k", "--pose", str(pose)]) == 0
    a, b = load_mesh(rest), load_mesh(bent)
    assert a.n_vertices == b.n_vertices == len(a.vertices) and 2000 < a.n_vertices < 3000
    moved = np.linalg.norm(a.vertices - b.vertices, axis=1)
    assert moved.max() > 0.1 and np.median(moved) < 1e-6
    assert "stature" in capsys.readouterr().out


def test_info_reports_counts(capsys):
    assert main(["body", "info"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["full"]["vertices"] == 13380 and info["6k"]["joints"] == 53
    assert 1.5 < info["default_body"]["stature_m"] < 1.8


@pytest.mark.parametrize("args, message", [
    (["--gender", "2"], "gender=2.0 is out of range"),
    (["--local", "nosuch=0.5"], "unknown local modifier"),
    (["--local", "upperarm-fat-decr-incr"], "NAME=VALUE"),
    (["--resolution", "huge"], "valid: full, 6k, 2k"),
    (["--rig", "nope"], "valid rigs"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    out = tmp_path / "x.ply"
    assert main(["body", "export", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
    assert not out.exists()


def test_malformed_pose_file(tmp_path, capsys):
    pose = tmp_path / "pose.json"
    pose.write_text('{"rotations": {"lowerarm_l": "ninety degrees"}}')
    assert main(["body", "export", str(tmp_path / "x.ply"), "--pose", str(pose)]) == 2
    err = capsys.readouterr().err
    assert str(pose) in err and "3 finite numbers" in err


def test_export_takes_the_ethnic_weights(tmp_path):
    """--african/--asian/--caucasian reach MakeHuman's ethnic macro targets (normalised to sum 1)."""
    paths = {}
    for name, weights in (("mixed", ()), ("african", ("--african", "1", "--asian", "0", "--caucasian", "0")),
                          ("asian", ("--african", "0", "--asian", "1", "--caucasian", "0"))):
        paths[name] = tmp_path / f"{name}.ply"
        assert main(["body", "export", str(paths[name]), "--resolution", "2k", *weights]) == 0
    V = {k: load_mesh(p).vertices for k, p in paths.items()}
    assert np.abs(V["african"] - V["asian"]).max() > 0.005  # the ethnic targets move the body by millimetres+
    assert np.abs(V["mixed"] - V["african"]).max() > 0.002
