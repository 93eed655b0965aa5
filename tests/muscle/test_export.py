"""The arm sequence's .glb (morph-target animation) and PLY sequence read back as written."""

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.muscle.export import read_morph_glb, write_morph_glb, write_ply_sequence


@pytest.fixture(scope="module")
def sequence():
    """A 'bulging' sphere: 12 frames, the +y cap pushed out by up to 2 cm, like a biceps."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    V0, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    bulge = np.clip(V0[:, 1] / 0.05, 0, None)[:, None] * V0 / 0.05
    frames = np.stack([V0 + [0.3, 1.2, 0.1] + 0.02 * np.sin(np.pi * k / 11) * bulge for k in range(12)])
    return frames, F


def test_glb_morph_targets_play_the_sequence(tmp_path, sequence):
    import pygltflib

    frames, F = sequence
    path = tmp_path / "arm.glb"
    write_morph_glb(path, frames, F, fps=30.0)
    seq = read_morph_glb(path)
    assert len(seq.targets) == len(frames) and seq.target_names[3] == "frame_00003"
    np.testing.assert_array_equal(seq.faces, F)
    np.testing.assert_allclose(seq.times, np.arange(12) / 30.0, atol=1e-6)
    for k in range(len(frames)):  # what a player shows at key k is frame k (float32 precision)
        assert np.abs(seq.frame_vertices(k) - frames[k]).max() < 1e-6
    # halfway between keys, LINEAR interpolation of one-hot weights averages two frames
    w = 0.5 * (seq.weights[4] + seq.weights[5])
    mid = seq.base + np.tensordot(w, seq.targets, axes=1)
    assert np.abs(mid - 0.5 * (frames[4] + frames[5])).max() < 1e-6
    gltf = pygltflib.GLTF2().load_binary(str(path))
    sampler = gltf.animations[0].samplers[0]
    assert sampler.interpolation == "LINEAR"
    assert gltf.animations[0].channels[0].target.path == "weights"
    prim = gltf.meshes[0].primitives[0]
    for t in prim.targets:  # glTF requires bounds on morph-target positions (three.js uses them)
        acc = gltf.accessors[t["POSITION"]]
        assert acc.min is not None and acc.max is not None and "NORMAL" in t
    assert gltf.accessors[sampler.input].max[0] == pytest.approx(11 / 30.0)


def test_glb_loads_in_trimesh(tmp_path, sequence):
    import trimesh

    frames, F = sequence
    path = tmp_path / "arm.glb"
    write_morph_glb(path, frames, F, colors=np.full((frames.shape[1], 3), 200, np.uint8))
    scene = trimesh.load(path)
    (mesh,) = scene.geometry.values()
    assert len(mesh.vertices) == frames.shape[1] and len(mesh.faces) == len(F)
    assert np.abs(np.sort(mesh.vertices, axis=0) - np.sort(frames[0], axis=0)).max() < 1e-6


def test_ply_sequence_round_trip(tmp_path, sequence):
    from bodystudio.geometry.mesh import load_mesh

    frames, F = sequence
    paths = write_ply_sequence(tmp_path / "meshes", frames[:3], F)
    assert [p.name for p in paths] == ["00000.ply", "00001.ply", "00002.ply"]
    m = load_mesh(paths[2])
    assert np.abs(m.vertices - frames[2]).max() < 1e-6 and len(m.faces) == len(F)


@pytest.mark.parametrize("bad", ["shape", "nan", "faces", "fps"])
def test_export_refuses_bad_sequences(tmp_path, sequence, bad):
    frames, F = sequence
    kwargs = {"frames": frames, "faces": F, "fps": 30.0}
    if bad == "shape":
        kwargs["frames"] = frames[0]
    elif bad == "nan":
        kwargs["frames"] = frames.copy()
        kwargs["frames"][2, 5, 1] = np.nan
    elif bad == "faces":
        kwargs["faces"] = F + len(frames[0])
    else:
        kwargs["fps"] = 0.0
    with pytest.raises(InputError):
        write_morph_glb(tmp_path / "x.glb", **kwargs)
    assert not list(tmp_path.iterdir())


def test_reading_junk_glb_is_one_line(tmp_path):
    junk = tmp_path / "junk.glb"
    junk.write_bytes(b"glTF" + b"\x00" * 40)
    with pytest.raises(FileFormatError, match="not a morph-target arm sequence"):
        read_morph_glb(junk)


def test_staged_output_folder_appears_whole_or_not_at_all(tmp_path):
    from bodystudio.muscle.export import staged_output_folder

    out = tmp_path / "capture"
    with pytest.raises(RuntimeError), staged_output_folder(out) as staging:
        (staging / "00000.ply").write_text("half")
        raise RuntimeError("killed mid-write")
    assert list(tmp_path.iterdir()) == []  # neither the output nor the staging folder remains
    with staged_output_folder(out) as staging:
        (staging / "a.txt").write_text("x")
        assert not out.exists()
    assert (out / "a.txt").read_text() == "x" and list(tmp_path.iterdir()) == [out]
    with pytest.raises(InputError, match="already exists"), staged_output_folder(out):
        pass


def test_new_output_in_unwritable_folder_is_refused(tmp_path, monkeypatch):
    import errno
    import tempfile

    from bodystudio.muscle.export import check_new_output

    def denied(*args, **kwargs):  # what an unwritable folder does to the probe (root ignores chmod, so fake it)
        raise PermissionError(errno.EACCES, "Permission denied")

    with monkeypatch.context() as m:
        m.setattr(tempfile, "mkstemp", denied)
        with pytest.raises(InputError, match="(?i)permission denied"):
            check_new_output(tmp_path / "sub" / "out.glb")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file, not a folder"):
        check_new_output(tmp_path / "file" / "out")


def test_new_output_on_a_virtual_file_system_is_refused():
    from bodystudio.muscle.export import check_new_output

    with pytest.raises(InputError, match="cannot write in /sys"):
        check_new_output("/sys/arm_capture")
