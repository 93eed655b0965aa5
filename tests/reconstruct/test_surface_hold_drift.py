"""The surface hold of Algorithm 1's outer iterations (issue 15's upper-back drift, ``RapidSkinParams.
surface_hold_k``): wrong rim matches that pull a surface further out with every re-matching are held near the
tangent planes of an earlier iterate, while right matches still move it."""

import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations, surface_hold_constraints
from bodystudio.reconstruct.silhouette import area_weighted_normals, silhouette_mask
from bodystudio.reconstruct.solver import ConstraintSet, SilhouetteConstraints, solve_constraints

HEAD_R, ARM_R, GAP = 0.15, 0.10, 0.02


def _sphere(radius, centre=(0.0, 0.0, 0.0), subdivisions=3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, float) + np.asarray(centre, float), np.asarray(m.faces, np.int64)


@pytest.fixture(scope="module")
def head_beside_arm():
    """The exact 'head' sphere as the template and an 'arm' sphere beside it that only the images show (the
    visual-hull gate's test scene): without the gate the arm's outline pulls the head out further with every
    re-matching, the drift in its simplest form."""
    V, F = _sphere(HEAD_R)
    Va, Fa = _sphere(ARM_R, (HEAD_R + GAP + ARM_R, 0.0, 0.0))
    scene_V, scene_F = np.vstack([V, Va]), np.vstack([F, Fa + len(V)])
    cams = [Camera.look_at(f"c{i}", (3 * np.sin(a), 0.4, 3 * np.cos(a)), (0, 0, 0), fx=500.0, width=320, height=240)
            for i, a in enumerate(np.linspace(0.0, 2 * np.pi, 6, endpoint=False) + 0.3)]
    masks = {c.name: silhouette_mask(scene_V, scene_F, c) for c in cams}
    return V, F, cams, masks


def _radial_mm(V, r):
    return 1000 * np.abs(np.linalg.norm(V, axis=1) - r)


def test_hold_limits_the_drift_of_wrong_matches(head_beside_arm):
    V, F, cams, masks = head_beside_arm
    base = dict(outer_iterations=6, inner_iterations=4, hull_gate_m=0.0)
    free = deform_to_observations(V, F, cams, masks, RapidSkinParams(**base)).vertices
    held = deform_to_observations(V, F, cams, masks, RapidSkinParams(**base, surface_hold_k=0.3,
                                                                     surface_hold_from=0)).vertices
    # measured: max radial error 130.7 mm free, 89.2 mm held; p90 18.2 -> 10.2 mm
    assert _radial_mm(free, HEAD_R).max() > 100.0
    assert _radial_mm(held, HEAD_R).max() < 0.75 * _radial_mm(free, HEAD_R).max()
    assert np.percentile(_radial_mm(held, HEAD_R), 90) < 0.7 * np.percentile(_radial_mm(free, HEAD_R), 90)


def test_hold_vertices_limit_the_hold_to_a_region(head_beside_arm):
    """``hold_vertices`` (the torso of a body template in :func:`reconstruct_session`): the held half keeps its
    tangent planes, the other half drifts as without the hold."""
    V, F, cams, masks = head_beside_arm
    base = dict(outer_iterations=4, inner_iterations=4, hull_gate_m=0.0)
    params = RapidSkinParams(**base, surface_hold_k=0.3, surface_hold_from=0, surface_hold_region="torso")
    free = deform_to_observations(V, F, cams, masks, RapidSkinParams(**base)).vertices
    everywhere = deform_to_observations(V, F, cams, masks, params).vertices
    nowhere = deform_to_observations(V, F, cams, masks, params, hold_vertices=np.zeros(len(V), bool)).vertices
    np.testing.assert_allclose(nowhere, free, atol=1e-12)
    far_side = V[:, 0] < 0  # away from the arm: held there, the near side free
    half = deform_to_observations(V, F, cams, masks, params, hold_vertices=far_side).vertices
    near = ~far_side & (V[:, 0] > 0.05)
    # measured: near side's median radial error 4.02 mm free, 4.02 held on the far side only, 2.50 held everywhere
    assert np.median(_radial_mm(half[near], HEAD_R)) > 0.8 * np.median(_radial_mm(free[near], HEAD_R))
    assert np.median(_radial_mm(everywhere[near], HEAD_R)) < 0.8 * np.median(_radial_mm(free[near], HEAD_R))


def test_right_matches_still_move_a_held_surface(sphere_scene):
    """The silhouettes of a sphere 5 % larger (radius 0.315 m): the held deformation (from the first iterate)
    still grows the rim towards it."""
    V, F, cams, masks = sphere_scene
    params = dict(outer_iterations=6, inner_iterations=8)
    free = deform_to_observations(V, F, cams, masks, RapidSkinParams(**params)).vertices
    held = deform_to_observations(V, F, cams, masks, RapidSkinParams(**params, surface_hold_k=0.3)).vertices
    r_free, r_held = np.linalg.norm(free, axis=1), np.linalg.norm(held, axis=1)
    # measured: median radius 0.30 -> 0.3152 m free, 0.3145 m held from the first iterate (96 % of the growth)
    assert np.median(r_held) > 0.3 + 0.85 * (np.median(r_free) - 0.3)
    assert abs(np.median(r_held) - 0.315) < 0.0015


def test_hold_constraints_are_tangent_planes_without_the_excluded_vertices():
    V, F = _sphere(0.2, subdivisions=2)
    N = area_weighted_normals(V, F)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    hold = surface_hold_constraints(V, N, 0.3, exclude=np.array([0, 5, 7]))
    assert len(hold) == len(V) - 3 and not np.isin([0, 5, 7], hold.vertex).any()
    np.testing.assert_allclose(hold.k, 0.3)
    # a vertex pushed 1 cm outwards and 1 cm sideways: the hold's solve takes the outward part back only
    i = int(hold.vertex[0])
    side = np.cross(N[i], [0.0, 0.0, 1.0] if abs(N[i, 2]) < 0.9 else [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    W = V.copy()
    W[i] += 0.01 * N[i] + 0.01 * side
    from bodystudio.geometry.laplacian import cotangent_delta_coordinates
    from bodystudio.reconstruct.solver import DepthConstraints

    delta, _ = cotangent_delta_coordinates(V, F)
    one = DepthConstraints(hold.vertex[:1], hold.point[:1], hold.normal[:1], np.array([1.0]))
    cs = ConstraintSet(delta, delta.apply(W), SilhouetteConstraints.empty(), one, k_sm=0.0)
    out = solve_constraints(W, cs, "gs", 1)
    assert abs((out[i] - V[i]) @ N[i]) < 1e-6
    assert (out[i] - V[i]) @ side == pytest.approx(0.01, abs=1e-6)


def test_hold_weight_out_of_range_is_a_one_line_error():
    with pytest.raises(InputError, match="surface_hold_k"):
        RapidSkinParams(surface_hold_k=-0.1)
    with pytest.raises(InputError, match="surface_hold_from"):
        RapidSkinParams(surface_hold_from=-1)
    with pytest.raises(InputError, match="surface_hold_region"):
        RapidSkinParams(surface_hold_region="back")
