"""Bad input to the garment stage (garments, user garment meshes, lighting, synth garment): one-line errors.

API cases assert the error type and a phrase of its one-line message; CLI cases the exit code 2 and one
stderr line, and that nothing is left at the output path.
"""

import numpy as np
import pytest

from bodystudio.errors import BodyStudioError, FileFormatError, InputError

from .conftest import run_bad


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


@pytest.mark.parametrize("args, phrase", [
    (([[0, 0, 1]], [[-1, 1, 1]], [0, 0, 0]), "light colours and ambient must be >= 0"),
    (([[0, 0, 0]], [[1, 1, 1]], [0, 0, 0]), "finite non-zero vectors"),
    (([[0, 0, 1], [0, 1, 0]], [[1, 1, 1]], [0, 0, 0]), "one colour per direction, got 2 and 1"),
    (([[0, np.nan, 1]], [[1, 1, 1]], [0, 0, 0]), "finite non-zero vectors"),
])
def test_lighting_refuses_impossible_lights(args, phrase):
    from bodystudio.garment.lighting import Lighting

    with pytest.raises(InputError) as e:
        Lighting(*args)
    one_line(e, phrase)


def test_lighting_estimation_inputs():
    from bodystudio.garment.lighting import dominant_light_direction, estimate_albedo, estimate_lighting, solve_lights

    P = np.zeros((5, 3))
    with pytest.raises(InputError) as e:
        estimate_lighting(P, P, P, P, np.array([0, 0, 1.0]))
    one_line(e, "at least 10 body pixels, got 5; is the person in view?")
    with pytest.raises(InputError) as e:
        estimate_lighting(np.zeros((20, 3)), np.zeros((20, 2)), np.zeros((20, 3)), np.zeros((20, 3)), [0, 0, 1])
    one_line(e, "normals must be (20, 3)")
    with pytest.raises(InputError) as e:
        solve_lights(np.ones((20, 4)), np.ones((20, 3)), np.ones((20, 3)), "cvx")
    one_line(e, "unknown lighting solver 'cvx'; valid: nnls, fast_nnls, lstsq")
    with pytest.raises(InputError) as e:
        dominant_light_direction(np.eye(3), np.zeros((3, 3)))
    one_line(e, "no light has positive intensity")
    with pytest.raises(InputError) as e:
        estimate_albedo([np.zeros((4, 4, 3), np.uint8)], [], np.zeros((1, 3), int), None)
    one_line(e, "one posed mesh per frame, got 1 frames and 0 meshes")


@pytest.mark.parametrize("extra, phrase", [
    (["--garment", "poncho"], "--garment 'poncho': valid: tights, skirt, tshirt, longsleeve"),
    (["--pattern", "paisley"], "--pattern 'paisley': valid: stripes, checks, print, plain"),
    (["--motion", "dance"], "--motion 'dance': valid: walk"),
    (["--frames", "0"], "--frames 0: must be in [1, 2000]"),
    (["--frames", "5000"], "--frames 5000: must be in [1, 2000]"),
    (["--resolution", "big"], "--resolution 'big' must be WIDTHxHEIGHT"),
    (["--resolution", "20x20"], "--resolution 20x20: width and height must be in [64, 4096]"),
    (["--resolution", "9000x9000"], "--resolution 9000x9000: width and height must be in [64, 4096]"),
])
def test_synth_garment_bad_options(tmp_path, capsys, extra, phrase):
    out = tmp_path / "session"
    run_bad(["synth", "garment", out, "--subject-seed", "3", *extra], capsys, phrase)
    assert not out.exists()


def test_synth_garment_refuses_a_used_folder_and_a_negative_seed(tmp_path, capsys):
    used = tmp_path / "used"
    used.mkdir()
    (used / "keep.txt").write_text("mine")
    run_bad(["synth", "garment", used, "--subject-seed", "3"], capsys, "exists and is not empty")
    assert [p.name for p in used.iterdir()] == ["keep.txt"]
    afile = tmp_path / "file"
    afile.write_text("x")
    run_bad(["synth", "garment", afile, "--subject-seed", "3"], capsys, "is a file, not a folder")
    run_bad(["synth", "garment", tmp_path / "neg", "--subject-seed", "-1"], capsys, "--subject-seed -1: must be >= 0")
    assert not (tmp_path / "neg").exists()


def _fuzz_settings():
    from hypothesis import HealthCheck, settings

    return settings(max_examples=30, deadline=None, database=None, derandomize=True,
                    suppress_health_check=list(HealthCheck))


def test_fuzzed_lighting_files_load_or_raise_one_line():
    from hypothesis import given
    from hypothesis import strategies as st

    from bodystudio.garment.lighting import Lighting

    leaf = st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=True, allow_infinity=True),
                     st.text(max_size=4))
    value = st.recursive(leaf, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=4), c, max_size=3),
                         max_leaves=8)
    valid = Lighting.single((0.2, 0.8, 0.5), 0.7, 0.2).to_dict()

    @_fuzz_settings()
    @given(key=st.sampled_from(["directions", "colors", "ambient", None]), new=value)
    def check(key, new):
        data = dict(valid)
        if key is None:
            data = new
        else:
            data[key] = new
        try:
            Lighting.from_dict(data, "gt/lighting.json")
        except BodyStudioError as exc:
            assert "\n" not in str(exc) and "gt/lighting.json" in str(exc)

    check()


def test_fuzzed_garment_obj_loads_or_raises_one_line(body, tmp_path_factory):
    from hypothesis import given
    from hypothesis import strategies as st

    from bodystudio.garment.garments import dress, load_garment_mesh

    skirt = dress(body, "skirt", texture_size=16)
    lines = [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in skirt.vertices[:120]]
    faces = skirt.faces[(skirt.faces < 120).all(1)][:150]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    tokens = ["nan", "-1", "0", "1e400", "f", "v", "vt 0.5", "1/2/3", "", "#", "999999", "x"]
    folder = tmp_path_factory.mktemp("fuzz_obj")

    @_fuzz_settings()
    @given(edits=st.lists(st.tuples(st.integers(0, len(lines) - 1), st.sampled_from(["replace", "delete", "dup"]),
                                    st.sampled_from(tokens), st.integers(0, 3)), min_size=1, max_size=3))
    def check(edits):
        text = list(lines)
        for index, op, token, position in edits:
            index %= len(text)
            if op == "delete":
                del text[index]
            elif op == "dup":
                text.insert(index, text[index])
            else:
                parts = text[index].split()
                parts[min(position, len(parts) - 1)] = token
                text[index] = " ".join(parts)
            if not text:
                text = ["#"]
        path = folder / "garment.obj"
        path.write_text("\n".join(text) + "\n")
        try:
            g = load_garment_mesh(path, body, texture_size=16, smooth_iterations=2)
            assert np.all(np.isfinite(g.vertices)) and np.allclose(g.weights.sum(1), 1.0)
        except BodyStudioError as exc:
            assert "\n" not in str(exc)

    check()
