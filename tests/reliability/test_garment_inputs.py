"""Bad input to the garment stage (garments, user garment meshes, lighting, synth garment): one-line errors.

API cases assert the error type and a phrase of its one-line message; CLI cases the exit code 2 and one
stderr line, and that nothing is left at the output path.
"""

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, FileFormatError, InputError


@pytest.fixture(scope="module")
def body():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


def one_line(exc_info, phrase):
    msg = str(exc_info.value)
    assert "\n" not in msg and phrase in msg, msg


@pytest.mark.parametrize("kwargs, phrase", [
    ({"name": "poncho"}, "unknown garment 'poncho'; valid: tights, skirt, tshirt, longsleeve"),
    ({"name": "tshirt", "pattern": "paisley"}, "unknown cloth pattern 'paisley'; valid: stripes"),
    ({"name": "skirt", "texture_size": 8}, "texture size 8 must lie in [16, 4096]"),
    ({"name": "skirt", "texture_size": 100000}, "texture size 100000 must lie in [16, 4096]"),
])
def test_dress_refuses_bad_choices(body, kwargs, phrase):
    from bodystudio.garment.garments import dress

    with pytest.raises(InputError) as e:
        dress(body, **kwargs)
    one_line(e, phrase)


def test_dress_needs_a_body():
    from bodystudio.garment.garments import dress

    with pytest.raises(InputError) as e:
        dress("body.ply", "tshirt")
    one_line(e, "dress needs a BodyModel")


def _write(path, V, F):
    import trimesh

    trimesh.Trimesh(V, F, process=False).export(path)
    return path


def test_user_garment_files(body, tmp_path):
    from bodystudio.garment.garments import load_garment_mesh

    F = body.faces[:200]
    cases = []
    cases.append((tmp_path / "missing.obj", FileFormatError, "no such garment mesh file"))
    (tmp_path / "notes.txt").write_text("hello")
    cases.append((tmp_path / "notes.txt", FileFormatError, "unsupported garment format; use .obj"))
    (tmp_path / "garbage.glb").write_bytes(b"\x00\x01not a glb")
    cases.append((tmp_path / "garbage.glb", FileFormatError, "cannot read the garment mesh"))
    (tmp_path / "empty.obj").write_text("v 0 0 0\nv 1 0 0\n")
    cases.append((tmp_path / "empty.obj", FileFormatError, "contains no triangles"))
    cases.append((_write(tmp_path / "cm.ply", body.vertices * 100, F), InputError, "export it in metres"))
    far = body.vertices + np.array([0.0, 0.0, 1.0])
    cases.append((_write(tmp_path / "far.ply", far, F), InputError, "from the body surface; place it on"))
    (tmp_path / "nan.obj").write_text("v 0 nan 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    cases.append((tmp_path / "nan.obj", FileFormatError, "1 vertices are NaN or infinite"))
    for path, kind, phrase in cases:
        with pytest.raises(kind) as e:
            load_garment_mesh(path, body)
        one_line(e, phrase)


def test_pose_garment_of_another_rig(body):
    from bodystudio.body import Pose, build_body
    from bodystudio.garment.garments import dress, pose_garment

    g = dress(body, "skirt", texture_size=16)
    other = build_body(resolution="2k", rig="cmu_mb")
    with pytest.raises(InputError) as e:
        pose_garment(g, other, Pose.rest(other.skeleton.n_bones))
    one_line(e, "dress this body again")


def test_errors_are_bodystudio_errors():
    assert issubclass(InputError, BodyStudioError) and issubclass(FileFormatError, BodyStudioError)
