"""Body model acceptance: statures, rest-pose skinning, rigid forearm, weights, joints inside, symmetry."""

import igl
import numpy as np
import pytest

from bodystudio.body import Phenotype, Pose, build_body, load_pose, pose_from_dict
from bodystudio.body.makehuman import load_base
from bodystudio.errors import FileFormatError, InputError


@pytest.fixture(scope="module")
def female():
    return build_body(Phenotype(gender=0.0))


@pytest.fixture(scope="module")
def male():
    return build_body(Phenotype(gender=1.0))


def stature(body):
    return body.vertices[:, 1].max() - body.vertices[:, 1].min()


def test_default_statures_are_plausible_and_male_taller(female, male):
    assert 1.50 < stature(female) < 1.72
    assert 1.62 < stature(male) < 1.85
    assert stature(male) > stature(female) + 0.05
    for body in (female, male):
        assert body.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-12)  # feet on the floor


def test_macro_height_and_local_targets_change_the_shape(default_body):
    tall = build_body(Phenotype(height=1.0))
    assert stature(tall) > stature(default_body) + 0.05
    fat_arms = build_body(local={"upperarm-fat-decr-incr": 1.0})
    moved = np.linalg.norm(fat_arms.vertices - default_body.vertices, axis=1)
    upperarm = default_body.weights[:, default_body.skeleton.index("upperarm_l")] > 0.5
    assert moved[upperarm].mean() > 5e-3 and np.median(moved[~upperarm]) < 1e-3


def test_rest_pose_skinning_reproduces_rest_mesh(default_body):
    for method in ("lbs", "dqs"):
        V, heads = default_body.pose(default_body.rest_pose(), method=method)
        np.testing.assert_allclose(V, default_body.vertices, atol=1e-12)
        np.testing.assert_allclose(heads, default_body.skeleton.heads, atol=1e-12)


@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_elbow_rotation_moves_forearm_rigidly(default_body, method):
    sk = default_body.skeleton
    j = sk.index("lowerarm_l")
    rotations = np.zeros((sk.n_bones, 3))
    rotations[j] = [np.pi / 2, 0.0, 0.0]
    V, heads = default_body.pose(Pose(rotations, np.zeros(3)), method=method)
    elbow = sk.heads[j]
    forearm = np.where(default_body.weights[:, j] > 0.999)[0]
    far = forearm[np.linalg.norm(default_body.vertices[forearm] - elbow, axis=1) > 0.08]
    assert len(far) > 30
    rest = default_body.vertices[far]
    D0 = np.linalg.norm(rest[:, None] - rest[None], axis=2)
    D1 = np.linalg.norm(V[far][:, None] - V[far][None], axis=2)
    assert np.abs(D1 - D0).max() < 1e-4
    # the forearm really moved (by a quarter turn about the elbow) and the elbow stayed put
    assert np.linalg.norm(V[far] - rest, axis=1).max() > 0.15
    np.testing.assert_allclose(heads[j], elbow, atol=1e-12)
    angle = np.arccos(np.clip(np.dot(V[far[0]] - elbow, rest[0] - elbow)
                              / np.linalg.norm(V[far[0]] - elbow) / np.linalg.norm(rest[0] - elbow), -1, 1))
    assert angle == pytest.approx(np.pi / 2, abs=0.3)


def test_skin_weights_are_normalised(default_body, body_2k):
    for body in (default_body, body_2k):
        assert body.weights.min() >= 0.0
        np.testing.assert_allclose(body.weights.sum(1), 1.0, atol=1e-12)


def test_joints_lie_inside_the_mesh(default_body):
    sk = default_body.skeleton
    anatomical = [i for i, name in enumerate(sk.bone_names) if name != "Root"]  # Root sits on the floor
    winding = igl.winding_number(default_body.vertices, default_body.faces, sk.heads[anatomical])
    outside = [sk.bone_names[anatomical[i]] for i in np.where(winding < 0.5)[0]]
    assert not outside, f"joints outside the body: {outside}"


def test_joints_follow_the_shape(default_body):
    tall = build_body(Phenotype(height=1.0))
    j = default_body.skeleton.index("head")
    assert tall.skeleton.heads[j, 1] > default_body.skeleton.heads[j, 1] + 0.05


def mirror_error(body):
    base = load_base()
    mirror = base.mirror[: base.n_body]
    return np.abs(body.vertices[mirror] * [-1, 1, 1] - body.vertices).max()


def test_default_body_is_symmetric(default_body):
    assert mirror_error(default_body) < 1e-3
    lopsided = build_body(local={"l-upperarm-fat-decr-incr": 1.0})
    assert mirror_error(lopsided) > 5e-3  # the check sees a one-sided change


@pytest.mark.parametrize("resolution, lo, hi", [("6k", 5000, 7000), ("2k", 2000, 3000)])
def test_decimated_templates_carry_shape_and_weights(default_body, resolution, lo, hi):
    low = build_body(resolution=resolution)
    assert lo <= low.n_vertices <= hi
    np.testing.assert_array_equal(low.vertices, default_body.vertices[low.vertex_ids])
    assert igl.boundary_facets(low.faces)[0].shape[0] == 0  # still a closed surface
    np.testing.assert_allclose(low.skeleton.heads, default_body.skeleton.heads)
    rotations = np.zeros((low.skeleton.n_bones, 3))
    rotations[low.skeleton.index("thigh_r")] = [0.6, 0.0, 0.2]
    pose = Pose(rotations, np.array([0.1, 0.0, 0.0]))
    V_low, _ = low.pose(pose)
    V_full, _ = default_body.pose(pose)
    # low-res weights are the renormalised full-res rows: posed vertices agree up to that renormalisation
    assert np.abs(V_low - V_full[low.vertex_ids]).max() < 1e-9


def test_invalid_parameters_raise_one_line_errors():
    with pytest.raises(InputError, match="out of range"):
        Phenotype(gender=1.5)
    with pytest.raises(InputError, match="valid: gender"):
        Phenotype.from_dict({"sex": 1.0})
    with pytest.raises(InputError, match="unknown local modifier"):
        build_body(local={"nosuchtarget": 0.5})
    with pytest.raises(InputError, match=r"\[-1, 1\]"):
        build_body(local={"upperarm-fat-decr-incr": 2.0})
    with pytest.raises(InputError, match="valid: full, 6k, 2k"):
        build_body(resolution="100k")
    with pytest.raises(InputError, match="valid rigs"):
        build_body(rig="mixamo_xl")


def test_pose_files(tmp_path, default_body):
    names = default_body.skeleton.bone_names
    tpose = load_base().data_dir / "poses" / "game_engine_fk" / "t-pose.json"
    pose = load_pose(tpose, names)
    assert np.abs(pose.rotations).max() > 0.1  # MPFB Euler angles read and converted
    arms_up, _ = default_body.pose(pose)
    hand = names.index("hand_l")
    shoulder_y = default_body.skeleton.heads[names.index("upperarm_l"), 1]
    assert abs(arms_up[default_body.weights[:, hand] > 0.9, 1].mean() - shoulder_y) < 0.15
    bad = tmp_path / "bad.json"
    bad.write_text('{"rotations": {"lowerarm_l": [1, 2]}}')
    with pytest.raises(FileFormatError, match="3 finite numbers"):
        load_pose(bad, names)
    with pytest.raises(InputError, match="unknown bone"):
        pose_from_dict({"rotations": {"elbow": [0, 0, 1]}}, names)
    bad.write_text("{not json")
    with pytest.raises(FileFormatError, match="not valid JSON"):
        load_pose(bad, names)
