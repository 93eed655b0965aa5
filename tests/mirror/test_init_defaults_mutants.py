"""mir12y's and mir12ab's init settings (mutLL): the defaults as docs/mirror.md measured them, and what
``initialise_from_observations`` hands the Eq. 2 fit for ``leg_splay`` / ``knee_hinge_weight`` / ``pool_seed``
in each pass (stand-ins for the fit and the refinement; the real ``leg_splay_basis`` of each pass's body)."""

import inspect

import numpy as np
import pytest

from bodystudio.mirror import init as init_mod
from bodystudio.mirror.init import initialise_from_observations, leg_splay_basis, refit_skeleton
from tests.mirror.test_init_pass_settle import frames  # noqa: F401  (the module fixture: 2k model, two frames)


def test_the_measured_defaults():
    sig = inspect.signature(initialise_from_observations).parameters
    # mir12y: the weighted pool with the posture bones is the default; mir12ab's leg splay off; mir12ac: the knee
    # angle rows on, from the SDK's joints
    assert init_mod.WEIGHTED_POOL is True and sig["weighted_pool"].default is True
    assert init_mod.UNPOSE_POSTURE_BONES == ("spine_02", "neck_01", "head")
    assert init_mod.LEG_SPLAY is False and sig["leg_splay"].default is False
    assert init_mod.KNEE_HINGE_WEIGHT == 3000.0 and sig["knee_hinge_weight"].default == 3000.0
    assert init_mod.KNEE_HINGE_FROM == "sdk" and sig["knee_hinge_from"].default == "sdk"
    assert sig["pool_seed"].default == 0
    assert init_mod.LEG_SPLAY_SIGMA_RAD == 0.1
    assert inspect.signature(init_mod.fit_shape).parameters["free_sigma"].default == 0.1
    assert init_mod.LEG_SPLAY_CHAINS == (("calf_l", ("calf_l", "foot_l", "ball_l")),
                                         ("calf_r", ("calf_r", "foot_r", "ball_r")))
    assert init_mod.MATCH_NEIGHBOURS == 4
    assert inspect.signature(init_mod.closest_vertex_matches).parameters["neighbours"].default == 4


def _fits(monkeypatch, frames, passes=3, refine=False, **options):  # noqa: F811
    """The passes' Eq. 2 fits recorded: pass k's fit returns 0.1 k standard deviations; with ``refine`` each frame's
    refined pose is a stand-in ("pose F/K": frame F, pass K) and the knee-hinge rows a recorded stand-in."""
    from bodystudio.mirror import refine as refine_mod

    model, eye, obs = frames
    calls, hinge = [], []
    options.setdefault("knee_hinge_weight", 0.0)  # mir12ab's rows from the refined poses: mir12ac's default is off here
    options.setdefault("knee_hinge_from", "refined")

    def fit(P0, m, coeffs, **kw):
        calls.append(kw)
        return np.full(m.n_components, 0.1 * len(calls)) * m.stddev, 0.004

    def rows(m, skeleton, poses, version, weight):
        hinge.append((m, skeleton, list(poses), version, weight))
        return f"rows {len(hinge)}"

    monkeypatch.setattr(init_mod, "fit_shape", fit)
    monkeypatch.setattr(init_mod, "knee_hinge_splay_rows", rows)
    if refine:
        monkeypatch.setattr(refine_mod, "refine_plan", lambda *args: "plan")
        monkeypatch.setattr(init_mod, "refined_init_pose",
                            lambda plan, body, o, P, cam, steps, **kw: None)
    initialise_from_observations(obs, model, view_point=eye, passes=passes, floor_y=None,
                                 depth_camera="cam" if refine else None, unpose_posture_bones=(), **options)
    return model, calls, hinge


def test_leg_splay_hands_each_pass_the_columns_of_its_own_body(monkeypatch, frames):  # noqa: F811
    model, calls, _ = _fits(monkeypatch, frames, leg_splay=True)
    assert len(calls) == 3
    for k, kw in enumerate(calls):
        c = np.zeros(model.n_components) if k == 0 else np.full(model.n_components, 0.1 * k) * model.stddev
        cols, joint_cols = leg_splay_basis(model.vertices(c), model.weights, refit_skeleton(model, c), "v2")
        np.testing.assert_allclose(kw["free_basis"], cols, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kw["free_joint_basis"], joint_cols, rtol=0, atol=1e-12)
        assert kw["free_sigma"] == init_mod.LEG_SPLAY_SIGMA_RAD and kw["coeff_rows"] is None
    _, calls, _ = _fits(monkeypatch, frames)  # off: nothing free
    assert all(kw["free_basis"] is None and kw["free_joint_basis"] is None for kw in calls)


def test_knee_hinge_rows_from_the_previous_pass_refined_poses(monkeypatch, frames):  # noqa: F811
    model, calls, hinge = _fits(monkeypatch, frames, passes=3, refine=True, knee_hinge_weight=2.5)
    # pass 0 has no refined poses (the refinement starts in pass 1, with the body pass 0 fitted): no rows; passes 1
    # and 2: the rows of the two frames' poses refined in that pass, on that pass's body, at the option's weight
    assert [kw["coeff_rows"] for kw in calls] == [None, "rows 1", "rows 2"]
    assert len(hinge) == 2
    for k, (m, skeleton, poses, version, weight) in enumerate(hinge, start=1):
        assert m is model and version == "v2" and weight == 2.5 and len(poses) == 2
        c = np.full(model.n_components, 0.1 * k) * model.stddev
        np.testing.assert_allclose(skeleton.heads, refit_skeleton(model, c).heads, rtol=0, atol=1e-12)
    # weight 0: no rows, whatever the poses
    _, calls, hinge = _fits(monkeypatch, frames, passes=3, refine=True)
    assert hinge == [] and all(kw["coeff_rows"] is None for kw in calls)
    # no refinement (no depth camera): no poses, no rows
    _, calls, hinge = _fits(monkeypatch, frames, passes=3, knee_hinge_weight=2.5)
    assert hinge == [] and all(kw["coeff_rows"] is None for kw in calls)


@pytest.mark.parametrize("seed", [0, 3])
def test_pool_seed_is_the_random_subsets_generator_seed(monkeypatch, frames, seed):  # noqa: F811
    """The random subset of each pass is ``default_rng(pool_seed).choice(N, pooled_points, replace=False)`` drawn in
    pass order (the pool's rows: the frames' points in order)."""
    model, eye, obs = frames
    pooled = []
    monkeypatch.setattr(init_mod, "fit_shape", lambda P0, m, c, **kw: pooled.append(np.array(P0))
                        or (np.zeros(m.n_components), 0.004))
    import dataclasses

    original = init_mod.transform_to_default_pose

    def unposed(P, *args, **kw):
        cloud = original(P, *args, **kw)
        return dataclasses.replace(cloud, points=np.array(P), correspondence=np.arange(len(P)) % len(model.mean))

    monkeypatch.setattr(init_mod, "transform_to_default_pose", unposed)
    initialise_from_observations(obs, model, view_point=eye, passes=2, floor_y=None, weighted_pool=False,
                                 pooled_points=50, pool_seed=seed, unpose_posture_bones=())
    everything = np.concatenate([o.points for o in obs])
    rng = np.random.default_rng(seed)
    for P0 in pooled:
        np.testing.assert_array_equal(P0, everything[rng.choice(len(everything), 50, replace=False)])
