"""Skinned glTF avatars: weights, skeleton and mesh survive a write/read round trip."""

import numpy as np
import pytest

from bodystudio.errors import FileFormatError
from bodystudio.geometry.mesh import save_mesh
from bodystudio.viewer.avatar import glb_has_skin, load_avatar
from bodystudio.viewer.views import open_viewable


def test_skinned_glb_round_trip(body_2k, tmp_path, skinned_glb):
    sk = body_2k.skeleton
    path = tmp_path / "avatar.glb"
    skinned_glb(path, body_2k.vertices, body_2k.faces, body_2k.weights, sk.heads, sk.parents, sk.bone_names)
    assert glb_has_skin(path)
    avatar = load_avatar(path)
    assert avatar.bone_names == tuple(sk.bone_names)
    np.testing.assert_allclose(avatar.mesh.vertices, body_2k.vertices, atol=1e-6)
    np.testing.assert_array_equal(avatar.mesh.faces, body_2k.faces)
    np.testing.assert_allclose(avatar.heads, sk.heads, atol=1e-5)
    np.testing.assert_array_equal(avatar.parents, sk.parents)
    np.testing.assert_allclose(avatar.weights.sum(1), 1.0, atol=1e-5)
    # The four strongest weights are kept: the dominant bone matches almost everywhere.
    assert np.mean(avatar.dominant_bone == body_2k.weights.argmax(1)) > 0.99
    item = open_viewable(path)
    assert item.kind == "avatar"


def test_plain_glb_is_a_mesh_and_broken_glb_is_one_line_error(body_mesh, tmp_path):
    plain = tmp_path / "scan.glb"
    save_mesh(plain, body_mesh)
    assert not glb_has_skin(plain)
    assert open_viewable(plain).kind == "mesh"
    with pytest.raises(FileFormatError, match="no skinned mesh"):
        load_avatar(plain)
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF not really")
    with pytest.raises(FileFormatError) as exc:
        open_viewable(broken)
    assert str(broken) in str(exc.value) and "\n" not in str(exc.value)


def test_gltf_with_embedded_buffer_reads_like_the_glb(body_2k, tmp_path, skinned_glb):
    import pygltflib

    sk = body_2k.skeleton
    glb = tmp_path / "avatar.glb"
    skinned_glb(glb, body_2k.vertices, body_2k.faces, body_2k.weights, sk.heads, sk.parents, sk.bone_names)
    gltf = pygltflib.GLTF2().load(str(glb))
    gltf.convert_buffers(pygltflib.BufferFormat.DATAURI)
    text = tmp_path / "avatar.gltf"
    gltf.save(str(text))
    a, b = load_avatar(glb), load_avatar(text)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.weights, b.weights)
    assert open_viewable(text).kind == "avatar"
