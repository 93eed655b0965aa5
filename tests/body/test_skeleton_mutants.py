"""The skeleton (:mod:`bodystudio.body.skeleton`) against hand-computed cases and an independent reference.

Mutation tests (issue 17, docs/mutation/body-skeleton.md). The rest frames are checked against frames worked out
by hand (a bone along each world axis, Blender's y-along-the-bone convention and its -y singularity) and, for
any direction, against the shortest-arc rotation taking Blender's y axis onto the bone (what Blender's
``vec_roll_to_mat3`` builds) followed by the roll about the bone; the rig and weight readers against a tiny rig
written here (three bones, a 6-vertex "mesh") whose regressors and weights are summed by hand.
"""

from __future__ import annotations

import json
from functools import cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import skeleton as K
from bodystudio.errors import AssetError, InputError

# world -> Blender: b = (x, -z, y)
WORLD_AXES_TO_FRAME = {
    # bone direction in world: its rest frame's columns (x, y, z axes) in world, roll 0, worked out by hand
    (0, 1, 0): [[1, 0, 0], [0, 1, 0], [0, 0, 1]],     # up (Blender +z): the identity
    (1, 0, 0): [[0, 0, 1], [1, 0, 0], [0, 1, 0]],     # Blender +x
    (0, 0, -1): [[1, 0, 0], [0, 0, -1], [0, 1, 0]],   # Blender +y: Blender's identity
    (0, 0, 1): [[-1, 0, 0], [0, 0, 1], [0, 1, 0]],    # Blender -y: the singular branch, diag(-1, -1, 1)
    (0, -1, 0): [[1, 0, 0], [0, -1, 0], [0, 0, -1]],  # down (Blender -z)
}


def _frame_columns(cols) -> np.ndarray:
    return np.array(cols, np.float64).T


def _blender_reference(direction, roll) -> np.ndarray:
    """Shortest-arc rotation from (0, 1, 0) onto ``direction``, then ``roll`` about it (Blender's bone matrix)."""
    d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    y = np.array([0.0, 1.0, 0.0])
    axis = np.cross(y, d)
    s = np.linalg.norm(axis)
    angle = np.arctan2(s, float(y @ d))
    B = Rotation.from_rotvec(axis / s * angle).as_matrix() if s > 1e-12 else np.eye(3)
    return Rotation.from_rotvec(roll * d).as_matrix() @ B


@pytest.mark.parametrize("direction", sorted(WORLD_AXES_TO_FRAME))
def test_rest_frames_of_bones_along_the_world_axes(direction):
    h = np.array([[0.1, 0.2, 0.3]])
    R = K.bone_rest_rotations(h, h + 0.5 * np.array([direction], np.float64), np.zeros(1))[0]
    np.testing.assert_allclose(R, _frame_columns(WORLD_AXES_TO_FRAME[direction]), atol=1e-12)


def test_roll_turns_the_frame_right_handed_about_the_bone():
    # an upward bone rolled +90 degrees: x axis (1, 0, 0) -> (0, 0, -1), z axis (0, 0, 1) -> (1, 0, 0)
    R = K.bone_rest_rotations(np.zeros((1, 3)), np.array([[0.0, 2.0, 0.0]]), np.array([np.pi / 2]))[0]
    np.testing.assert_allclose(R, _frame_columns([[0, 0, -1], [0, 1, 0], [1, 0, 0]]), atol=1e-12)


def test_blender_bone_matrix_is_the_shortest_arc_then_the_roll():
    rng = np.random.default_rng(3)
    dirs = list(rng.normal(size=(40, 3))) + [np.array([0.02, -1.0, 0.0]),
                                            np.array([0.0, 1.0, 0.0]), np.array([0.3, 0.0, 0.0])]
    rolls = list(rng.uniform(-np.pi, np.pi, len(dirs)))
    for d, r in zip(dirs, rolls, strict=True):
        got = K.blender_vec_roll_to_matrix(np.array(d) * 3.7, r)  # the length does not matter
        np.testing.assert_allclose(got, _blender_reference(d, r), atol=1e-9, err_msg=str(d))


def test_blender_bone_matrix_at_minus_y_is_a_half_turn_about_z_then_the_roll():
    got = K.blender_vec_roll_to_matrix(np.array([0.0, -2.0, 0.0]), 0.0)
    np.testing.assert_allclose(got, np.diag([-1.0, -1.0, 1.0]), atol=1e-15)
    got = K.blender_vec_roll_to_matrix(np.array([0.0, -1.0, 0.0]), np.pi / 2)
    # roll +90 about -y: Blender x (-1, 0, 0) -> (0, 0, 1)... the columns of Rot(-y, 90) @ diag(-1, -1, 1)
    ref = Rotation.from_rotvec([0.0, -np.pi / 2, 0.0]).as_matrix() @ np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(got, ref, atol=1e-15)
    # just off the singularity (1 + y = 2e-6, x^2 + z^2 = 4e-6 < 2.5e-4): still the singular branch
    d = np.array([2e-3, -np.sqrt(1 - 4e-6), 0.0])
    np.testing.assert_allclose(K.blender_vec_roll_to_matrix(d, 0.0), np.diag([-1.0, -1.0, 1.0]), atol=1e-15)
    d = np.array([1e-3, -1.0, 2e-3])  # 1 + y = 2.5e-6, off the axis in x and z
    np.testing.assert_allclose(K.blender_vec_roll_to_matrix(d, 0.0), np.diag([-1.0, -1.0, 1.0]), atol=1e-15)
    # 1 + y = 5e-5 (> 1e-5) while x^2 + z^2 = 1e-4 (< 2.5e-4): the shortest arc, not the singular branch
    for d in (np.array([0.01, -1.0, 0.0]), np.array([0.0, -1.0, 0.01])):
        np.testing.assert_allclose(K.blender_vec_roll_to_matrix(d, 0.3), _blender_reference(d, 0.3), atol=1e-9)
    # offset in z: about a half turn about x, far from the singular branch's half turn about z
    np.testing.assert_allclose(K.blender_vec_roll_to_matrix(d, 0.0), np.diag([1.0, -1.0, -1.0]), atol=0.03)


def test_zero_length_bone_gets_the_upward_frame():
    h = np.array([[0.5, 0.5, 0.5], [0.0, 0.0, 0.0]])
    R = K.bone_rest_rotations(h, h + np.array([[0.0, 0.0, 0.0], [0.0, 1e-10, 0.0]]), np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R[1], _frame_columns([[0, 0, -1], [0, 1, 0], [1, 0, 0]]), atol=1e-12)


def test_bone_rest_rotations_refuses_rolls_of_another_length():
    with pytest.raises(ValueError):
        K.bone_rest_rotations(np.zeros((2, 3)), np.ones((2, 3)), np.zeros(1))


# ---- the Skeleton object -------------------------------------------------------------------------------------

def _skeleton() -> K.Skeleton:
    heads = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    tails = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, -2.0], [1.0, 1.0, 0.0], [1.0, 4.0, 4.0]])
    return K.Skeleton(("root", "spine", "arm", "hand"), np.array([-1, 0, 0, 2]), heads, tails, np.zeros(4))


def test_skeleton_lengths_children_index_and_frames():
    s = _skeleton()
    assert s.n_bones == 4
    np.testing.assert_allclose(s.lengths, [1.0, 2.0, 1.0, 5.0])
    assert s.children == [[1, 2], [], [3], []]
    assert s.index("arm") == 2 and s.index("root") == 0
    with pytest.raises(InputError, match=r"unknown bone 'leg'; valid bones: root, spine, arm, hand"):
        s.index("leg")
    np.testing.assert_allclose(s.rest_rotations[1], _frame_columns(WORLD_AXES_TO_FRAME[(0, 0, -1)]), atol=1e-12)
    A = s.rest_frames
    assert A.shape == (4, 4, 4)
    for b in range(4):
        np.testing.assert_allclose(A[b, :3, :3], s.rest_rotations[b])
        np.testing.assert_allclose(A[b, :3, 3], s.heads[b])
        np.testing.assert_array_equal(A[b, 3], [0.0, 0.0, 0.0, 1.0])
    # bone -> world: the bone's own y axis, scaled by its length, lands on the tail
    for b in range(4):
        np.testing.assert_allclose(A[b] @ [0.0, s.lengths[b], 0.0, 1.0], [*s.tails[b], 1.0], atol=1e-12)


# ---- the rig and weight readers ------------------------------------------------------------------------------

# six vertices; cube "c_hip" = vertices 0 and 1, cube "c_top" = 2, 3, 4
VERTS = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 3.0, 3.0], [3.0, 3.0, 0.0],
                  [9.0, 9.0, 9.0]])
CUBES = {"c_hip": np.array([0, 1]), "c_top": np.array([2, 3, 4])}
RIG = {
    # written children first and out of name order, to check the parents-first order
    "zhand": {"parent": "arm", "head": {"strategy": "VERTEX", "vertex_index": 4},
              "tail": {"strategy": "VERTEX", "vertex_index": 5}},
    "arm": {"parent": "base", "roll": 0.25, "head": {"strategy": "CUBE", "cube_name": "c_top"},
            "tail": {"strategy": "MEAN", "vertex_indices": [4, 5]}},
    "base": {"parent": None, "roll": -0.5, "head": {"strategy": "CUBE", "cube_name": "c_hip"},
             "tail": {"strategy": "CUBE", "cube_name": "c_top"}},
    "aux": {"parent": "", "head": {"strategy": "VERTEX", "vertex_index": 0},
            "tail": {"strategy": "MEAN", "vertex_indices": [0, 1, 2, 3]}},
}


def _write_rig(root, name="default", rig=RIG, weights=None):
    folder = root / "rigs" / "standard"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"rig.{name}.json").write_text(json.dumps(rig))
    if weights is not None:
        (folder / f"weights.{'default' if name == 'default_no_toes' else name}.json").write_text(json.dumps(weights))
    return root


@cache
def _rig_dir():
    import tempfile
    from pathlib import Path

    return _write_rig(Path(tempfile.mkdtemp(prefix="skeleton-mutants-")))


def test_load_rig_orders_bones_parents_first_and_regresses_joints_by_hand():
    rig = K.load_rig("default", _rig_dir(), 6, CUBES)
    assert rig.name == "default"
    # wave 1: roots aux, base (sorted); wave 2: arm; wave 3: zhand
    assert rig.bone_names == ("aux", "base", "arm", "zhand")
    np.testing.assert_array_equal(rig.parents, [-1, -1, 1, 2])
    np.testing.assert_allclose(rig.rolls, [0.0, -0.5, 0.25, 0.0])
    assert rig.head_regressor.shape == (4, 6) and rig.tail_regressor.shape == (4, 6)
    s = K.skeleton_from_vertices(rig, VERTS)
    heads = [[0, 0, 0], [1, 0, 0], [1, 3, 1], [3, 3, 0]]  # vertex 0; mean of 0, 1; of 2, 3, 4; vertex 4
    tails = [[0.5, 1.5, 0.75], [1, 3, 1], [6, 6, 4.5], [9, 9, 9]]
    np.testing.assert_allclose(s.heads, heads, atol=1e-12)
    np.testing.assert_allclose(s.tails, tails, atol=1e-12)
    assert s.bone_names == rig.bone_names
    np.testing.assert_array_equal(s.parents, rig.parents)
    np.testing.assert_allclose(s.rolls, rig.rolls)
    assert rig.weights_file == _rig_dir() / "rigs" / "standard" / "weights.default.json"


def test_default_no_toes_reads_the_default_weights_and_other_rigs_their_own(tmp_path):
    _write_rig(tmp_path, "default_no_toes")
    _write_rig(tmp_path, "cmu_mb")
    assert K.load_rig("default_no_toes", tmp_path, 6, CUBES).weights_file.name == "weights.default.json"
    assert K.load_rig("cmu_mb", tmp_path, 6, CUBES).weights_file.name == "weights.cmu_mb.json"
    assert K.RIGS == ("game_engine", "default", "default_no_toes", "cmu_mb")


def test_load_rig_refusals(tmp_path):
    with pytest.raises(InputError, match=r"unknown rig 'tpose'; valid rigs: game_engine, default, default_no_toes"):
        K.load_rig("tpose", tmp_path, 6, CUBES)
    with pytest.raises(AssetError, match=r"rig\.default\.json: cannot read rig .*\); delete the asset cache and "
                                         r"rerun 'make setup'$"):
        K.load_rig("default", tmp_path, 6, CUBES)
    folder = tmp_path / "rigs" / "standard"
    folder.mkdir(parents=True)
    (folder / "rig.default.json").write_text("{not json")
    with pytest.raises(AssetError, match=r"rig\.default\.json: cannot read rig"):
        K.load_rig("default", tmp_path, 6, CUBES)
    ends = {"head": RIG["zhand"]["head"], "tail": RIG["zhand"]["tail"]}
    orphan = {**RIG, "foot": {"parent": "leg", **ends}, "leg": {"parent": "foot", **ends}}
    _write_rig(tmp_path, rig=orphan)
    with pytest.raises(AssetError, match=r"rig\.default\.json: bones \['foot', 'leg'\] have parents outside the rig$"):
        K.load_rig("default", tmp_path, 6, CUBES)
    # at most three of them named
    orphans = {**orphan, "toe": {"parent": "x", **ends}, "heel": {"parent": "x", **ends}}
    _write_rig(tmp_path, rig=orphans)
    with pytest.raises(AssetError, match=r"bones \['foot', 'heel', 'leg'\] have parents outside the rig$"):
        K.load_rig("default", tmp_path, 6, CUBES)
    _write_rig(tmp_path, rig={"b": {"parent": None, "head": {"strategy": "CUBE", "cube_name": "c_x"},
                                    "tail": RIG["zhand"]["tail"]}})
    with pytest.raises(AssetError, match=r"rig\.default\.json: bone b uses joint cube 'c_x', which the base mesh"):
        K.load_rig("default", tmp_path, 6, CUBES)
    _write_rig(tmp_path, rig={"b": {"parent": None, "head": RIG["zhand"]["head"],
                                    "tail": {"strategy": "SPLINE"}}})
    with pytest.raises(AssetError, match=r"rig\.default\.json: bone b has unknown joint strategy 'SPLINE'"):
        K.load_rig("default", tmp_path, 6, CUBES)


def _weights_rig(tmp_path, weights):
    _write_rig(tmp_path, weights=weights)
    return K.load_rig("default", tmp_path, 6, CUBES)


def test_skin_weights_are_summed_clipped_and_normalised_by_hand(tmp_path):
    weights = {"weights": {
        "aux": [],  # an empty bone and one the rig lacks come first: skipped, the others still read
        "tail_bone_not_in_rig": [[0, 100.0]],
        "base": [[0, 1.0], [1, 0.5], [1, 0.25], [2, 2.0], [7, 5.0], [4, 1.0]],  # vertex 1: 0.75; 4, 7: >= n_body
        "arm": [[1, 0.25], [2, 2.0], [3, -1.0], [3, 0.0]],           # a negative weight clipped to 0
        "zhand": [[3, 3.0], [0, 0.0]],
    }}
    rig = _weights_rig(tmp_path, weights)
    W = K.load_skin_weights(rig, 4)
    # columns: aux, base, arm, zhand
    np.testing.assert_allclose(W, [[0, 1, 0, 0], [0, 0.75, 0.25, 0], [0, 0.5, 0.5, 0], [0, 0, 0, 1]], atol=1e-15)
    # rows of chosen base-mesh vertices, including one past n_body (a helper vertex)
    Wv = K.load_skin_weights(rig, 4, vertex_ids=[7, 1])
    np.testing.assert_allclose(Wv, [[0, 1, 0, 0], [0, 0.75, 0.25, 0]], atol=1e-15)
    Wv = K.load_skin_weights(rig, 4, vertex_ids=np.array([3.0, 2.0]))
    np.testing.assert_allclose(Wv, [[0, 0, 0, 1], [0, 0.5, 0.5, 0]], atol=1e-15)


def test_skin_weights_refusals(tmp_path):
    rig = _weights_rig(tmp_path, {"weights": {"base": [[0, 1.0], [2, 1.0]], "arm": [[1, -2.0]]}})
    with pytest.raises(AssetError, match=r"weights\.default\.json: 2 vertices have no skin weight"):
        K.load_skin_weights(rig, 4)
    with pytest.raises(AssetError, match=r"weights\.default\.json: 1 vertices have no skin weight"):
        K.load_skin_weights(rig, 4, vertex_ids=[0, 1])
    rig = _weights_rig(tmp_path, {"bones": {}})
    with pytest.raises(AssetError, match=r"weights\.default\.json: cannot read skin weights .*rerun 'make setup'"):
        K.load_skin_weights(rig, 4)
    (tmp_path / "rigs" / "standard" / "weights.default.json").write_text("[")
    with pytest.raises(AssetError, match=r"cannot read skin weights"):
        K.load_skin_weights(rig, 4)
    (tmp_path / "rigs" / "standard" / "weights.default.json").unlink()
    with pytest.raises(AssetError, match=r"cannot read skin weights"):
        K.load_skin_weights(rig, 4)
