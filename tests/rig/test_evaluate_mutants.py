"""rig/evaluate.py's scores against hand-computed references: a stand-in scan ground truth and avatar whose posing
is a known linear function of the pose (so every held-out pose's vertex error is known), vertices matched by a
brute-force nearest neighbour, joint / finger errors and the weights' L1 per vertex in loops; and load_avatar on a
five-vertex avatar written by the exporter, read back field by field, with every refusal word for word.
"""

import json
from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.errors import FileFormatError
from bodystudio.register.synthetic import random_pose, scan_pose, t_pose_path
from bodystudio.rig import evaluate as ev
from bodystudio.rig.avatar import Avatar
from bodystudio.rig.export import rig_description, rig_json_path, write_glb


@cache
def bone_names():
    """The T-pose file's bones, the floor-level Root and three finger bones (the rig's order does not matter)."""
    tpose = tuple(json.loads(t_pose_path().read_text())["bone_rotations"])
    return ("Root",) + tpose[:6] + ("index_01_l", "thumb_02_r") + tpose[6:] + ("pinky_03_l",)


def test_eval_bones_leave_out_fingers_and_root():
    names = bone_names()
    got = ev.eval_bones(names)
    want = [i for i, b in enumerate(names) if b not in ("Root", "index_01_l", "thumb_02_r", "pinky_03_l")]
    assert got.tolist() == want and len(want) == len(names) - 4
    assert ev.eval_bones(("ring_01_r", "middle_02_l", "Root", "spine_01")).tolist() == [3]


def test_held_out_poses_are_the_t_pose_and_three_unused_random_ones():
    names = bone_names()
    poses = ev.held_out_poses(names)
    assert len(poses) == 4 == 1 + ev.N_HELD_OUT_RANDOM
    np.testing.assert_array_equal(poses[0].rotations, scan_pose("t", names, 0).rotations)
    for k in range(3):
        np.testing.assert_array_equal(poses[k + 1].rotations,
                                      random_pose(names, np.random.default_rng([424242, k])).rotations)
    # not the synthetic scans' own stream (seed, 7)
    assert not np.allclose(poses[1].rotations, scan_pose("random", names, 424242).rotations)
    assert len({p.rotations.tobytes() for p in poses}) == 4


@cache
def rig_case():
    """Ground truth with 40 scan vertices; the avatar: 30 of them (shuffled, 0.1 mm off, one twice) in a canonical
    frame turned by ``R``; posing moves every vertex by sum(rotations) times its own direction plus the translation."""
    rng = np.random.default_rng(11)
    names = bone_names()
    B = len(names)
    V_gt, D_gt = rng.normal(size=(40, 3)), rng.normal(size=(40, 3)) * 0.01
    gt_pose = Pose(rng.normal(size=(B, 3)) * 0.1, np.array([0.1, 0.0, -0.2]))
    W_gt = rng.random((40, B)) ** 6
    W_gt /= W_gt.sum(1, keepdims=True)

    def gt_posed(pose):
        return V_gt + pose.rotations.sum() * D_gt + pose.translation

    gt = SimpleNamespace(pose=gt_pose, joints=rng.normal(size=(B, 3)), weights=sp.csr_matrix(W_gt),
                         posed_vertices=gt_posed)
    R = Rotation.from_rotvec([0.0, 0.4, 0.1]).as_matrix()
    pick = np.r_[rng.permutation(40)[:29], 3]
    V_av = gt_posed(gt_pose)[pick] @ R.T + rng.normal(size=(30, 3)) * 1e-4
    D_av = D_gt[pick] @ R.T + rng.normal(size=(30, 3)) * 0.002
    bind_t = np.array([0.0, 0.05, 0.3])
    W_av = np.clip(W_gt[pick] + rng.normal(size=(30, B)) * 0.05, 0, None)
    avatar = SimpleNamespace(vertices=V_av, bone_names=names, heads=gt.joints @ R.T + rng.normal(size=(B, 3)) * 0.01,
                             weights=W_av, bind_translation=bind_t, metadata={"fit_err_mm_median": 1.25, "x": 1},
                             posed=lambda pose: (V_av + pose.rotations.sum() * D_av + pose.translation, None))
    return avatar, gt, R, pick


def test_evaluate_rig_against_per_vertex_and_per_joint_loops():
    avatar, gt, R, pick = rig_case()
    names = bone_names()
    region = np.zeros(30, bool)
    region[[1, 4, 9, 20, 29]] = True
    out = ev.evaluate_rig(avatar, gt, to_canonical=R, region=region)
    scan = gt.posed_vertices(gt.pose) @ R.T
    idx = [int(np.argmin(np.linalg.norm(scan - v, axis=1))) for v in avatar.vertices]
    assert idx == pick.tolist()
    body = [i for i, b in enumerate(names) if b not in ("Root", "index_01_l", "thumb_02_r", "pinky_03_l")]
    fingers = [names.index(b) for b in ("index_01_l", "thumb_02_r", "pinky_03_l")]
    jerr = [1000 * np.linalg.norm(avatar.heads[j] - R @ gt.joints[j]) for j in range(len(names))]
    errs = []
    for q in ev.held_out_poses(names):
        for i in range(len(avatar.vertices)):
            ours = avatar.posed(Pose(q.rotations, avatar.bind_translation))[0][i]
            truth = R @ gt.posed_vertices(Pose(q.rotations, gt.pose.translation))[idx[i]]
            errs.append((1000 * np.linalg.norm(ours - truth), region[i]))
    W_true = gt.weights.toarray()
    l1 = np.mean([np.abs(avatar.weights[i] - W_true[idx[i]]).sum() for i in range(30)])
    want = {"joint_err_mm_mean": np.mean([jerr[j] for j in body]), "joint_err_mm_max": max(jerr[j] for j in body),
            "joint_err_mm_mean_fingers": np.mean([jerr[j] for j in fingers]),
            "pose_vertex_err_mm_mean": np.mean([e for e, _ in errs]), "weights_l1_mean": l1,
            "fit_err_mm_median": 1.25, "pose_vertex_err_mm_region": np.mean([e for e, r in errs if r])}
    assert out == pytest.approx(want, rel=1e-12)
    assert list(out) == list(want)
    assert all(type(v) is float for v in out.values())
    assert out["pose_vertex_err_mm_mean"] > 5 and out["pose_vertex_err_mm_region"] != out["pose_vertex_err_mm_mean"]


def test_evaluate_rig_without_canonical_frame_region_or_fingers():
    avatar, gt, R, pick = rig_case()
    names = tuple(b for b in bone_names() if b not in ("index_01_l", "thumb_02_r", "pinky_03_l"))
    keep = [bone_names().index(b) for b in names]
    gt2 = SimpleNamespace(pose=Pose(gt.pose.rotations[keep], gt.pose.translation), joints=gt.joints[keep],
                          weights=sp.csr_matrix(gt.weights.toarray()[:, keep]), posed_vertices=gt.posed_vertices)
    V = gt.posed_vertices(gt.pose)[pick]
    av = SimpleNamespace(vertices=V, bone_names=names, heads=gt2.joints.copy(), weights=gt2.weights.toarray()[pick],
                         bind_translation=gt.pose.translation, metadata={},
                         posed=lambda pose: (gt.posed_vertices(pose)[pick], None))
    out = ev.evaluate_rig(av, gt2)
    assert out == {"joint_err_mm_mean": 0.0, "joint_err_mm_max": 0.0, "joint_err_mm_mean_fingers": None,
                   "pose_vertex_err_mm_mean": 0.0, "weights_l1_mean": 0.0, "fit_err_mm_median": None}
    with pytest.raises(FileFormatError) as exc:  # the avatar in its canonical frame does not match the raw scan
        ev.evaluate_rig(avatar, gt)
    assert "mm (median) from the ground-truth scan's; was it rigged from this scan (and not reshaped)?" in \
        str(exc.value)


def test_match_vertices_by_the_median_distance():
    rng = np.random.default_rng(4)
    G = rng.normal(size=(50, 3))
    order = rng.permutation(50)
    off = np.zeros((50, 3))
    off[:24, 0] = 0.0009  # 24 of 50 at 0.9 mm, the rest at 0: median 0
    assert ev.match_vertices(G[order] + off, G).tolist() == order.tolist()
    off[:26, 0] = 0.0009  # now the median is 0.9 mm: still within 1 mm
    assert ev.match_vertices(G[order] + off, G).tolist() == order.tolist()
    off[:26, 0] = 0.0012
    with pytest.raises(FileFormatError) as exc:
        ev.match_vertices(G[order] + off, G)
    assert str(exc.value) == "the avatar's vertices are 1.2 mm (median) from the ground-truth scan's; was it rigged " \
                             "from this scan (and not reshaped)?"
    assert ev.match_vertices(G[order] + off, G, max_mm=1.5).tolist() == order.tolist()
    off[:, 0] = 0.0016
    with pytest.raises(FileFormatError, match="1.6 mm"):
        ev.match_vertices(G[order] + off, G, max_mm=1.5)
    off[:26, 0] = 0.0012497  # the figure in the message is the median in mm, rounded to 0.1
    with pytest.raises(FileFormatError, match=r"are 1\.2 mm \(median\)"):
        ev.match_vertices(G[order] + off, G)
    off[:26, 0] = 0.0009995
    assert ev.match_vertices(G[order] + off, G).tolist() == order.tolist()
    flat = np.c_[np.zeros(50), G[:, 1:]]  # 1 mm exactly (x = 0 + 0.001): within
    assert ev.match_vertices(flat[order] + [0.001, 0.0, 0.0], flat).tolist() == order.tolist()


@cache
def tiny_avatar():
    """Five vertices (a pyramid), four bones in a chain (the exporter's four influences), colours, a bind
    translation."""
    V = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.2], [0.2, 0.0, 0.2], [0.1, 0.5, 0.1]])
    F = np.array([[0, 2, 1], [1, 2, 3], [0, 1, 4], [1, 3, 4], [3, 2, 4], [2, 0, 4]])
    rot = Rotation.from_rotvec([[0.0, 0.0, 0.1], [0.2, 0.0, 0.0], [0.0, -0.3, 0.0], [0.1, 0.1, 0.1]]).as_matrix()
    W = np.array([[1.0, 0, 0, 0], [0.5, 0.5, 0, 0], [0.25, 0.25, 0.5, 0], [0, 1.0, 0, 0], [0, 0.2, 0.7, 0.1]])
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 99, 199], [1, 2, 3]], np.uint8)
    return Avatar(V, F, colors, ("pelvis", "spine_01", "head", "hand_l"), np.array([-1, 0, 1, 0]), None, rot,
                  rot[::-1].copy(), np.array([0.2, 0.25, 0.15, 0.1]), W, np.array([0.0, 0.9, 0.1]),
                  {"fit_err_mm_median": 2.5, "seconds": 3.0, "scan": "s.ply", "other": 1},
                  loaded_heads=np.array([[0.1, 0.0, 0.1], [0.1, 0.2, 0.1], [0.1, 0.4, 0.1], [0.15, 0.1, 0.1]]))


@cache
def _exported(texture):
    """The tiny avatar's glb bytes, rig description and vertex map (the UV atlas is built once)."""
    import tempfile
    from pathlib import Path

    glb = Path(tempfile.mkdtemp(prefix="rig-eval-")) / "a.glb"
    source = write_glb(glb, tiny_avatar(), texture=texture)
    return glb.read_bytes(), rig_description(tiny_avatar(), source), source


def _written(tmp_path, texture=False, name="a.glb"):
    data, desc, source = _exported(texture)
    glb = tmp_path / name
    glb.write_bytes(data)
    rig_json_path(glb).write_text(json.dumps(desc))
    return glb, desc, source


@pytest.mark.parametrize("texture", [False, True])
def test_load_avatar_reads_back_every_field(tmp_path, texture):
    av = tiny_avatar()
    glb, _, source = _written(tmp_path, texture)
    assert (source is not None) == texture and (not texture or len(source) > 5)
    back = ev.load_avatar(str(glb))
    np.testing.assert_allclose(back.vertices, av.vertices, atol=1e-7)
    assert back.vertices.dtype == np.float64 and back.faces.dtype == np.int64
    assert sorted(map(sorted, back.faces.tolist())) == sorted(map(sorted, av.faces.tolist()))
    np.testing.assert_allclose(back.weights, av.weights, atol=1e-7)
    assert back.weights.shape == (5, 4)
    if texture:
        assert back.vertex_colors is None
    else:
        np.testing.assert_array_equal(back.vertex_colors, av.vertex_colors)
    assert back.bone_names == ("pelvis", "spine_01", "head", "hand_l") and back.parents.tolist() == [-1, 0, 1, 0]
    np.testing.assert_allclose(back.bind_rotations, av.bind_rotations, atol=1e-6)
    np.testing.assert_allclose(back.rest_rotations, av.rest_rotations, atol=1e-15)
    np.testing.assert_allclose(back.bone_lengths, [0.2, 0.25, 0.15, 0.1])
    np.testing.assert_allclose(back.bind_translation, [0.0, 0.9, 0.1])
    np.testing.assert_allclose(back.heads, av.heads, atol=1e-6)
    assert back.joint_coordinates is None
    assert back.metadata == {"fit_err_mm_median": 2.5, "seconds": 3.0, "scan": "s.ply"}
    np.testing.assert_allclose(back.posed(Pose(np.full((4, 3), 0.2), np.zeros(3)))[0],
                               av.posed(Pose(np.full((4, 3), 0.2), np.zeros(3)))[0], atol=1e-5)


def test_load_avatar_refusals_word_for_word(tmp_path):
    with pytest.raises(FileFormatError) as exc:
        ev.load_avatar(tmp_path / "none.glb")
    assert str(exc.value) == f"{tmp_path / 'none.glb'}: no such avatar file"
    glb, desc, _ = _written(tmp_path)
    rig_json_path(glb).unlink()
    with pytest.raises(FileFormatError) as exc:
        ev.load_avatar(glb)
    assert str(exc.value) == f"{tmp_path / 'a.rig.json'}: rig description not found; `bodystudio rig` writes it " \
                             "beside a.glb"
    rig_json_path(glb).write_text(json.dumps({**desc, "n_vertices": 6}))
    with pytest.raises(FileFormatError) as exc:
        ev.load_avatar(glb)
    assert str(exc.value) == f"{tmp_path / 'a.rig.json'}: describes 6 vertices but {glb} has 5; the two are from " \
                             "different runs, re-run `bodystudio rig`"
    rig_json_path(glb).write_text(json.dumps({k: v for k, v in desc.items() if k != "n_vertices"}))
    assert len(ev.load_avatar(glb).vertices) == 5  # no count: nothing to compare
    bad = tmp_path / "b.glb"
    bad.write_bytes(b"glTF not really")
    rig_json_path(bad).write_text(json.dumps(desc))
    with pytest.raises(FileFormatError) as exc:
        ev.load_avatar(bad)
    assert str(exc.value).startswith(f"{bad}: not a skinned glTF binary (")
    assert "NoneType" not in str(exc.value) and str(exc.value).split("(", 1)[1].split(":")[0].isidentifier()


def test_load_avatar_reads_accessors_with_their_own_offsets(tmp_path):
    """glTF lets an accessor start inside its buffer view (other exporters interleave): the data sits at the view's
    offset plus the accessor's."""
    import pygltflib

    glb, _, _ = _written(tmp_path)
    g = pygltflib.GLTF2().load(str(glb))
    moved = 0
    for acc in g.accessors:
        view = g.bufferViews[acc.bufferView]
        if (view.byteOffset or 0) >= 8:
            view.byteOffset -= 8
            view.byteLength += 8
            acc.byteOffset = 8
            moved += 1
    assert moved >= 4
    g.save(str(glb))
    back = ev.load_avatar(glb)
    av = tiny_avatar()
    np.testing.assert_allclose(back.vertices, av.vertices, atol=1e-7)
    np.testing.assert_allclose(back.weights, av.weights, atol=1e-7)
    np.testing.assert_array_equal(back.vertex_colors, av.vertex_colors)
    np.testing.assert_allclose(back.heads, av.heads, atol=1e-6)


def test_load_avatar_keeps_colours_through_a_vertex_map(tmp_path):
    glb, desc, _ = _written(tmp_path)  # the coloured glb, described with a vertex map (glb vertex i = avatar i)
    rig_json_path(glb).write_text(json.dumps({**desc, "vertex_source": list(range(5)), "n_avatar_vertices": 5}))
    back = ev.load_avatar(glb)
    np.testing.assert_array_equal(back.vertex_colors, tiny_avatar().vertex_colors)


def test_load_avatar_refuses_a_vertex_source_that_does_not_fit(tmp_path):
    glb, desc, source = _written(tmp_path, texture=True)
    n = len(source)
    cases = [
        ({"vertex_source": source[:-1].tolist()}, "vertex_source does not fit"),
        ({"vertex_source": [-1] + source[1:].tolist()}, "vertex_source does not fit"),
        ({"vertex_source": source.tolist(), "n_avatar_vertices": 4}, "vertex_source does not fit"),
        ({"vertex_source": source.tolist(), "n_avatar_vertices": 6}, "vertex_source misses avatar vertices"),
    ]
    for change, message in cases:
        rig_json_path(glb).write_text(json.dumps({**desc, **change}))
        with pytest.raises(FileFormatError) as exc:
            ev.load_avatar(glb)
        fix = "; re-run `bodystudio rig`"
        assert str(exc.value) == f"{tmp_path / 'a.rig.json'}: {message}" + \
            (f" {glb}{fix}" if "fit" in message else fix), str(exc.value)
    # without n_avatar_vertices the count is the largest source + 1
    rig_json_path(glb).write_text(json.dumps({k: v for k, v in desc.items() if k != "n_avatar_vertices"}))
    assert len(ev.load_avatar(glb).vertices) == 5 and n > 5
    # each avatar vertex is read from its first glb copy
    split = source.tolist()
    rig_json_path(glb).write_text(json.dumps({**desc, "vertex_source": split}))
    back = ev.load_avatar(glb)
    np.testing.assert_allclose(back.vertices, tiny_avatar().vertices, atol=1e-7)
    assert back.faces.max() == 4
