"""The rest-shape fits and the capture give the same bits with 1 and 2 BLAS threads (issue 11, docs/muscle.md "the
thread count"): their normal equations and solves go through ``muscle.normal_equations`` (numpy's fixed summation
order), not OpenBLAS's skinny products and LU, whose last bits depend on the thread count; the sequence fit after them
turns such a 1e-13 m difference into up to millimetres."""

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from bodystudio.muscle.normal_equations import normal_matrix, normal_rhs, ordered_product, spd_solve
from tests.muscle.test_body_rest_shape import planted, space_2k  # noqa: F401  (the planted 8-frame subject)
from tests.muscle.test_capture_analytic import scene  # noqa: F401  (the tiny capture scene)


def _at_threads(n, f):
    with threadpool_limits(limits=n):
        return f()


def _flat(out):
    """The floats of a fit's result (arrays, poses, lists of them) as one vector."""
    if isinstance(out, np.ndarray):
        return out.ravel()
    if hasattr(out, "angles"):
        return np.r_[out.root.ravel(), out.angles.ravel()]
    return np.concatenate([_flat(o) for o in out])


def test_the_normal_equations_are_numpys_algebra_and_the_same_at_any_thread_count():
    """``normal_matrix`` / ``normal_rhs`` / ``ordered_product`` equal ``G.T @ diag(w) @ G`` etc. to rounding and
    ``spd_solve`` solves the system (residual at rounding), each bit for bit the same with 1 and 2 threads; a
    product of this skinny shape through BLAS (``G.T @ (w G)``) is not on OpenBLAS 0.3 (checked on main's code)."""
    rng = np.random.default_rng(5)
    G = rng.standard_normal((4000, 60))
    w = rng.random(4000)
    r = rng.standard_normal(4000)
    B = rng.standard_normal((4000, 4))
    H_ref = G.T @ (w[:, None] * G)
    H = normal_matrix(G, w)
    np.testing.assert_allclose(H, H_ref, rtol=0, atol=1e-10 * np.abs(H_ref).max())
    assert np.array_equal(H, H.T)
    np.testing.assert_allclose(normal_matrix(G), G.T @ G, rtol=0, atol=1e-10 * np.abs(G.T @ G).max())
    np.testing.assert_allclose(normal_rhs(G, r, w), G.T @ (w * r), rtol=0, atol=1e-10 * np.abs(G.T @ (w * r)).max())
    np.testing.assert_allclose(normal_rhs(G, B, w), G.T @ (w[:, None] * B), rtol=0, atol=1e-9)
    np.testing.assert_allclose(ordered_product(G[:60], B[:60]), G[:60] @ B[:60], rtol=0, atol=1e-12)
    # an ill-scaled SPD system (units from 1e-3 to 1e3): the solve's residual is at rounding
    scale = np.logspace(-3, 3, 60)
    A = H * scale[:, None] * scale[None, :] + np.diag(1e-6 * scale ** 2)
    b = rng.standard_normal((60, 3))
    x = spd_solve(A, b)
    assert np.abs(A @ x - b).max() < 1e-9 * np.abs(b).max()
    np.testing.assert_allclose(spd_solve(A, b[:, 0]), x[:, 0], rtol=1e-12, atol=0)
    for f in (lambda: normal_matrix(G, w), lambda: normal_rhs(G, r, w), lambda: spd_solve(A, b)):
        assert np.array_equal(_at_threads(1, f), _at_threads(2, f))
    with pytest.raises(np.linalg.LinAlgError):
        spd_solve(np.array([[1.0, 2.0], [2.0, 1.0]]), np.ones(2))


@pytest.mark.parametrize("fit", ["held_poses", "joint", "projection"])
def test_the_rest_shape_fits_give_the_same_bits_with_one_and_two_threads(planted, fit):  # noqa: F811
    """The planted 8-frame subject (~1000 pairs a frame, ~100 body parameters) at the capture's defaults (prior
    100, norm limit 0.2, Huber 4 mm, 3 Gauss-Newton steps): ``fit_body_rest_shape``, ``fit_body_rest_shape_and_poses``
    and ``project_to_body_space`` give identical results at 1 and 2 BLAS threads. On main's code (BLAS products and
    ``np.linalg.solve``) they differed by 7e-14 to 4e-12 (and the 4-frame capture after them by up to 1.65 mm)."""
    from bodystudio.muscle.model import project_to_body_space
    from bodystudio.muscle.refine import fit_body_rest_shape, fit_body_rest_shape_and_poses

    s = planted
    common = (100.0, 0.2, 0.004, 3)
    tracker = np.stack(_tracked(s))
    if fit == "held_poses":
        def run():
            return fit_body_rest_shape(s.space, s.model, s.poses, s.frames, s.mean, s.shoulder, s.mean, s.sigma,
                                       *common, True, None, 0.0, tracker, 30.0)
    elif fit == "joint":
        def run():
            return fit_body_rest_shape_and_poses(s.space, s.model, s.poses, s.frames, s.mean, s.shoulder, s.mean,
                                                 s.sigma, *common, None, 0.0, tracker, 30.0, 1.0)
    else:
        rest, J = s.space.rest_and_joints(s.x_true, s.shoulder)

        def run():
            return project_to_body_space(s.space, rest + 1e-3 * np.sin(rest), J, s.mean, s.sigma)
    one, two = _flat(_at_threads(1, run)), _flat(_at_threads(2, run))
    assert np.all(np.isfinite(one))
    assert np.abs(one - _flat(_at_threads(1, run))).max() == 0.0  # repeatable at all
    assert np.abs(two - one).max() == 0.0, np.abs(two - one).max()


def _tracked(s):
    """The planted frames' true shoulder, elbow and wrist (a noise-free body tracker)."""
    from bodystudio.muscle.refine import posed_joints

    _, J = s.space.rest_and_joints(s.x_true, s.shoulder)
    out = []
    for p in s.poses:
        root = p.root.copy()
        root[:3, 3] += s.offset
        out.append(posed_joints(J, type(p)(root, p.angles)))
    return out


def test_the_capture_with_the_body_rest_shape_gives_the_same_mesh_with_one_and_two_threads(scene):  # noqa: F811
    """End to end on the tiny 3-frame scene with the body rest-shape fit on (the default: two rounds, the joint fit,
    keep-best, the pose refit; fewer NICP and sequence steps for speed): the captured meshes and the fitted rest
    shape are bit for bit the same with 1 and 2 BLAS threads (on main's code: 0.41 mm apart)."""
    from bodystudio.muscle.capture import CaptureOptions, capture_arm_frames
    from bodystudio.muscle.nicp import NicpOptions

    s = scene
    o = CaptureOptions(mode="model", shape_frames=2, shape_rounds=1, first_frame_nicp_iterations=3,
                       nicp=NicpOptions(iterations=2), body_rest_frame_stride=1, sequence_max_nfev=5)
    assert o.body_rest_shape and o.body_rest_fit_poses and o.body_rest_keep_best and o.pose_refit

    def run():
        c = capture_arm_frames(s.depths, s.camera, s.template, s.model, o, s.tracker, known_shape=s.shape)
        return np.r_[c.vertices.ravel(), c.joints.ravel()]

    one, two = _at_threads(1, run), _at_threads(2, run)
    assert np.abs(two - one).max() == 0.0, np.abs(two - one).max()
