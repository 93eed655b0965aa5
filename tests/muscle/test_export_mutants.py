"""Fast tests of the arm-sequence export (bodystudio.muscle.export; issue 17): every array the .glb holds equals
what is read back from it (positions, per-target normal displacements, colours, indices, the one-hot weights
track, accessor bounds), the refusals name their limit, and the staged output folder commits whole or not at all.

The sequence is a 2 x 2 grid of two triangles, small enough to write out each expected value by hand.
"""

import os

import numpy as np
import pytest

from bodystudio.errors import FileFormatError, InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle import export as ex

V0 = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.1, 0.1, 0.0]])
F = np.array([[0, 1, 2], [1, 3, 2]])


def _frames():
    """Frame 0 flat in z = 0; frame 1 with vertex 3 lifted 2 cm; frame 2 the whole sheet moved by (1, 2, 3) mm."""
    f1 = V0.copy()
    f1[3, 2] = 0.02
    return np.stack([V0, f1, V0 + [0.001, 0.002, 0.003]])


def _gltf(path):
    import pygltflib

    return pygltflib.GLTF2().load_binary(str(path))


def test_the_glb_holds_the_frames_normals_colours_and_one_hot_track(tmp_path):
    import pygltflib as g

    frames = _frames()
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30]], np.uint8)
    path = tmp_path / "arm.glb"
    ex.write_morph_glb(path, frames, F, fps=10.0, colors=colors, name="left_arm")
    gltf = _gltf(path)
    prim = gltf.meshes[0].primitives[0]

    def arr(i):
        return ex._accessor_array(gltf, i)

    np.testing.assert_array_equal(arr(prim.attributes.POSITION), V0.astype(np.float32))
    n0 = vertex_normals(V0, F)
    np.testing.assert_allclose(arr(prim.attributes.NORMAL), n0, atol=1e-7)
    np.testing.assert_allclose(np.abs(arr(prim.attributes.NORMAL)[:, 2]), 1.0, atol=1e-7)
    np.testing.assert_array_equal(arr(prim.attributes.COLOR_0), np.c_[colors, np.full(4, 255)])
    acc = gltf.accessors[prim.attributes.COLOR_0]
    assert acc.normalized is True and acc.componentType == g.UNSIGNED_BYTE and acc.type == g.VEC4
    assert not gltf.accessors[prim.attributes.POSITION].normalized
    np.testing.assert_array_equal(arr(prim.indices).reshape(-1, 3), F)
    assert gltf.accessors[prim.indices].componentType == g.UNSIGNED_INT
    assert len(prim.targets) == 3
    for k, t in enumerate(prim.targets):
        np.testing.assert_allclose(arr(t["POSITION"]), frames[k] - V0, atol=1e-8)
        np.testing.assert_allclose(arr(t["NORMAL"]), vertex_normals(frames[k], F) - n0, atol=1e-7)
        a = gltf.accessors[t["POSITION"]]
        np.testing.assert_allclose(a.min, (frames[k] - V0).min(0), atol=1e-8)
        np.testing.assert_allclose(a.max, (frames[k] - V0).max(0), atol=1e-8)
    assert np.abs(arr(prim.targets[1]["NORMAL"])).max() > 0.05  # the lifted corner tilts the normals
    a = gltf.accessors[prim.attributes.POSITION]
    assert a.min == [0.0, 0.0, 0.0] and a.max == pytest.approx([0.1, 0.1, 0.0])
    sampler = gltf.animations[0].samplers[0]
    np.testing.assert_allclose(arr(sampler.input), [0.0, 0.1, 0.2], atol=1e-7)
    assert gltf.accessors[sampler.input].min == [0.0] and gltf.accessors[sampler.input].max == pytest.approx([0.2])
    np.testing.assert_array_equal(arr(sampler.output).reshape(3, 3), np.eye(3))
    assert sampler.interpolation == "LINEAR" and gltf.animations[0].name == "left_arm_sequence"
    assert gltf.nodes[0].name == "left_arm" and gltf.meshes[0].name == "left_arm" and gltf.nodes[0].mesh == 0
    assert gltf.meshes[0].weights == [1.0, 0.0, 0.0]
    assert gltf.meshes[0].extras == {"targetNames": ["frame_00000", "frame_00001", "frame_00002"]}
    assert gltf.scene == 0 and gltf.scenes[0].nodes == [0] and prim.material == 0
    assert gltf.materials[0].doubleSided is True and gltf.asset.version == "2.0"
    assert gltf.asset.generator == "bodystudio muscle" and gltf.materials[0].name == "skin"
    pbr = gltf.materials[0].pbrMetallicRoughness
    assert pbr.baseColorFactor == pytest.approx([0.85, 0.68, 0.58, 1.0]) and pbr.metallicFactor == 0.0
    assert pbr.roughnessFactor == pytest.approx(0.8)
    channel = gltf.animations[0].channels[0]
    assert channel.sampler == 0 and channel.target.node == 0 and channel.target.path == "weights"
    # every vertex attribute (base and targets) sits in an ARRAY_BUFFER view
    attribute_accessors = [prim.attributes.POSITION, prim.attributes.NORMAL, prim.attributes.COLOR_0]
    attribute_accessors += [i for t in prim.targets for i in t.values()]
    assert {gltf.bufferViews[gltf.accessors[i].bufferView].target for i in attribute_accessors} == {g.ARRAY_BUFFER}
    # every buffer view starts on a 4-byte boundary (glTF's alignment rule for float accessors)
    assert all(v.byteOffset % 4 == 0 for v in gltf.bufferViews)
    assert [v.target for v in gltf.bufferViews[-3:]] == [g.ELEMENT_ARRAY_BUFFER, None, None]
    assert gltf.bufferViews[0].target == g.ARRAY_BUFFER
    assert gltf.buffers[0].byteLength == len(gltf.binary_blob())
    # read back: base, faces, targets, times, weights, names; a player at key k shows frame k
    seq = ex.read_morph_glb(path)
    np.testing.assert_allclose(seq.times, [0.0, 0.1, 0.2], atol=1e-7)
    np.testing.assert_array_equal(seq.weights, np.eye(3))
    np.testing.assert_array_equal(seq.faces, F)
    assert seq.base.dtype == np.float64 and seq.targets.dtype == np.float64 and seq.faces.dtype == np.int64
    assert seq.target_names == ("frame_00000", "frame_00001", "frame_00002")
    for k in range(3):
        np.testing.assert_allclose(seq.frame_vertices(k), frames[k], atol=1e-7)


def test_without_normals_the_glb_has_positions_only(tmp_path):
    path = tmp_path / "arm.glb"
    ex.write_morph_glb(path, _frames(), F, normals=False)
    gltf = _gltf(path)
    prim = gltf.meshes[0].primitives[0]
    assert prim.attributes.NORMAL is None and prim.attributes.COLOR_0 is None
    assert all(set(t) == {"POSITION"} for t in prim.targets)
    np.testing.assert_allclose(ex.read_morph_glb(path).frame_vertices(2), _frames()[2], atol=1e-7)
    assert gltf.meshes[0].name == "arm"
    # the default frame rate is 30 fps
    np.testing.assert_allclose(ex.read_morph_glb(path).times, np.arange(3) / 30.0, atol=1e-7)


def test_an_accessor_offset_inside_its_view_is_honoured(tmp_path):
    """_accessor_array adds the accessor's own byteOffset to the view's (other writers use it)."""
    path = tmp_path / "arm.glb"
    ex.write_morph_glb(path, _frames(), F, normals=False)
    gltf = _gltf(path)
    prim = gltf.meshes[0].primitives[0]
    acc = gltf.accessors[prim.attributes.POSITION]
    acc.byteOffset, acc.count = 12, 3  # skip vertex 0
    np.testing.assert_array_equal(ex._accessor_array(gltf, prim.attributes.POSITION), V0[1:].astype(np.float32))
    acc.byteOffset = None
    assert ex._accessor_array(gltf, prim.attributes.POSITION).shape == (3, 3)
    times = ex._accessor_array(gltf, gltf.animations[0].samplers[0].input)
    assert times.shape == (3,)
    # VEC2 and MAT4 accessors (not written here, read from other writers' files) come back as (count, width)
    acc.byteOffset, acc.count, acc.type = 0, 6, "VEC2"
    np.testing.assert_array_equal(ex._accessor_array(gltf, prim.attributes.POSITION),
                                  V0.astype(np.float32).reshape(6, 2))
    acc.count, acc.type = 1, "MAT4"
    blob = np.frombuffer(gltf.binary_blob(), np.float32, count=16)
    np.testing.assert_array_equal(ex._accessor_array(gltf, prim.attributes.POSITION), blob.reshape(1, 16))


def test_a_glb_without_target_names_reads_with_none(tmp_path):
    import pygltflib

    path = tmp_path / "arm.glb"
    ex.write_morph_glb(path, _frames(), F, normals=False)
    gltf = pygltflib.GLTF2().load_binary(str(path))
    gltf.meshes[0].extras = {}
    gltf.save_binary(str(tmp_path / "plain.glb"))
    seq = ex.read_morph_glb(tmp_path / "plain.glb")
    assert seq.target_names == () and len(seq.targets) == 3


def test_the_one_hot_track_is_keyed_at_k_over_fps():
    t, w = ex.one_hot_weights_track(4, 8.0)
    assert t.dtype == np.float32 and w.dtype == np.float32
    np.testing.assert_array_equal(t, [0.0, 0.125, 0.25, 0.375])
    np.testing.assert_array_equal(w, np.eye(4))
    np.testing.assert_allclose(ex.one_hot_weights_track(3)[0], np.arange(3) / 30.0, atol=1e-8)


@pytest.mark.parametrize("frames, faces, fps, match", [
    (np.zeros((0, 4, 3)), F, 30.0, "got shape"),
    (np.zeros((2, 4, 2)), F, 30.0, "got shape"),
    (np.zeros((4, 3)), F, 30.0, "got shape"),
    (np.zeros((2, 4, 3)), F[:, :2], 30.0, r"faces must be \(m, 3\)"),
    (np.zeros((2, 4, 3)), F[0], 30.0, r"faces must be \(m, 3\)"),
    (np.zeros((2, 4, 3)), np.zeros((0, 3), int), 30.0, r"faces must be \(m, 3\)"),
    (np.zeros((2, 4, 3)), F - 1, 30.0, "index vertices"),
    (np.zeros((2, 4, 3)), F + 1, 30.0, "sequence has 4 vertices"),
    (np.zeros((2, 4, 3)), F, -1.0, "fps -1.0"),
    (np.zeros((2, 4, 3)), F, 0.0, r"fps 0.0: must be in \(0, 1000\]$"),
    (np.zeros((2, 4, 3)), F, 1000.5, r"\(0, 1000\]"),
    (np.zeros((2, 4, 3)), F, float("nan"), "fps"),
    (np.full((2, 4, 3), np.inf), F, 30.0,
     "^the arm sequence has non-finite vertex positions; refusing to export it$"),
])
def test_the_sequence_checks_name_the_limit(tmp_path, frames, faces, fps, match):
    with pytest.raises(InputError, match=match):
        ex.write_morph_glb(tmp_path / "x.glb", frames, faces, fps=fps)
    with pytest.raises(InputError):
        ex.write_ply_sequence(tmp_path / "ply", frames, faces) if np.isfinite(fps) and 0 < fps <= 1000 else \
            ex._validate_sequence(frames, faces, fps)
    assert not list(tmp_path.iterdir())


def test_the_limits_themselves_are_accepted(tmp_path):
    ex._validate_sequence(_frames(), F, 0.5)  # below one frame per second is still a frame rate
    frames, faces = ex._validate_sequence(_frames()[:1], F.astype(np.int32), 1000.0)
    assert faces.dtype == np.int64 and frames.dtype == np.float64 and frames.shape == (1, 4, 3)
    ex._validate_sequence(np.zeros((ex.MAX_FRAMES, 4, 3)), F, 30.0)
    with pytest.raises(InputError, match=f"at most {ex.MAX_FRAMES}"):
        ex._validate_sequence(np.zeros((ex.MAX_FRAMES + 1, 4, 3)), F, 30.0)
    assert ex.MAX_FRAMES == 2000 and ex.DEFAULT_FPS == 30.0


def test_colours_of_another_vertex_count_are_refused(tmp_path):
    with pytest.raises(InputError, match=r"colors must be \(4, 3\) uint8; got shape \(3, 3\)"):
        ex.write_morph_glb(tmp_path / "x.glb", _frames(), F, colors=np.zeros((3, 3), np.uint8))
    assert not list(tmp_path.iterdir())


def test_reading_a_missing_or_foreign_glb_is_one_line(tmp_path):
    with pytest.raises(FileFormatError, match="not found"):
        ex.read_morph_glb(tmp_path / "none.glb")
    import trimesh

    other = tmp_path / "box.glb"
    trimesh.creation.box().export(other)  # a valid .glb without morph targets or animation
    with pytest.raises(FileFormatError, match=r"box.glb: not a morph-target arm sequence .glb \(") as info:
        ex.read_morph_glb(other)
    msg = str(info.value)
    assert "\n" not in msg and msg.endswith("); re-export it with bodystudio muscle capture")
    assert "(ValueError: need at least one array to stack)" in msg  # no morph targets to stack


def test_the_ply_sequence_files_hold_each_frame(tmp_path):
    from bodystudio.geometry.mesh import load_mesh

    frames = _frames()
    paths = ex.write_ply_sequence(tmp_path, frames, F)
    assert [p.name for p in paths] == ["00000.ply", "00001.ply", "00002.ply"]
    for p, V in zip(paths, frames, strict=True):
        m = load_mesh(p)
        np.testing.assert_allclose(m.vertices, V, atol=1e-7)
        np.testing.assert_array_equal(m.faces, F)


def test_a_new_output_path_must_not_exist(tmp_path):
    (tmp_path / "taken").write_text("x")
    with pytest.raises(InputError, match="taken: capture already exists; choose a new path"):
        ex.check_new_output(tmp_path / "taken", "capture")
    os.symlink(tmp_path / "nowhere", tmp_path / "dangling")
    with pytest.raises(InputError, match="output already exists"):
        ex.check_new_output(tmp_path / "dangling")
    assert ex.check_new_output(tmp_path / "fresh.glb") == tmp_path / "fresh.glb"
    # the checks of check_output_file name the same thing
    with pytest.raises(InputError, match="^capture "):
        ex.check_new_output(tmp_path / "taken" / "inside", "capture")


def test_the_staging_folder_sits_hidden_beside_the_output_and_replaces_a_stale_one(tmp_path):
    out = tmp_path / "deep" / "capture"
    stale = out.parent / f".capture.staging-{os.getpid()}"
    with ex.staged_output_folder(out) as staging:
        assert staging == stale and staging.is_dir() and list(staging.iterdir()) == []
        (staging / "f").write_text("1")
    assert (out / "f").read_text() == "1" and not stale.exists()
    out2 = tmp_path / "capture2"
    stale2 = tmp_path / f".capture2.staging-{os.getpid()}"
    stale2.mkdir()
    (stale2 / "old").write_text("left by a killed run")
    with ex.staged_output_folder(out2) as staging:
        assert list(staging.iterdir()) == []
    assert list(out2.iterdir()) == []


def test_a_failed_commit_is_one_line_and_leaves_nothing(tmp_path, monkeypatch):
    import errno

    out = tmp_path / "capture"

    def refuse(src, dst):
        raise OSError(errno.EEXIST, "File exists")

    monkeypatch.setattr(os, "rename", refuse)
    with pytest.raises(InputError, match=r"capture: could not commit the output \(File exists\)"):
        with ex.staged_output_folder(out, "capture folder") as staging:
            (staging / "f").write_text("1")
    assert list(tmp_path.iterdir()) == []
