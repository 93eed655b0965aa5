"""Shape deformation of §5.1 (Eq. 4 of Real-time Reshaping) against answers known in closed form.

Eq. 4 without the refinement is linear in the edits (``c + sum_i lambda_i w_i``), lambda = 0 returns the
source; the ramp of "a gradual and continuous change" moves by at most its step; Eq. 3 moves every joint
but the floor anchor with its vertices, so a translated body has a translated skeleton.
"""

import math

import numpy as np
import pytest

from bodystudio.body import Pose, build_body
from bodystudio.body.population import sample_population
from bodystudio.errors import InputError
from bodystudio.mirror.init import SourceBody, refit_skeleton
from bodystudio.mirror.reshape import (
    EDIT_ATTRIBUTES,
    EDIT_NAMES,
    EDIT_RANGES,
    RAMP_STEP_PER_FRAME,
    check_edits,
    posed_source_and_target,
    ramp_edits,
    target_coeffs,
    target_skeleton,
)


@pytest.fixture(scope="module")
def model_source(model_6k):
    c = model_6k.project(build_body(*sample_population(1, seed=5)[0], resolution="6k").vertices)
    return SourceBody(c, model_6k.vertices(c), refit_skeleton(model_6k, c), (0,), 0.0, model_6k.weights, model_6k.faces)


def test_check_edits_accepts_the_range_and_refuses_the_rest():
    assert check_edits(None) == {} and check_edits({}) == {}
    ok = check_edits({n: EDIT_RANGES[n] for n in EDIT_NAMES})
    assert ok == {n: EDIT_RANGES[n] for n in EDIT_NAMES}
    assert check_edits({"heavier": "-40"}) == {"heavier": -40.0}
    assert isinstance(check_edits({"taller": 1 // 10})["taller"], float)
    for name, limit in EDIT_RANGES.items():
        with pytest.raises(InputError, match=f"edit {name}=.* out of range: use -{limit} to \\+{limit}"):
            check_edits({name: limit * 1.001})
        with pytest.raises(InputError, match="out of range"):
            check_edits({name: -limit * 1.001})
    with pytest.raises(InputError, match=r"out of range: use -40.0 to \+40.0 kg$"):
        check_edits({"heavier": 41})
    with pytest.raises(InputError, match=r"use -0.5 to \+0.5$"):  # muscularity has no unit
        check_edits({"muscular": 0.6})
    for bad in (math.nan, math.inf):
        with pytest.raises(InputError, match="out of range"):
            check_edits({"taller": bad})
    with pytest.raises(InputError, match="unknown edit 'wider'; valid edits: taller, heavier"):
        check_edits({"wider": 0.1})
    with pytest.raises(InputError, match="edit taller must be a number, got 'tall'"):
        check_edits({"taller": "tall"})
    with pytest.raises(InputError, match="must be a number"):
        check_edits({"taller": None})


def test_eq4_without_refinement_is_linear_in_the_edits(model_6k, model_source):
    """c_T = c_S + sum_i lambda_i w_i: doubling the edits doubles the step, edits add, lambda = 0 is the source."""
    c = model_source.coeffs
    a = {"taller": 0.06, "heavier": -8.0}
    b = {"muscular": 0.2, "waist": -0.04}
    step_a = target_coeffs(model_6k, c, a, refine=False) - c
    step_2a = target_coeffs(model_6k, c, {k: 2 * v for k, v in a.items()}, refine=False) - c
    np.testing.assert_allclose(step_2a, 2 * step_a, atol=1e-12)
    step_b = target_coeffs(model_6k, c, b, refine=False) - c
    np.testing.assert_allclose(target_coeffs(model_6k, c, {**a, **b}, refine=False) - c, step_a + step_b, atol=1e-12)
    assert np.abs(step_a).max() > 1e-3 and np.abs(step_b).max() > 1e-3
    # each edit moves along its own semantic direction w_i, by lambda_i
    W = model_6k.semantic_directions
    for name, lam in (("taller", 0.06), ("heavier", -8.0), ("hips", 0.05)):
        i = model_6k.attribute_names.index(EDIT_ATTRIBUTES[name])
        np.testing.assert_allclose(target_coeffs(model_6k, c, {name: lam}, refine=False) - c, lam * W[i], atol=1e-12)
    # lambda = 0 returns the source, as a copy
    for refine in (False, True):
        out = target_coeffs(model_6k, c, {"taller": 0.0, "heavier": 0.0}, refine=refine)
        np.testing.assert_array_equal(out, c)
        assert out is not c
        out[0] += 1.0
        assert out[0] != c[0]
        np.testing.assert_array_equal(target_coeffs(model_6k, c, None, refine=refine), c)
    # the refined step is the model's Newton-corrected edit; the linear one is its first step
    refined = target_coeffs(model_6k, c, a)
    np.testing.assert_allclose(refined, model_6k.edit(c, {"stature_m": 0.06, "mass_kg": -8.0}), atol=1e-12)
    assert np.abs(refined - (c + step_a)).max() > 1e-6
    with pytest.raises(InputError, match="unknown edit"):
        target_coeffs(model_6k, c, {"slimmer": 0.1}, refine=False)
    # an edit of exactly 1 (kg) is an edit like any other
    i = model_6k.attribute_names.index("mass_kg")
    np.testing.assert_allclose(target_coeffs(model_6k, c, {"heavier": 1.0}, refine=False) - c, W[i], atol=1e-12)


def test_ramp_moves_by_at_most_the_step_and_reaches_the_goal():
    # default steps per edit
    out = ramp_edits({}, {"taller": 0.1, "heavier": -5.0, "muscular": 0.01})
    assert out == pytest.approx({"taller": RAMP_STEP_PER_FRAME["taller"], "heavier": -RAMP_STEP_PER_FRAME["heavier"],
                                 "muscular": 0.01})
    # one number: the same step in each edit's unit
    assert ramp_edits({"taller": 0.05}, {"taller": 0.1, "heavier": 3.0}, max_step=0.02) == \
        pytest.approx({"taller": 0.07, "heavier": 0.02})
    # a dict: those edits' steps, the others' defaults
    assert ramp_edits({}, {"taller": 0.1, "heavier": 4.0}, max_step={"heavier": 1.5}) == \
        pytest.approx({"taller": 0.005, "heavier": 1.5})
    # downward, back to 0 when an edit is no longer wanted, and an edit neither current nor wanted stays absent
    assert ramp_edits({"taller": 0.1, "chest": -0.001}, {}, max_step=0.03) == pytest.approx({"taller": 0.07,
                                                                                             "chest": 0.0})
    assert ramp_edits({"hips": 0.01}, {"hips": -0.2}) == pytest.approx({"hips": 0.005})
    assert "waist" not in ramp_edits({"taller": 0.0}, {"heavier": 1.0})
    # a goal within one step is reached exactly, and stays
    assert ramp_edits({"taller": 0.098}, {"taller": 0.1}) == {"taller": 0.1}
    assert ramp_edits({"taller": 0.1}, {"taller": 0.1}) == {"taller": 0.1}
    with pytest.raises(InputError, match="^ramp max_step must be positive$"):
        ramp_edits({}, {"taller": 0.1}, max_step={"taller": -1.0})
    with pytest.raises(InputError, match="max_step must be positive"):
        ramp_edits({}, {"taller": 0.1}, max_step=0.0)
    with pytest.raises(InputError, match="max_step must be positive"):
        ramp_edits({}, {"taller": 0.1}, max_step=math.nan)
    with pytest.raises(InputError, match="out of range"):
        ramp_edits({"taller": 0.5}, {})


def test_target_skeleton_of_a_translated_body_is_translated_but_the_floor_anchor_stays(model_source):
    """Eq. 3 moves each joint by the mean displacement of its vertices: a body moved by d has every joint moved
    by d exactly, except the root (the rig's floor anchor between the feet), which keeps the source's."""
    d = np.array([0.03, -0.02, 0.05])
    sk = model_source.skeleton
    moved = target_skeleton(model_source, model_source.vertices + d)
    roots = np.asarray(sk.parents) < 0
    assert roots.sum() >= 1 and (~roots).sum() > 10
    np.testing.assert_allclose(moved.heads[~roots], sk.heads[~roots] + d, atol=1e-12)
    np.testing.assert_allclose(moved.tails[~roots], sk.tails[~roots] + d, atol=1e-12)
    np.testing.assert_array_equal(moved.heads[roots], sk.heads[roots])
    np.testing.assert_array_equal(moved.tails[roots], sk.tails[roots])
    assert moved.bone_names == sk.bone_names and list(moved.parents) == list(sk.parents)
    np.testing.assert_array_equal(moved.rolls, sk.rolls)
    # the source's own vertices give the source's skeleton
    same = target_skeleton(model_source, model_source.vertices)
    np.testing.assert_allclose(same.heads, sk.heads, atol=1e-12)


def test_posed_target_of_a_translated_body_is_the_posed_source_translated(model_source):
    """A pure translation of the rest body is a reshape whose posed displacement is that translation turned by
    the root's rotation: check it for the rest pose (no rotation: exactly d) and an explicit target rig."""
    sk = model_source.skeleton
    d = np.array([0.0, 0.0, 0.04])
    pose = Pose(np.zeros((sk.n_bones, 3)), np.array([0.3, 0.0, 2.0]))
    Vs, Vt = posed_source_and_target(model_source, model_source.vertices + d, pose)
    moved = target_skeleton(model_source, model_source.vertices + d)
    roots = np.asarray(sk.parents) < 0
    # the root keeps its place, every other bone carries the body: the posed target is the source moved by d
    assert np.allclose(moved.heads[roots], sk.heads[roots])
    np.testing.assert_allclose(Vt - Vs, np.broadcast_to(d, Vs.shape), atol=1e-9)
    # the target posed on the source's own rig (target_rig given) is the same rest-pose shift
    Vs2, Vt2 = posed_source_and_target(model_source, model_source.vertices + d, pose, target_rig=sk)
    np.testing.assert_allclose(Vs2, Vs, atol=1e-12)
    np.testing.assert_allclose(Vt2 - Vs2, np.broadcast_to(d, Vs.shape), atol=1e-9)
    with pytest.raises(InputError, match="do not match the source body"):
        posed_source_and_target(model_source, model_source.vertices[:-1], pose)
    bare = SourceBody(model_source.coeffs, model_source.vertices, sk, (0,), 0.0)
    with pytest.raises(InputError, match=r"^the source body has no skin weights: load it with "
                                         r"load_source_body\(path, model\)$"):
        posed_source_and_target(bare, model_source.vertices, pose)


def test_posed_target_uses_the_rig_given_and_poses_only_the_subset(model_source):
    """A turned pose: the target posed on an explicit rig (here the source's own, unmoved joints) is LBS of the
    target's rest vertices on that rig, not on the Eq. 3 skeleton; ``subset`` gives those rows of both bodies."""
    from bodystudio.body.pose import transfer_pose
    from bodystudio.mirror.track import skin_vertices

    sk = model_source.skeleton
    rot = np.random.default_rng(5).normal(0, 0.2, (sk.n_bones, 3))
    pose = Pose(rot, np.array([0.1, 0.0, 2.2]))
    d = np.array([0.0, 0.05, 0.0])
    Vt_rest = model_source.vertices * 1.03 + d
    _, on_rig = posed_source_and_target(model_source, Vt_rest, pose, target_rig=sk)
    want = skin_vertices(Vt_rest, model_source.weights, sk, transfer_pose(pose, sk, sk))
    np.testing.assert_allclose(on_rig, want, atol=1e-12)
    _, on_eq3 = posed_source_and_target(model_source, Vt_rest, pose)
    assert np.abs(on_eq3 - on_rig).max() > 1e-3
    sub = np.array([3, 500, 4000])
    Vs, Vt = posed_source_and_target(model_source, Vt_rest, pose)
    Vs_sub, Vt_sub = posed_source_and_target(model_source, Vt_rest, pose, subset=sub)
    assert Vs_sub.shape == (3, 3)
    np.testing.assert_allclose(Vs_sub, Vs[sub], atol=1e-12)
    np.testing.assert_allclose(Vt_sub, Vt[sub], atol=1e-12)


def test_target_skeleton_from_the_model_moves_the_joints_by_the_regressor(model_6k, model_source):
    """With the model and the target's coefficients (what ``mirror run`` does, lead 4) the source's joints move by
    ``model.skeleton(c_T) - model.skeleton(c_S)``, whatever the source skeleton is, the root too (MIR12s; with
    ``keep_root`` it stays, before MIR12s). On a source that carries the model's own joints this is the model's
    target skeleton exactly, and it differs from Eq. 3's."""
    c_s = model_source.coeffs
    c_t = target_coeffs(model_6k, c_s, {"taller": 0.17, "heavier": 15.0})
    V_t = model_6k.vertices(c_t)
    sk_s, sk_t = model_6k.skeleton(c_s), model_6k.skeleton(c_t)
    roots = np.asarray(sk_s.parents) < 0
    # a source with Eq. 3's skeleton (an older source_body.npz): moved by the regressor's change
    moved = target_skeleton(model_source, V_t, model_6k, c_t)
    eq3 = model_source.skeleton
    np.testing.assert_allclose(moved.heads, eq3.heads + sk_t.heads - sk_s.heads, atol=1e-12)
    np.testing.assert_allclose(moved.tails, eq3.tails + sk_t.tails - sk_s.tails, atol=1e-12)
    kept = target_skeleton(model_source, V_t, model_6k, c_t, keep_root=True)
    np.testing.assert_array_equal(kept.heads[roots], eq3.heads[roots])
    np.testing.assert_array_equal(kept.tails[roots], eq3.tails[roots])
    np.testing.assert_array_equal(kept.heads[~roots], moved.heads[~roots])
    # a source with the model's joints (what mirror init writes): the model's target skeleton
    own = SourceBody(c_s, model_source.vertices, sk_s, (0,), 0.0, model_6k.weights, model_6k.faces)
    exact = target_skeleton(own, V_t, model_6k, c_t)
    np.testing.assert_allclose(exact.heads, sk_t.heads, atol=1e-12)
    np.testing.assert_allclose(exact.tails, sk_t.tails, atol=1e-12)
    by_eq3 = target_skeleton(own, V_t)
    assert np.abs(by_eq3.heads - exact.heads)[~roots].max() > 1e-3  # Eq. 3 is another skeleton
    np.testing.assert_array_equal(by_eq3.heads[roots], sk_s.heads[roots])  # Eq. 3 keeps the root whatever


def test_posed_target_of_a_side_on_person_is_the_ground_truths(model_6k):
    """The mirror's target (the source's vertices and joints moved by the model's change, posed as the source) is the
    synthetic studio's Eq. 4 target (``synthetic.target_rest_body``) posed by the same pose, to 1e-9 m, for a person
    turned 80 degrees from the sensor. +10 cm with -15 kg moves the model's floor anchor (the ``Root``) 3 mm back:
    a target that keeps the source's root is off by ``(I - R_root) d``, ~4 mm side-on (MIR12s: warp_iou 0.931 ->
    0.946 on a walk that crosses the room side-on)."""
    from scipy.spatial.transform import Rotation

    from bodystudio.body.pose import transfer_pose
    from bodystudio.mirror.synthetic import target_rest_body

    actor = build_body(*sample_population(1, seed=11)[0], resolution="6k")
    target, c_s, c_t = target_rest_body(model_6k, actor, {"taller": 0.1, "heavier": -15.0})
    sk = actor.skeleton
    root = int(np.flatnonzero(np.asarray(sk.parents) < 0)[0])
    d = target.skeleton.heads[root] - sk.heads[root]
    assert np.linalg.norm(d) > 1e-3  # the anchor moves: the case that tells the two conventions apart
    rot = np.random.default_rng(3).normal(0.0, 0.1, (sk.n_bones, 3))
    world = Rotation.from_rotvec([0.0, np.radians(80.0), 0.0]).as_matrix()
    rot[root] = Rotation.from_matrix(sk.rest_rotations[root].T @ world @ sk.rest_rotations[root]).as_rotvec()
    pose = Pose(rot, np.array([0.2, 0.0, 0.4]))
    truth, _ = target.pose(transfer_pose(pose, sk, target.skeleton))
    source = SourceBody(c_s, actor.vertices, sk, (0,), 0.0, actor.weights, actor.faces)
    Vt_rest = actor.vertices + model_6k.vertices(c_t) - model_6k.vertices(c_s)
    for keep_root, lo, hi in ((None, 0.0, 1e-9), (True, 3e-3, 1e-2)):
        rig = target_skeleton(source, Vt_rest, model_6k, c_t, keep_root=keep_root)
        _, Vt = posed_source_and_target(source, Vt_rest, pose, rig)
        err = np.linalg.norm(Vt - truth, axis=1)
        assert lo <= err.mean() <= hi, (keep_root, err.mean())
    np.testing.assert_allclose(err, np.linalg.norm((np.eye(3) - world) @ d), atol=1e-9)  # all of it the anchor
