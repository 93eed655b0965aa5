"""bodystudio.body.model against references independent of it (issue 17, mutation testing): posing a two-bone
stand-in body (rigid one-bone vertices, the LBS average and the DQS half-angle rotation of a 50/50 vertex in
closed form), the shape as base vertices plus hand-summed target deltas with the feet put on y = 0, the full
template's quad split written out, the decimation's pymeshlab call spied and run on a sphere and an open grid,
and every field of a built body against the rig's regressors and the renormalised weight rows."""

from functools import cache

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from bodystudio.body import model as body_model
from bodystudio.body.makehuman import load_base, load_targets
from bodystudio.body.phenotype import Phenotype, local_target_weights, macro_target_weights
from bodystudio.body.pose import Pose
from bodystudio.body.skeleton import Skeleton, load_skin_weights
from bodystudio.errors import InputError

PHENOTYPE = Phenotype(gender=0.8, weight=0.7, height=0.3)
LOCAL = {"upperarm-fat-decr-incr": 0.3, "l-lowerleg-scale-depth-decr|incr": -0.4}


def _two_bones():
    """A 1 m root up +y from the origin and a 1 m child above it; vertices: root only, child only, 50/50."""
    heads = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    tails = np.array([[0.0, 1.0, 0.0], [0.0, 2.0, 0.0]])
    sk = Skeleton(("root", "child"), np.array([-1, 0]), heads, tails, np.array([0.0, 0.4]))
    V = np.array([[0.2, 0.5, 0.1], [0.3, 1.6, -0.2], [-0.1, 1.2, 0.4]])
    W = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])
    F = np.array([[0, 1, 2]])
    return body_model.BodyModel(V, F, sk, W, resolution="2k")


def _world_rotation(sk, j, rotvec):
    """A local rotation of bone ``j`` in world axes (its rest frame's axes)."""
    A = sk.rest_rotations[j]
    return A @ Rotation.from_rotvec(rotvec).as_matrix() @ A.T


@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_a_bent_child_bone_moves_its_vertices_rigidly_about_its_head(method):
    body = _two_bones()
    r = np.array([0.9, 0.0, 0.3])
    rot = np.zeros((2, 3))
    rot[1] = r
    V, heads = body.pose(Pose(rot, np.zeros(3)), method=method)
    p = body.skeleton.heads[1]
    Rw = _world_rotation(body.skeleton, 1, r)
    np.testing.assert_allclose(V[0], body.vertices[0], atol=1e-12)
    np.testing.assert_allclose(V[1], Rw @ (body.vertices[1] - p) + p, atol=1e-12)
    np.testing.assert_allclose(heads, body.skeleton.heads, atol=1e-12)
    v = body.vertices[2]
    if method == "lbs":  # the average of the two rigid motions
        expected = 0.5 * (v + Rw @ (v - p) + p)
    else:  # the dual-quaternion blend of the identity and a rotation about p: half the angle about p
        expected = _world_rotation(body.skeleton, 1, r / 2) @ (v - p) + p
    np.testing.assert_allclose(V[2], expected, atol=1e-12)


@pytest.mark.parametrize("method", ["lbs", "dqs"])
def test_a_rotated_root_carries_everything_and_the_heads(method):
    body = _two_bones()
    rot = np.zeros((2, 3))
    rot[0] = [0.0, 0.0, 0.7]
    t = np.array([0.3, -0.2, 0.5])
    V, heads = body.pose(Pose(rot, t), method=method)
    Rw = _world_rotation(body.skeleton, 0, rot[0])  # about the root's head at the origin
    np.testing.assert_allclose(V, body.vertices @ Rw.T + t, atol=1e-12)
    np.testing.assert_allclose(heads, body.skeleton.heads @ Rw.T + t, atol=1e-12)


def test_pose_defaults_to_lbs_and_refuses_other_methods():
    body = _two_bones()
    rot = np.zeros((2, 3))
    rot[1] = [1.2, 0.0, 0.0]
    pose = Pose(rot, np.zeros(3))
    default, _ = body.pose(pose)
    lbs, _ = body.pose(pose, method="lbs")
    dqs, _ = body.pose(pose, method="dqs")
    np.testing.assert_array_equal(default, lbs)
    assert np.abs(lbs[2] - dqs[2]).max() > 1e-3  # the two blends differ on the 50/50 vertex
    with pytest.raises(InputError) as err:
        body.pose(pose, method="LBS")
    assert str(err.value) == "unknown skinning method 'LBS'; valid: lbs, dqs"


def test_rest_pose_is_zero_rotations_and_translation_per_bone():
    pose = _two_bones().rest_pose()
    np.testing.assert_array_equal(pose.rotations, np.zeros((2, 3)))
    np.testing.assert_array_equal(pose.translation, np.zeros(3))


def test_an_unknown_resolution_is_named_with_the_valid_ones():
    for call in (lambda: body_model.template_topology("100k"), lambda: body_model.build_body(resolution="100k")):
        with pytest.raises(InputError) as err:
            call()
        assert str(err.value) == "unknown resolution '100k'; valid: full, 6k, 2k"


@cache
def _reference_weights():
    """Macro weights plus the local ones, summed by hand (no name is both)."""
    base = load_base()
    names = load_targets(len(base.vertices)).names
    macro = macro_target_weights(PHENOTYPE, names)
    local = local_target_weights(LOCAL, base.data_dir, names)
    assert local and not set(local) & set(macro)
    return {**macro, **local}


def test_shape_weights_are_the_macro_and_local_weights():
    got = body_model.shape_weights(PHENOTYPE, LOCAL)
    ref = _reference_weights()
    assert set(got) == set(ref)
    for k, w in ref.items():
        assert got[k] == pytest.approx(w, abs=1e-15)
    # the local ones: 0.3 on both upper arms, 0.4 on the left lower leg's "decr" target
    assert sorted(v for k, v in got.items() if "upperarm-fat" in k or "lowerleg-scale-depth" in k) == \
        pytest.approx([0.3, 0.3, 0.4])
    assert body_model.shape_weights(PHENOTYPE) == macro_target_weights(PHENOTYPE, load_targets(
        len(load_base().vertices)).names)


@cache
def _reference_shape():
    """Base vertices plus each target's delta times its weight (summed one target at a time), feet on y = 0."""
    base = load_base()
    targets = load_targets(len(base.vertices))
    V = np.array(base.vertices, dtype=np.float64)
    for name, w in _reference_weights().items():
        idx, d = targets.delta(name)
        for i, row in zip(idx, d, strict=True):
            V[i] += w * row
    V[:, 1] -= V[: base.n_body, 1].min()
    return V


def test_shaped_vertices_add_the_weighted_targets_and_stand_the_body_on_y0():
    base = load_base()
    V = body_model.shaped_vertices(PHENOTYPE, LOCAL)
    ref = _reference_shape()
    np.testing.assert_allclose(V, ref, atol=1e-12)
    assert V[: base.n_body, 1].min() == 0.0
    assert V[:, 1].min() < 0.0  # a helper below the feet is not what stands on the floor
    default = body_model.shaped_vertices()
    np.testing.assert_array_equal(default, body_model.shaped_vertices(Phenotype(), {}))


def test_the_full_template_splits_each_quad_into_two_triangles():
    ids, F = body_model.template_topology("full")
    Q = load_base().body_quads
    assert ids is None
    assert F.shape == (2 * len(Q), 3)
    for k in (0, 1, len(Q) // 2, len(Q) - 1):
        a, b, c, d = Q[k]
        assert F[2 * k].tolist() == [a, b, c] and F[2 * k + 1].tolist() == [a, c, d]
    ids, F = body_model.template_topology("2k")
    assert 2000 <= len(ids) <= 3000 and F.max() == len(ids) - 1


class _SpyMeshSet:
    """Records the decimation call and hands back a mesh whose first vertex moved by ``shift``."""

    calls: list = []

    def __init__(self, shift):
        self.shift = shift

    def add_mesh(self, mesh):
        self.mesh = mesh

    def meshing_decimation_quadric_edge_collapse(self, **kw):
        _SpyMeshSet.calls.append(kw)

    def meshing_remove_unreferenced_vertices(self):
        _SpyMeshSet.calls.append("remove")

    def current_mesh(self):
        return self.mesh


class _SpyMesh:
    def __init__(self, V, F, shift=0.0):
        self.V, self.F = np.array(V, dtype=np.float64), np.asarray(F, dtype=np.int32)
        self.V[0] += shift

    def vertex_matrix(self):
        return self.V

    def face_matrix(self):
        return self.F


def _spy_pymeshlab(shift):
    from types import SimpleNamespace

    return SimpleNamespace(MeshSet=lambda: _SpyMeshSet(shift), Mesh=lambda V, F: _SpyMesh(V, F, shift))


def test_decimation_asks_pymeshlab_to_keep_vertices_and_refuses_moved_ones(monkeypatch):
    import bodystudio.geometry.meshlab as meshlab

    sphere = trimesh.creation.icosphere(2)
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    _SpyMeshSet.calls = []
    monkeypatch.setattr(meshlab, "import_pymeshlab", lambda: _spy_pymeshlab(0.0))
    ids, Fl = body_model.decimate_keeping_vertices(V, F, 37)
    assert _SpyMeshSet.calls == [dict(targetfacenum=74, optimalplacement=False, preserveboundary=True,
                                      preservenormal=True, preservetopology=True, planarquadric=True,
                                      qualitythr=0.5), "remove"]
    np.testing.assert_array_equal(ids, np.arange(len(V)))
    assert ids.dtype == np.int64 and Fl.dtype == np.int64
    np.testing.assert_array_equal(Fl, F)
    monkeypatch.setattr(meshlab, "import_pymeshlab", lambda: _spy_pymeshlab(2e-9))
    with pytest.raises(RuntimeError) as err:
        body_model.decimate_keeping_vertices(V, F, 37)
    assert str(err.value) == "decimation moved vertices; expected optimalplacement=False to keep them"
    monkeypatch.setattr(meshlab, "import_pymeshlab", lambda: _spy_pymeshlab(5e-10))
    body_model.decimate_keeping_vertices(V, F, 37)  # within the 1e-9 round-off allowance


def test_decimation_keeps_a_subset_of_a_sphere_and_the_border_of_a_grid():
    sphere = trimesh.creation.icosphere(3)  # 642 vertices, 1280 faces
    V, F = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    ids, Fl = body_model.decimate_keeping_vertices(V, F, 100)
    assert len(Fl) == 200 and len(ids) == 102  # Euler: a closed sphere of 200 triangles has 102 vertices
    assert len(np.unique(ids)) == len(ids) and Fl.max() == len(ids) - 1
    centres = V[ids][Fl].mean(1)
    normals = np.cross(V[ids][Fl[:, 1]] - V[ids][Fl[:, 0]], V[ids][Fl[:, 2]] - V[ids][Fl[:, 0]])
    assert (np.einsum("ij,ij->i", normals, centres) > 0).all()  # still facing out
    n = 12  # an open 12 x 12 grid, slightly bent so the quadrics see curvature
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    G = np.c_[u.ravel(), v.ravel(), 0.1 * np.sin(3 * u.ravel()) * np.cos(2 * v.ravel())]
    q = np.arange(n * n).reshape(n, n)
    a, b, c, d = q[:-1, :-1].ravel(), q[:-1, 1:].ravel(), q[1:, 1:].ravel(), q[1:, :-1].ravel()
    GF = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    ids, Fl = body_model.decimate_keeping_vertices(G, GF, 60)
    border = np.unique(np.r_[q[0], q[-1], q[:, 0], q[:, -1]])
    assert set(border) <= set(ids.tolist())  # the boundary is kept
    assert len(ids) < n * n


def _bodies():
    """Built in each test, never cached: mutmut forks its mutants from a process that ran the clean tests."""
    return (body_model.build_body(PHENOTYPE, LOCAL, resolution="2k"), body_model.build_body(PHENOTYPE, LOCAL),
            body_model.build_body())


def test_a_built_body_is_the_shape_the_rig_and_the_renormalised_weights():
    base = load_base()
    low, full, _ = _bodies()
    rig = body_model.rig_definition("game_engine")
    ref = _reference_shape()
    W = load_skin_weights(rig, base.n_body)
    ids, F = body_model.template_topology("2k")
    np.testing.assert_array_equal(low.vertex_ids, ids)
    np.testing.assert_array_equal(low.faces, F)
    np.testing.assert_allclose(low.vertices, ref[ids], atol=1e-12)
    np.testing.assert_allclose(low.weights, W[ids], atol=1e-15)  # the asset's rows sum to 1 already
    for body in (low, full):
        np.testing.assert_allclose(body.skeleton.heads, rig.head_regressor @ ref, atol=1e-12)
        np.testing.assert_allclose(body.skeleton.tails, rig.tail_regressor @ ref, atol=1e-12)
        np.testing.assert_array_equal(body.skeleton.rolls, rig.rolls)
        assert body.skeleton.bone_names == rig.bone_names
        assert body.phenotype == PHENOTYPE and body.rig == "game_engine"
        assert body.local == LOCAL and body.local is not LOCAL
    assert low.resolution == "2k" and full.resolution == "full" and full.vertex_ids is None
    np.testing.assert_allclose(full.vertices, ref[: base.n_body], atol=1e-12)
    np.testing.assert_allclose(full.weights, W, atol=1e-15)
    np.testing.assert_array_equal(full.faces, body_model.template_topology("full")[1])


def test_a_template_body_renormalises_its_weight_rows(monkeypatch):
    W = load_skin_weights(body_model.rig_definition(), load_base().n_body)
    scale = 1.0 + np.arange(len(W)) % 7  # rows summing to 1 .. 7
    monkeypatch.setattr(body_model, "_full_weights", lambda rig: W * scale[:, None])
    low = body_model.build_body(resolution="2k")
    full = body_model.build_body()
    np.testing.assert_allclose(low.weights, W[low.vertex_ids], atol=1e-15)
    np.testing.assert_allclose(full.weights, W * scale[:, None], atol=1e-15)  # the full body keeps them


def test_a_default_body_is_the_default_phenotype_on_the_game_engine_rig():
    body = _bodies()[2]
    assert body.phenotype == Phenotype() and body.local == {} and body.resolution == "full"
    assert body.rig == "game_engine" and body.rig == body_model.DEFAULT_RIG
    np.testing.assert_array_equal(body.vertices, body_model.shaped_vertices(Phenotype())[: load_base().n_body])
    assert body_model.rig_definition().bone_names == body.skeleton.bone_names
    assert body_model.rig_definition().name == "game_engine"
