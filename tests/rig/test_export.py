"""Avatar posing and export: glTF skin re-imported and posed the glTF way equals our skinning; validator; BVH."""

import json
import shutil
import subprocess

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.body.skinning import linear_blend_skinning, skinning_transforms
from bodystudio.fileio import write_json
from bodystudio.register.synthetic import random_pose
from bodystudio.rig.avatar import Avatar
from bodystudio.rig.evaluate import load_avatar, rig_json_path
from bodystudio.rig.export import rig_description, write_bvh, write_glb
from bodystudio.rig.weights import limit_influences

VALIDATOR_JS = """
const validator = require('gltf-validator');
const fs = require('fs');
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])), {maxIssues: 20}).then((r) => {
  console.log(JSON.stringify({errors: r.issues.numErrors, messages: r.issues.messages.map(m => m.code)}));
});
"""


@pytest.fixture(scope="module")
def rest_avatar(body_2k):
    sk = body_2k.skeleton
    colors = (np.abs(np.sin(body_2k.vertices * 20.0)) * 255).astype(np.uint8)
    return Avatar(body_2k.vertices, body_2k.faces, colors, sk.bone_names, sk.parents, None, sk.rest_rotations,
                  sk.rest_rotations, sk.lengths, limit_influences(body_2k.weights), np.zeros(3),
                  loaded_heads=sk.heads.copy())


def test_avatar_in_rest_bind_poses_like_the_body_model(rest_avatar, body_2k):
    pose = random_pose(body_2k.skeleton.bone_names, 5)
    ours, _ = rest_avatar.posed(pose)
    ref = linear_blend_skinning(body_2k.vertices, rest_avatar.weights, skinning_transforms(body_2k.skeleton, pose))
    np.testing.assert_allclose(ours, ref, atol=1e-9)


def _gltf_skinning(glb, pose_local_rotations):
    """Pose a glb the glTF way (node TRS hierarchy x inverse bind matrices), independently of our code."""
    import pygltflib

    g = pygltflib.GLTF2().load(str(glb))
    blob = g.binary_blob()

    def read(i, dtype, width):
        a = g.accessors[i]
        v = g.bufferViews[a.bufferView]
        return np.frombuffer(blob, dtype=dtype, count=a.count * width, offset=v.byteOffset or 0).reshape(a.count, width)

    prim = g.meshes[0].primitives[0]
    V = read(prim.attributes.POSITION, np.float32, 3).astype(float)
    J = read(prim.attributes.JOINTS_0, np.uint16, 4)
    W = read(prim.attributes.WEIGHTS_0, np.float32, 4).astype(float)
    skin = g.skins[0]
    ibm = read(skin.inverseBindMatrices, np.float32, 16).reshape(-1, 4, 4).transpose(0, 2, 1)
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    world = {}

    def node_world(i):
        if i not in world:
            n = g.nodes[i]
            L = np.eye(4)
            L[:3, :3] = pose_local_rotations[i] if i < len(pose_local_rotations) else \
                Rotation.from_quat(n.rotation or [0, 0, 0, 1]).as_matrix()
            L[:3, 3] = n.translation or [0, 0, 0]
            world[i] = node_world(parent[i]) @ L if i in parent else L
        return world[i]

    joint_mats = np.stack([node_world(j) @ ibm[k] for k, j in enumerate(skin.joints)])
    Vh = np.c_[V, np.ones(len(V))]
    out = np.zeros((len(V), 4))
    for k in range(4):
        out += W[:, k, None] * np.einsum("nij,nj->ni", joint_mats[J[:, k]], Vh)
    return out[:, :3], g


def test_glb_skin_poses_like_our_skinning(rest_avatar, tmp_path, body_2k):
    glb = tmp_path / "avatar.glb"
    write_glb(glb, rest_avatar)
    pose = random_pose(body_2k.skeleton.bone_names, 9)
    theirs, g = _gltf_skinning(glb, rest_avatar.local_node_rotations(pose))
    ours, _ = rest_avatar.posed(pose)
    assert np.abs(theirs - ours).max() < 1e-4  # float32 storage
    assert len(g.skins[0].joints) == rest_avatar.n_bones
    # Read back through our loader (with the rig description beside it) and pose again.
    write_json(rig_json_path(glb), rig_description(rest_avatar))
    back = load_avatar(glb)
    np.testing.assert_allclose(back.posed(pose)[0], ours, atol=1e-4)
    import trimesh

    scene = trimesh.load(glb)
    assert sum(len(m.vertices) for m in scene.geometry.values()) == len(rest_avatar.vertices)


def _validator(tmp_path_factory):
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm not installed: cannot run the Khronos glTF validator")
    d = tmp_path_factory.mktemp("gltf_validator")
    try:
        subprocess.run(["npm", "install", "--prefix", str(d), "gltf-validator"], check=True, capture_output=True,
                       timeout=180)
    except (subprocess.SubprocessError, OSError) as exc:
        pytest.skip(f"cannot install the npm package gltf-validator ({type(exc).__name__})")
    script = d / "validate.js"
    script.write_text(VALIDATOR_JS)
    return d, script


@pytest.mark.parametrize("texture", [False, True])
def test_glb_passes_khronos_validator(rest_avatar, tmp_path, tmp_path_factory, texture):
    d, script = _validator(tmp_path_factory)
    glb = tmp_path / "avatar.glb"
    write_glb(glb, rest_avatar, texture=texture)
    out = subprocess.run(["node", str(script), str(glb)], capture_output=True, text=True, cwd=d, timeout=120,
                         env={"NODE_PATH": str(d / "node_modules"), "PATH": shutil.os.environ["PATH"]})
    report = json.loads(out.stdout)
    assert report["errors"] == 0, report


def test_texture_bake_reproduces_vertex_colours(rest_avatar, tmp_path):
    import io

    import pygltflib
    from PIL import Image

    glb = tmp_path / "textured.glb"
    write_glb(glb, rest_avatar, texture=True)
    g = pygltflib.GLTF2().load(str(glb))
    blob = g.binary_blob()
    view = g.bufferViews[g.images[0].bufferView]
    img = np.asarray(Image.open(io.BytesIO(blob[view.byteOffset: view.byteOffset + view.byteLength])))
    prim = g.meshes[0].primitives[0]
    a = g.accessors[prim.attributes.TEXCOORD_0]
    uv = np.frombuffer(blob, np.float32, a.count * 2, g.bufferViews[a.bufferView].byteOffset).reshape(-1, 2)
    a = g.accessors[prim.attributes.POSITION]
    V = np.frombuffer(blob, np.float32, a.count * 3, g.bufferViews[a.bufferView].byteOffset).reshape(-1, 3)
    size = img.shape[0]
    px = np.clip((uv * size).astype(int), 0, size - 1)
    sampled = img[px[:, 1], px[:, 0], :3].astype(float)
    from scipy.spatial import cKDTree

    _, idx = cKDTree(rest_avatar.vertices).query(V)
    expected = rest_avatar.vertex_colors[idx].astype(float)
    assert np.median(np.abs(sampled - expected)) < 12


def test_bvh_has_one_value_per_channel(rest_avatar, tmp_path, body_2k):
    poses = [Pose.rest(rest_avatar.n_bones), random_pose(body_2k.skeleton.bone_names, 3)]
    path = tmp_path / "motion.bvh"
    write_bvh(path, rest_avatar, poses)
    text = path.read_text().splitlines()
    n_channels = sum(int(line.split()[1]) for line in text if line.strip().startswith("CHANNELS"))
    assert n_channels == 6 + 3 * (rest_avatar.n_bones - 1)
    frames = text[text.index("MOTION") + 3:]
    assert len(frames) == 2 and all(len(f.split()) == n_channels for f in frames)
    # Rest frame: no rotation anywhere.
    assert np.allclose([float(x) for x in frames[0].split()[3:]], 0.0, atol=1e-6)
