"""Analytic checks of garment/lighting.py (§5 of Garment Replacement, Eq. 7): tiny inputs with exact answers.

Written for mutation testing (issue 17): each test runs in well under a second, needs no body model, and pins
one piece of the maths (the golden-spiral hemisphere, the Lambert matrix's clamp, NNLS on a planted sparse light
set, the albedo as the mean colour, the samples' geometry) tightly enough that a dropped term fails it.
"""

import re

import numpy as np
import pytest
import scipy.optimize

from bodystudio.errors import FileFormatError, InputError
from bodystudio.garment import lighting as lt
from bodystudio.geometry.camera import Camera


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def exact(message):
    """A ``pytest.raises(match=...)`` pattern for exactly this message."""
    return "^" + re.escape(message) + "$"


def sphere_normals(n=600, seed=0):
    return unit(np.random.default_rng(seed).normal(size=(n, 3)))


# ------------------------------------------------------------------------------------------ Lighting


def test_lighting_normalises_directions_and_keeps_colours():
    light = lt.Lighting([[0.0, 3.0, 4.0], [2.0, 0.0, 0.0]], [[1, 2, 3], [0, 0.5, 0]], [0.1, 0.2, 0.3])
    assert np.allclose(light.directions, [[0, 0.6, 0.8], [1, 0, 0]], atol=1e-15)
    assert light.colors.dtype == np.float64 and np.array_equal(light.colors, [[1, 2, 3], [0, 0.5, 0]])
    assert np.array_equal(light.ambient, [0.1, 0.2, 0.3])


NEGATIVE = "light colours and ambient must be >= 0 (a light cannot emit negative light)"


@pytest.mark.parametrize("directions, colors, ambient, phrase", [
    ([[0, 0, 1], [1, 0, 0]], [[1, 1, 1]], [0, 0, 0], "lighting needs one colour per direction, got 2 and 1"),
    ([[0, 0, 0]], [[1, 1, 1]], [0, 0, 0], "light directions must be finite non-zero vectors and colours finite"),
    ([[0, 0, 1e-13]], [[1, 1, 1]], [0, 0, 0], "light directions must be finite non-zero vectors and colours finite"),
    ([[0, np.nan, 1]], [[1, 1, 1]], [0, 0, 0], "light directions must be finite non-zero vectors and colours finite"),
    ([[0, 0, 1]], [[1, np.inf, 1]], [0, 0, 0], "light directions must be finite non-zero vectors and colours finite"),
    ([[0, 0, 1]], [[1, 1, 1]], [0, np.nan, 0], "light directions must be finite non-zero vectors and colours finite"),
    ([[0, 0, 1]], [[1, -0.1, 1]], [0, 0, 0], NEGATIVE),
    ([[0, 0, 1]], [[1, 1, 1]], [0, 0, -0.1], NEGATIVE),
])
def test_lighting_refuses_bad_lights(directions, colors, ambient, phrase):
    with pytest.raises(InputError, match=exact(phrase)):
        lt.Lighting(directions, colors, ambient)


def test_lighting_stores_float64_rows_and_a_flat_ambient():
    light = lt.Lighting([[0, 0, 2]], [[1, 2, 3]], [[1, 0, 2]])
    assert light.colors.dtype == np.float64 and light.ambient.dtype == np.float64
    assert light.directions.dtype == np.float64 and light.ambient.shape == (3,)
    assert np.array_equal(light.ambient, [1.0, 0.0, 2.0])


def test_lighting_accepts_a_tiny_but_nonzero_direction_and_zero_lights():
    light = lt.Lighting([[0, 0, 1e-11]], [[0, 0, 0]], [0, 0, 0])
    assert np.allclose(light.directions, [[0, 0, 1]])


def test_single_light_and_dict_round_trip():
    light = lt.Lighting.single([0, 2, 0], 0.7, 0.3)
    assert np.array_equal(light.directions, [[0, 1, 0]])
    assert np.array_equal(light.colors, [[0.7, 0.7, 0.7]]) and np.array_equal(light.ambient, [0.3] * 3)
    default = lt.Lighting.single([1, 0, 0])
    assert np.array_equal(default.colors, [[1.0] * 3]) and np.array_equal(default.ambient, [0.2] * 3)
    d = light.to_dict()
    assert d == {"directions": [[0.0, 1.0, 0.0]], "colors": [[0.7] * 3], "ambient": [0.3] * 3}
    back = lt.Lighting.from_dict(d)
    for name in ("directions", "colors", "ambient"):
        assert np.array_equal(getattr(back, name), getattr(light, name))


@pytest.mark.parametrize("data", [
    {"colors": [[1, 1, 1]], "ambient": [0, 0, 0]},
    {"directions": [[0, 0, 1]], "ambient": [0, 0, 0]},
    {"directions": [[0, 0, 1]], "colors": [[1, 1, 1]]},
    {"directions": [[0, 0, 1]], "colors": [[1, 1, 1]], "ambient": [0, 0]},
    {"directions": "up", "colors": [[1, 1, 1]], "ambient": [0, 0, 0]},
    {"directions": [[0, 0, 1]], "colors": [[1, 1, "x"]], "ambient": [0, 0, 0]},
    None,
])
def test_from_dict_refuses_malformed_lights_naming_the_source(data):
    pattern = (r"^gt/lighting\.json: lights need 'directions' and 'colors' \(n x 3\) and 'ambient' \(3 numbers\) "
               r"\((KeyError|TypeError|ValueError): .+\)$")
    with pytest.raises(FileFormatError, match=pattern):
        lt.Lighting.from_dict(data, "gt/lighting.json")


def test_from_dict_turns_invalid_lights_into_a_file_error():
    with pytest.raises(FileFormatError, match=r"^scene\.json: light colours and ambient must be >= 0"):
        lt.Lighting.from_dict({"directions": [[0, 0, 1]], "colors": [[-1, 0, 0]], "ambient": [0, 0, 0]},
                              "scene.json")
    with pytest.raises(FileFormatError, match=exact("lighting: light directions must be finite non-zero vectors and "
                                                    "colours finite")):
        lt.Lighting.from_dict({"directions": [[0, 0, 0]], "colors": [[1, 0, 0]], "ambient": [0, 0, 0]})


# ------------------------------------------------------------------------------------------ §5.2 hemisphere


@pytest.mark.parametrize("axis", [(0.0, 0.0, 1.0), (0.3, 0.2, 0.9), (1.0, 0.0, 0.0), (-0.95, 0.1, 0.2),
                                  (0.0, -1.0, 0.0)])
def test_golden_spiral_hemisphere_is_the_equal_area_spiral(axis):
    """§5.2: point k at cos(polar) = 1 - (k + 1/2) / n about the axis, azimuth advancing one golden angle."""
    n = 50
    a = unit(axis)
    D = lt.golden_spiral_hemisphere(n, 3.0 * np.asarray(axis))  # the axis need not be unit
    assert D.shape == (n, 3)
    assert np.allclose(np.linalg.norm(D, axis=1), 1.0, atol=1e-12)
    assert np.allclose(D @ a, 1.0 - (np.arange(n) + 0.5) / n, atol=1e-12)
    # azimuth step about the axis, right-handed: one golden angle between consecutive points
    P = D - np.outer(D @ a, a)
    step = np.arctan2(np.einsum("nd,d->n", np.cross(P[:-1], P[1:]), a), np.einsum("nd,nd->n", P[:-1], P[1:]))
    golden = np.pi * (3.0 - np.sqrt(5.0))
    assert np.allclose(np.mod(step - golden + np.pi, 2 * np.pi) - np.pi, 0.0, atol=1e-9)
    # point 0 (azimuth 0) lies along axis x helper: x unless the axis is within 26 degrees of x, then y
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = unit(np.cross(a, helper))
    c0 = 1.0 - 0.5 / n
    assert np.allclose(D[0], np.sqrt(1 - c0**2) * e1 + c0 * a, atol=1e-12)


def test_golden_spiral_starts_on_the_first_tangent_axis():
    """Point 0 has azimuth 0, i.e. lies along ``axis x helper`` (x helper unless the axis is near x)."""
    D = lt.golden_spiral_hemisphere(4, (0.0, 0.0, 1.0))
    s = np.sqrt(1.0 - 0.875**2)
    assert np.allclose(D[0], [0.0, s, 0.875], atol=1e-12)  # (0,0,1) x (1,0,0) = (0,1,0)
    D = lt.golden_spiral_hemisphere(4, (1.0, 0.0, 0.0))
    assert np.allclose(D[0], [0.875, 0.0, s], atol=1e-12)  # (1,0,0) x (0,1,0) = (0,0,1)


def test_golden_spiral_default_is_400_lights_about_z_and_needs_one():
    D = lt.golden_spiral_hemisphere()
    assert D.shape == (lt.N_LIGHTS, 3) == (400, 3)
    assert np.isclose(D[:, 2].min(), 1.0 / 800) and np.isclose(D[:, 2].max(), 1.0 - 1.0 / 800)
    assert np.allclose(lt.golden_spiral_hemisphere(1, (0, 1, 0)) @ [0, 1, 0], 0.5)
    with pytest.raises(InputError, match=exact("the light hemisphere needs at least one light, got 0")):
        lt.golden_spiral_hemisphere(0)


# ------------------------------------------------------------------------------------------ Eq. 7 matrix


def test_lambert_matrix_clamps_at_90_degrees_and_adds_the_ambient_column():
    d = unit([[0, 0, 1], [1, 0, 0], [0, 1, 1]])
    theta = np.radians([0.0, 60.0, 89.0, 90.0, 91.0, 180.0])
    normals = np.column_stack([np.zeros(6), np.sin(theta), np.cos(theta)])  # angle theta to light 0
    G = lt.lambert_light_matrix(normals, d)
    assert G.shape == (6, 4)
    want0 = np.clip(np.cos(theta), 0.0, None)
    assert np.allclose(G[:, 0], want0, atol=1e-15)
    # beyond 90 deg: no light, not negative light
    assert abs(G[3, 0]) < 1e-15 and np.all(G[4:, 0] == 0.0) and G[2, 0] > 0.017
    assert np.allclose(G[:, 1], 0.0)
    assert np.allclose(G[:, 2], np.clip(normals @ d[2], 0.0, None))
    assert np.array_equal(G[:, 3], np.ones(6))
    G0 = lt.lambert_light_matrix(normals, d, ambient=False)
    assert np.array_equal(G0, G[:, :3])


def test_lambert_matrix_multiplies_by_visibility():
    normals = unit([[0, 0, 1], [0, 1, 1]])
    d = unit([[0, 0, 1], [0, 1, 0]])
    vis = np.array([[1.0, 0.0], [0.0, 0.5]])
    G = lt.lambert_light_matrix(normals, d, vis)
    assert np.allclose(G, [[1.0, 0.0, 1.0], [0.0, 0.5 * np.sqrt(0.5), 1.0]])


# ------------------------------------------------------------------------------------------ NNLS


def test_fast_nnls_recovers_a_planted_sparse_solution_exactly():
    rng = np.random.default_rng(1)
    A = np.abs(rng.normal(size=(200, 40)))
    x0 = np.zeros(40)
    x0[[2, 11, 30]] = [0.7, 0.2, 1.3]
    b = A @ x0
    x = lt.fast_nnls(A.T @ A, A.T @ b)
    assert np.abs(x - x0).max() < 1e-10


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_fast_nnls_is_lawson_hanson_where_constraints_bind(seed):
    """Noise that the unconstrained solution answers with negative entries: the active set must drop some."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(40, 12)) + 0.5
    b = rng.normal(size=40)
    want, _ = scipy.optimize.nnls(A, b)
    assert np.linalg.lstsq(A, b, rcond=None)[0].min() < 0  # the constraint binds
    got = lt.fast_nnls(A.T @ A, A.T @ b)
    assert got.min() >= 0.0 and np.abs(got - want).max() < 1e-9


@pytest.mark.parametrize("seed", [9, 28, 36, 38])
def test_fast_nnls_backtracks_on_problems_that_need_it(seed):
    """Non-negative A and noisy b where an entering variable drives a passive one below zero (found by search:
    these seeds enter Lawson-Hanson's inner loop once; the cases above never do)."""
    rng = np.random.default_rng(seed)
    A = np.abs(rng.normal(size=(30, 8)))
    b = rng.normal(size=30) + 1
    want, _ = scipy.optimize.nnls(A, b)
    got = lt.fast_nnls(A.T @ A, A.T @ b)
    assert got.min() >= 0.0 and np.abs(got - want).max() < 1e-9


def test_fast_nnls_backtracks_when_a_passive_variable_would_go_negative():
    """A hand case where the second variable entering drives the first below zero (the inner loop)."""
    A = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]) @ np.array([[1.0, 2.0], [0.0, 1.0]])
    b = np.array([0.0, 1.0, 3.0])
    want, _ = scipy.optimize.nnls(A, b)
    got = lt.fast_nnls(A.T @ A, A.T @ b)
    assert np.abs(got - want).max() < 1e-12


def test_fast_nnls_iteration_limit_and_zero_right_hand_side():
    rng = np.random.default_rng(5)
    A = np.abs(rng.normal(size=(30, 6)))
    x0 = np.array([0.0, 1.0, 0.0, 2.0, 0.0, 0.5])
    AtA, Atb = A.T @ A, A.T @ (A @ x0)
    assert np.array_equal(lt.fast_nnls(AtA, Atb, max_iter=0), np.zeros(6))
    one = lt.fast_nnls(AtA, Atb, max_iter=1)
    assert np.count_nonzero(one) == 1 and one[np.argmax(Atb)] > 0  # the most negative gradient enters first
    assert np.array_equal(lt.fast_nnls(AtA, np.zeros(6)), np.zeros(6))
    assert np.array_equal(lt.fast_nnls(AtA, -Atb), np.zeros(6))  # every gradient points below zero


def test_fast_nnls_tolerance_is_relative_to_the_right_hand_side():
    """A variable whose gradient is below ``tol * max|A^T b|`` does not enter, whatever the scale."""
    AtA = np.eye(2)
    for scale in (1e-6, 1.0, 1e6):
        Atb = scale * np.array([1.0, 1e-11])
        assert np.allclose(lt.fast_nnls(AtA, Atb), [scale, 0.0], rtol=1e-12, atol=0)
        Atb = scale * np.array([1.0, 1e-9])
        assert np.allclose(lt.fast_nnls(AtA, Atb), [scale, scale * 1e-9], rtol=1e-12, atol=0)


def test_solve_spd_falls_back_to_least_squares_on_a_singular_matrix():
    M = np.array([[2.0, 1.0], [1.0, 2.0]])
    assert np.allclose(lt._solve_spd(M, np.array([3.0, 3.0])), [1.0, 1.0], atol=1e-14)
    S = np.array([[1.0, 1.0], [1.0, 1.0]])
    assert np.allclose(lt._solve_spd(S, np.array([2.0, 2.0])), [1.0, 1.0], atol=1e-12)


def planted_scene(n_lights=30, K=400, ambient=True, seed=0):
    axis = unit([0.2, 0.3, 1.0])
    directions = lt.golden_spiral_hemisphere(n_lights, axis)
    rng = np.random.default_rng(seed)
    normals = sphere_normals(K, seed)
    albedo = rng.uniform(0.2, 0.9, size=(K, 3))
    colors = np.zeros((n_lights, 3))
    colors[4] = [0.6, 0.5, 0.4]
    colors[9] = [0.2, 0.3, 0.1]
    amb = np.array([0.25, 0.2, 0.15]) if ambient else np.zeros(3)
    observed = albedo * (amb + np.clip(normals @ directions.T, 0, None) @ colors)
    return axis, directions, normals, albedo, colors, amb, observed


@pytest.mark.parametrize("solver", ["nnls", "fast_nnls", "lstsq"])
def test_solve_lights_recovers_planted_lights_per_channel(solver):
    """Eq. 7 with ``A_c = albedo_c * G``: each channel's planted light colours come back exactly."""
    _, directions, normals, albedo, colors, amb, observed = planted_scene(n_lights=12)
    G = lt.lambert_light_matrix(normals, directions)
    X = lt.solve_lights(G, albedo, observed, solver)
    assert X.shape == (13, 3)
    assert np.abs(X - np.vstack([colors, amb])).max() < 1e-8


def test_solve_lights_refuses_an_unknown_solver():
    with pytest.raises(InputError, match=exact("unknown lighting solver 'cg'; valid: nnls, fast_nnls, lstsq")):
        lt.solve_lights(np.ones((3, 2)), np.ones((3, 3)), np.ones((3, 3)), "cg")


def test_scipy_nnls_gets_enough_iterations_for_many_lights():
    """400 lights and a long Lawson-Hanson path: scipy's default iteration cap (3 n) is not enough here."""
    axis, _, normals, albedo, _, _, _ = planted_scene(K=1200)
    directions = lt.golden_spiral_hemisphere(400, axis)
    rng = np.random.default_rng(7)
    colors = np.zeros((400, 3))
    colors[rng.choice(400, 25, replace=False)] = rng.uniform(0.05, 0.3, size=(25, 3))
    observed = albedo * (0.1 + np.clip(normals @ directions.T, 0, None) @ colors)
    observed += 0.02 * rng.normal(size=observed.shape)
    G = lt.lambert_light_matrix(normals, directions)
    X = lt.solve_lights(G, albedo, observed, "nnls")
    Y = lt.solve_lights(G, albedo, observed, "fast_nnls")
    assert X.min() >= 0 and np.abs(X - Y).max() < 1e-6


# ------------------------------------------------------------------------------------------ estimate_lighting


@pytest.mark.parametrize("solver", ["nnls", "fast_nnls"])
def test_estimate_lighting_recovers_a_planted_sparse_light_set(solver):
    axis, directions, normals, albedo, colors, amb, observed = planted_scene()
    light = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=30, solver=solver)
    assert len(light.directions) == 2
    assert np.allclose(light.directions, directions[[4, 9]], atol=1e-12)
    assert np.abs(light.colors - colors[[4, 9]]).max() < 1e-8
    assert np.abs(light.ambient - amb).max() < 1e-8


def test_estimate_lighting_without_the_ambient_column():
    axis, directions, normals, albedo, colors, _, observed = planted_scene(ambient=False)
    light = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=30, ambient=False)
    assert np.array_equal(light.ambient, np.zeros(3))
    assert np.allclose(light.directions, directions[[4, 9]], atol=1e-12)
    assert np.abs(light.colors - colors[[4, 9]]).max() < 1e-8


def test_estimate_lighting_with_lstsq_keeps_negative_lights():
    """The unconstrained solution (kept to show why NNLS matters) may hold negative lights: they are returned."""
    axis, directions, normals, albedo, colors, amb, observed = planted_scene(n_lights=12)
    observed = observed - 0.3 * albedo * np.clip(normals @ directions[7], 0, None)[:, None]  # a "negative light"
    light = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=12, solver="lstsq")
    want = colors.copy()
    want[7] -= 0.3
    active = np.abs(want).sum(1) > 0
    assert np.allclose(light.directions, directions[active], atol=1e-12)
    assert np.abs(light.colors - want[active]).max() < 1e-8
    assert np.abs(light.ambient - amb).max() < 1e-8


def test_estimate_lighting_drops_lights_of_zero_power():
    axis, directions, normals, albedo, _, _, _ = planted_scene()
    observed = albedo * 0.4  # ambient only
    light = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=30)
    assert len(light.directions) == 0 and np.allclose(light.ambient, 0.4, atol=1e-10)


@pytest.mark.parametrize("bad, phrase", [
    ({"normals": np.ones((20, 2))}, r"^estimate_lighting: normals must be \(20, 3\), got \(20, 2\)$"),
    ({"albedo": np.ones((19, 3))}, r"^estimate_lighting: albedo must be \(20, 3\), got \(19, 3\)$"),
    ({"observed": np.ones(20)}, r"^estimate_lighting: observed must be \(20, 3\), got \(20,\)$"),
])
def test_estimate_lighting_refuses_mismatched_rows(bad, phrase):
    args = {"points": np.zeros((20, 3)), "normals": sphere_normals(20), "albedo": np.ones((20, 3)),
            "observed": np.ones((20, 3)), "view_axis": np.array([0.0, 0.0, 1.0])}
    args.update(bad)
    with pytest.raises(InputError, match=phrase):
        lt.estimate_lighting(**args)


def test_estimate_lighting_needs_ten_pixels_and_a_mesh_for_shadows():
    N = sphere_normals(10)
    assert len(lt.estimate_lighting(N, N, np.ones((10, 3)), np.full((10, 3), 0.5), [0, 0, 1], 8).ambient) == 3
    with pytest.raises(InputError, match=exact("estimate_lighting needs at least 10 body pixels, got 9; is the person "
                                               "in view?")):
        lt.estimate_lighting(N[:9], N[:9], np.ones((9, 3)), np.ones((9, 3)), [0, 0, 1])
    with pytest.raises(InputError, match=exact("estimate_lighting with shadows needs the body mesh (V, F)")):
        lt.estimate_lighting(N, N, np.ones((10, 3)), np.ones((10, 3)), [0, 0, 1], shadows=True)


def test_estimate_lighting_uses_the_view_axis_for_the_hemisphere():
    axis = unit([0.0, 1.0, 0.2])
    directions = lt.golden_spiral_hemisphere(20, axis)
    normals = sphere_normals(300)
    albedo = np.full((300, 3), 0.5)
    observed = albedo * np.clip(normals @ directions[9], 0, None)[:, None] * 0.8
    light = lt.estimate_lighting(normals, normals, albedo, observed, axis, n_lights=20)
    assert np.allclose(light.directions, directions[[9]], atol=1e-12) and np.allclose(light.colors, 0.8)


def test_dominant_light_direction_is_the_power_weighted_mean_within_the_cone():
    d = unit([[0, 0, 1], [0, np.sin(np.radians(20)), np.cos(np.radians(20))], [1, 0, 0], [0, -1, 1e-9]])
    colors = np.array([[1.0, 1.0, 1.0], [0.5, 0.5, 0.5], [0.9, 0.9, 0.9], [-5.0, -5.0, -5.0]])
    got = lt.dominant_light_direction(d, colors)
    assert np.allclose(got, unit(3 * d[0] + 1.5 * d[1]), atol=1e-12)
    # a narrower cone keeps only the brightest light; a wider one takes in the 90 deg light too (not the dark one)
    assert np.allclose(lt.dominant_light_direction(d, colors, cone_deg=19.0), d[0], atol=1e-12)
    assert np.allclose(lt.dominant_light_direction(d, colors, cone_deg=91.0), unit(3 * d[0] + 1.5 * d[1] + 2.7 * d[2]),
                       atol=1e-12)
    # exactly on the cone's edge counts as inside
    edge = unit([[0, 0, 1], [0, np.sin(np.radians(25)), np.cos(np.radians(25))]])
    assert lt.dominant_light_direction(edge, np.array([[1.0] * 3, [1.0] * 3]), cone_deg=25.0 + 1e-9)[1] > 0.1
    # colour channels summed: a red-only light outshines a dim white one
    two = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    assert np.allclose(lt.dominant_light_direction(two, np.array([[0.1, 0.1, 0.1], [0.4, 0.0, 0.0]])), [1, 0, 0])


def test_dominant_light_direction_needs_a_positive_light():
    with pytest.raises(InputError, match=exact("no light has positive intensity; the scene's lighting could not be "
                                                   "estimated")):
        lt.dominant_light_direction(np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, -1.0, 0.0]]))


# ------------------------------------------------------------------------------------------ visibility / shading


def wall():
    """A 2 x 2 m square at z = 1 facing -z (two triangles)."""
    V = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    return V, F


def test_light_visibility_is_blocked_by_the_mesh_only():
    V, F = wall()
    points = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    d = unit([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-2, 0, 1]])
    vis = lt.light_visibility(points, d, V, F)
    assert vis.shape == (3, 4) and vis.dtype == np.float64
    assert np.array_equal(vis, [[0, 1, 1, 1], [1, 1, 1, 0], [1, 0, 1, 1]])


def icosphere(subdivisions=2, radius=1.0):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


def test_vertex_shading_is_ambient_plus_clamped_lambert():
    from bodystudio.capture.render import vertex_normals_area_weighted

    V, F = icosphere()
    N = vertex_normals_area_weighted(V, F)
    light = lt.Lighting(unit([[0, 1, 0], [1, 0, 1]]), [[0.5, 0.4, 0.3], [0.2, 0.2, 0.6]], [0.1, 0.05, 0.0])
    S = lt.vertex_shading(V, F, light)
    want = light.ambient + np.clip(N @ light.directions.T, 0, None) @ light.colors
    assert np.abs(S - want).max() < 1e-12
    assert S[:, 0].min() == pytest.approx(0.1)  # the side facing away sees the ambient only


def test_vertex_shading_with_shadows_darkens_what_a_wall_hides():
    V, F = icosphere(radius=0.3)
    WV, WF = wall()
    WV = WV * [1, 1, 1] + [0, 0, 0.5]  # wall at z = 1.5, between the ball and a light at +z
    V_all = np.vstack([V, WV])
    F_all = np.vstack([F, WF + len(V)])
    light = lt.Lighting.single([0, 0, 1], 1.0, 0.2)
    lit = lt.vertex_shading(V_all, F_all, light)[: len(V)]
    shadowed = lt.vertex_shading(V_all, F_all, light, shadows=True)[: len(V)]
    front = V[:, 2] > 0.1
    assert lit[front].min() > 0.5 and np.allclose(shadowed, 0.2)
    no_lights = lt.Lighting(np.zeros((0, 3)), np.zeros((0, 3)), [0.3, 0.3, 0.3])
    assert np.allclose(lt.vertex_shading(V, F, no_lights, shadows=True), 0.3)


# ------------------------------------------------------------------------------------------ §5.1 albedo


def front_camera(size=48):
    return Camera.look_at("front", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fx=2.4 * size, width=size, height=size)


def position_image(cam, dtype=np.float64):
    """Each pixel's colour encodes where it is: (col / W, row / H, 0.5)."""
    rows, cols = np.mgrid[: cam.height, : cam.width]
    image = np.dstack([cols / cam.width, rows / cam.height, np.full(rows.shape, 0.5)])
    if dtype == np.uint8:
        return np.round(image * 255).astype(np.uint8)
    return image


def test_visible_vertex_colors_are_the_pixels_under_front_facing_unoccluded_vertices():
    from bodystudio.capture.render import vertex_normals_area_weighted

    V, F = icosphere(3, 0.5)
    cam = front_camera()
    image = position_image(cam)
    ((ids, colors),) = lt.visible_vertex_colors([image], [V], F, cam)
    uv = cam.project(V)
    N = vertex_normals_area_weighted(V, F)
    view = unit(cam.center - V)
    cos = np.einsum("nd,nd->n", N, view)
    # facing at more than acos(0.3) and not behind the rendered depth: towards the rim a vertex's rounded pixel
    # may lie on a facet more than 1 cm behind it (the ball spans 25 px), so only the well-facing ones are sure
    assert np.all(cos[ids] > 0.3) and set(np.flatnonzero(cos > 0.75)) <= set(ids)
    assert len(ids) > 0.8 * np.count_nonzero(cos > 0.3)
    col, row = np.round(uv[ids, 0]).astype(int), np.round(uv[ids, 1]).astype(int)
    assert np.array_equal(colors, image[row, col])
    assert np.all(V[ids, 2] > 0)
    # uint8 frames come back in [0, 1]
    ((ids8, colors8),) = lt.visible_vertex_colors([position_image(cam, np.uint8)], [V], F, cam)
    assert np.array_equal(ids8, ids) and np.abs(colors8 - colors).max() <= 0.5 / 255 + 1e-12
    # a stricter facing angle keeps fewer vertices
    ((strict, _),) = lt.visible_vertex_colors([image], [V], F, cam, min_cos=0.8)
    assert set(strict) < set(ids)
    assert np.all(np.einsum("nd,nd->n", N[strict], view[strict]) > 0.8)


def test_visible_vertex_colors_drop_occluded_and_off_image_vertices():
    V, F = icosphere(2, 0.3)
    cam = front_camera()
    front_ball = V + [0.0, 0.0, 1.0]  # in front: hides the back ball's centre
    back_ball = V + [0.05, 0.0, 0.0]
    side_ball = V + [5.0, 0.0, 0.0]  # outside the image
    nv = len(V)
    both = np.vstack([back_ball, front_ball, side_ball])
    F3 = np.vstack([F, F + nv, F + 2 * nv])
    ((ids, _),) = lt.visible_vertex_colors([position_image(cam)], [both], F3, cam)
    assert np.all((ids >= nv) & (ids < 2 * nv))  # only the front ball
    alone = np.vstack([back_ball, side_ball])
    ((ids2, _),) = lt.visible_vertex_colors([position_image(cam)], [alone], np.vstack([F, F + nv]), cam)
    assert len(ids2) > 30 and np.all(ids2 < nv)
    with pytest.raises(InputError, match=exact("estimate_albedo needs one posed mesh per frame, got 1 frames and 2 "
                                                   "meshes")):
        lt.visible_vertex_colors([position_image(cam)], [V, V], F, cam)
    with pytest.raises(InputError, match="got 0 frames"):
        lt.visible_vertex_colors([], [], F, cam)


def test_visible_vertex_colors_behind_the_camera_are_dropped():
    V, F = icosphere(2, 0.3)
    cam = front_camera()
    ((ids, _),) = lt.visible_vertex_colors([position_image(cam)], [V + [0, 0, 4.0]], F, cam)
    assert len(ids) == 0


def test_estimate_albedo_is_the_mean_colour_over_the_frames_that_see_a_vertex():
    V, F = icosphere(3, 0.5)
    cam = front_camera()
    dark = np.full((cam.height, cam.width, 3), 0.2)
    bright = np.full((cam.height, cam.width, 3), [0.6, 0.4, 0.8])
    turned = V @ np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=np.float64).T  # a quarter turn about y
    albedo, count = lt.estimate_albedo([dark, bright], [V, turned], F, cam)
    ((ids0, _), (ids1, _)) = lt.visible_vertex_colors([dark, bright], [V, turned], F, cam)
    assert np.array_equal(count, np.bincount(ids0, minlength=len(V)) + np.bincount(ids1, minlength=len(V)))
    both = np.intersect1d(ids0, ids1)
    only0, only1 = np.setdiff1d(ids0, ids1), np.setdiff1d(ids1, ids0)
    assert len(both) and len(only0) and len(only1)
    assert np.allclose(albedo[both], [0.4, 0.3, 0.5])
    assert np.allclose(albedo[only0], 0.2) and np.allclose(albedo[only1], [0.6, 0.4, 0.8])
    seen = count > 0
    assert not seen.all()
    assert np.allclose(albedo[~seen], albedo[seen].mean(0))  # unseen: mean of the seen
    with pytest.raises(InputError, match=exact("estimate_albedo: no body vertex is visible in any frame; check the "
                                                   "camera and poses")):
        lt.estimate_albedo([dark], [V + [0, 0, 5.0]], F, cam)


def test_surface_samples_are_points_normals_albedo_and_colour_of_body_pixels():
    V, F = icosphere(3, 0.5)
    cam = front_camera()
    image = position_image(cam, np.uint8)
    vertex_albedo = np.column_stack([V[:, 0] + 1.0, V[:, 1] + 2.0, V[:, 2] + 3.0])  # linear: interpolates exactly
    P, N, A, B = lt.surface_samples(image, V, F, cam, vertex_albedo, max_samples=10_000, erode_px=0)
    from bodystudio.capture.render import render

    mask = render(V, F, cam).mask
    assert len(P) == mask.sum()
    assert np.allclose(np.linalg.norm(P, axis=1), 0.5, atol=0.02)  # on the ball (flat facets)
    assert np.allclose(np.linalg.norm(N, axis=1), 1.0)
    assert np.all(np.einsum("kd,kd->k", N, cam.center - P) > 0)  # facing the camera
    assert np.median(np.einsum("kd,kd->k", N, unit(P))) > 0.99
    assert np.abs(A - (P + [1.0, 2.0, 3.0])).max() < 1e-6
    uv = cam.project(P)  # each sample's colour is its own pixel's
    assert np.abs(B[:, :2] - (uv + 0.5) / cam.width).max() < 1.2 / cam.width
    assert np.allclose(B[:, 2], 128 / 255)


def test_surface_samples_erode_subsample_and_mask():
    V, F = icosphere(3, 0.5)
    cam = front_camera()
    image = position_image(cam)
    albedo = np.full((len(V), 3), 0.5)
    import cv2

    from bodystudio.capture.render import render

    mask = render(V, F, cam).mask
    full = lt.surface_samples(image, V, F, cam, albedo, max_samples=10_000, erode_px=0)[0]
    eroded = lt.surface_samples(image, V, F, cam, albedo, max_samples=10_000)[0]  # erode_px 2 by default
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).sum()
    assert len(full) == mask.sum() and len(eroded) == inner
    few = lt.surface_samples(image, V, F, cam, albedo, max_samples=50, seed=1)
    assert len(few[0]) == 50
    again = lt.surface_samples(image, V, F, cam, albedo, max_samples=50, seed=1)[0]
    other = lt.surface_samples(image, V, F, cam, albedo, max_samples=50, seed=2)[0]
    assert np.array_equal(few[0], again) and not np.array_equal(few[0], other)
    left = np.zeros(mask.shape, bool)
    left[:, : cam.width // 2] = True
    P = lt.surface_samples(image, V, F, cam, albedo, max_samples=10_000, erode_px=0, pixel_mask=left)[0]
    assert len(P) == (mask & left).sum() and np.all(cam.project(P)[:, 0] < cam.width // 2 + 0.5)
    with pytest.raises(InputError, match=exact("frame is 48x40 but the camera 48x48")):
        lt.surface_samples(image[:40], V, F, cam, albedo)


def test_vertex_samples_are_the_visible_vertices_inside_the_eroded_silhouette():
    from bodystudio.capture.render import vertex_normals_area_weighted

    V, F = icosphere(3, 0.5)
    cam = front_camera()
    image = position_image(cam)
    albedo = np.random.default_rng(0).uniform(size=(len(V), 3))
    ((ids, colors),) = lt.visible_vertex_colors([image], [V], F, cam)
    P, N, A, B = lt.vertex_samples(image, V, F, cam, albedo, erode_px=0)
    order = np.argsort(ids)
    assert np.array_equal(P, V[ids]) and np.array_equal(A, albedo[ids]) and np.array_equal(B, colors)
    assert np.allclose(N, vertex_normals_area_weighted(V, F)[ids])
    assert len(order) == len(P)
    P2 = lt.vertex_samples(image, V, F, cam, albedo)[0]  # erode 2 px: the rim's vertices go
    r = np.linalg.norm(cam.project(P2) - cam.project(np.zeros((1, 3))), axis=1)
    assert 0 < len(P2) < len(P) and r.max() < np.linalg.norm(cam.project(P) - cam.project(np.zeros((1, 3))),
                                                             axis=1).max() - 1.0


def render_ball(cam, V, F, light, albedo):
    from bodystudio.garment.render import render_body

    image, _ = render_body(V, F, cam, light, albedo)
    return image


@pytest.mark.parametrize("sampling", ["pixel", "vertex"])
def test_frame_lighting_finds_the_light_of_a_rendered_ball(sampling):
    V, F = icosphere(3, 0.5)
    cam = front_camera(64)
    axis = unit(cam.center)
    directions = lt.golden_spiral_hemisphere(60, axis)
    truth = lt.Lighting(directions[[20]], [[0.8, 0.8, 0.8]], [0.2, 0.2, 0.2])
    albedo = np.full((len(V), 3), 0.6)
    image = render_ball(cam, V, F, truth, albedo)
    est = lt.frame_lighting(image, V, F, cam, albedo, n_lights=60, sampling=sampling)
    d = lt.dominant_light_direction(est.directions, est.colors)
    assert np.degrees(np.arccos(np.clip(d @ directions[20], -1, 1))) < 3.0
    # the fitted lights reproduce the irradiance on the sample normals (ambient and a spread of lights trade off
    # on a ball seen from one side, so the split between them is not pinned)
    N = lt.surface_samples(image, V, F, cam, albedo)[1]
    true = 0.2 + 0.8 * np.clip(N @ directions[20], 0, None)
    fit = est.ambient[0] + np.clip(N @ est.directions.T, 0, None) @ est.colors[:, 0]
    assert np.median(np.abs(fit - true) / true) < (0.01 if sampling == "pixel" else 0.05)
    with pytest.raises(InputError, match=exact("unknown lighting sampling 'texel'; valid: pixel, vertex")):
        lt.frame_lighting(image, V, F, cam, albedo, sampling="texel")


def albedo_round(observations, meshes, F, lights, mean_colour, count):
    """One albedo round written out: per vertex ``sum I S / sum S^2`` over the frames that see it (S the
    shading of that frame's lights), rescaled to the mean colour's mean and clipped at 0; unseen vertices keep
    the mean colour."""
    num, den = np.zeros_like(mean_colour), np.zeros_like(mean_colour)
    for (ids, colors), Vt, lw in zip(observations, meshes, lights, strict=True):
        S = lt.vertex_shading(Vt, F, lw)[ids]
        num[ids] += colors * S
        den[ids] += S * S
    seen = count > 0
    want = mean_colour.copy()
    want[seen] = num[seen] / den[seen]
    return np.clip(want * mean_colour[seen].mean(0) / want[seen].mean(0), 0, None)


def test_alternating_albedo_is_the_least_squares_ratio_to_each_frames_shading():
    """Our §5.1 extension, one round written out: lights per frame (Eq. 7) with the mean colour, then per vertex
    ``a = sum_t I S / sum_t S^2`` over the frames that see it, rescaled to the mean colour's mean, clipped at 0."""
    V, F = icosphere(3, 0.5)
    cam = front_camera(64)
    light = lt.Lighting.single(unit([0.6, 0.3, 1.0]), 0.8, 0.2)
    albedo = np.where(V[:, 1:2] > 0, [0.8, 0.5, 0.4], [0.3, 0.5, 0.7])
    frames, meshes = [], []
    for yaw in np.linspace(-0.6, 0.6, 3):
        c, s = np.cos(yaw), np.sin(yaw)
        Vt = V @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
        frames.append(render_ball(cam, Vt, F, light, albedo))
        meshes.append(Vt)
    mean_colour, count = lt.estimate_albedo(frames, meshes, F, cam)
    unchanged, none = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=0)
    assert np.array_equal(unchanged, mean_colour) and none == []
    refined, lights = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=1, n_lights=60)
    want_lights = [lt.frame_lighting(f, Vt, F, cam, mean_colour, n_lights=60)
                   for f, Vt in zip(frames, meshes, strict=True)]
    assert len(lights) == 3
    for got, want in zip(lights, want_lights, strict=True):
        assert np.array_equal(got.directions, want.directions) and np.allclose(got.colors, want.colors)
    want = albedo_round(lt.visible_vertex_colors(frames, meshes, F, cam), meshes, F, want_lights, mean_colour, count)
    assert np.abs(refined - want).max() < 1e-9
    assert not np.allclose(refined, mean_colour, atol=0.01)  # the round changed something
    # a second round starts from the first's albedo
    two, _ = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=2, n_lights=60)
    assert not np.allclose(two, refined, atol=1e-6)


# ------------------------------------------------------------------------------------------ options passed on


def test_from_dict_reads_several_lights_and_refuses_rows_of_four():
    two = lt.Lighting([[0, 0, 1], [0, 1, 0]], [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], [0.1, 0.1, 0.1])
    back = lt.Lighting.from_dict(two.to_dict())
    assert np.array_equal(back.directions, two.directions) and np.array_equal(back.colors, two.colors)
    flat = lt.Lighting.from_dict({"directions": [0, 0, 2, 0, 3, 0], "colors": [1, 1, 1, 2, 2, 2], "ambient": [0, 0, 0]})
    assert np.array_equal(flat.directions, [[0, 0, 1], [0, 1, 0]]) and np.array_equal(flat.colors[1], [2, 2, 2])
    for key in ("directions", "colors", "ambient"):
        data = two.to_dict()
        data[key] = [[1, 2, 3, 4]]
        with pytest.raises(FileFormatError, match=r"^src: lights need .* \(ValueError: "):
            lt.Lighting.from_dict(data, "src")
        data[key] = [["x", "y", "z"]] * (1 if key == "ambient" else 2)
        with pytest.raises(FileFormatError, match=r"^src: lights need .* \(ValueError: could not convert"):
            lt.Lighting.from_dict(data, "src")


def test_dominant_light_default_cone_is_25_degrees_inclusive():
    near = unit([[0, 0, 1], [0, np.sin(np.radians(24.5)), np.cos(np.radians(24.5))],
                 [np.sin(np.radians(25.5)), 0, np.cos(np.radians(25.5))]])
    colors = np.array([[1.0] * 3, [0.5] * 3, [0.5] * 3])
    assert np.allclose(lt.dominant_light_direction(near, colors), unit(near[0] + 0.5 * near[1]), atol=1e-12)
    # a zero cone keeps the brightest light and any light in exactly its direction
    same = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    got = lt.dominant_light_direction(same, np.array([[1.0] * 3, [0.2] * 3, [0.9] * 3]), cone_deg=0.0)
    assert np.array_equal(got, [0.0, 0.0, 1.0])


def ball_behind_a_wall():
    """A ball lit from +x through a wall at x = 1.5 (outside the view): self-shadowing changes everything."""
    V, F = icosphere(3, 0.5)
    WV = np.array([[1.5, -1.0, -1.0], [1.5, 1.0, -1.0], [1.5, 1.0, 1.0], [1.5, -1.0, 1.0]])
    return np.vstack([V, WV]), np.vstack([F, np.array([[0, 1, 2], [0, 2, 3]]) + len(V)]), len(V)


def test_alternating_albedo_passes_on_min_cos_shadows_masks_and_the_default_of_three_rounds():
    V, F, nb = ball_behind_a_wall()
    cam = front_camera(64)
    light = lt.Lighting(unit([[1.0, 0.2, 0.4], [0.0, 0.3, 1.0]]), [[0.8] * 3, [0.3] * 3], [0.2] * 3)
    albedo = np.where(V[:, 1:2] > 0, [0.8, 0.5, 0.4], [0.3, 0.5, 0.7])
    frames, meshes = [], []
    for yaw in (-0.3, 0.3):
        c, s = np.cos(yaw), np.sin(yaw)
        Vt = V.copy()
        Vt[:nb] = V[:nb] @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
        frames.append(render_ball(cam, Vt, F, light, albedo))
        meshes.append(Vt)
    # min_cos reaches the mean colour and the observations
    a0, _ = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=0, min_cos=0.7)
    assert np.array_equal(a0, lt.estimate_albedo(frames, meshes, F, cam, 0.7)[0])
    a1, l1 = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=1, min_cos=0.7, n_lights=40)
    a1d, l1d = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=1, n_lights=40)
    assert not np.allclose(a1, a1d)
    mean_colour, count = lt.estimate_albedo(frames, meshes, F, cam, 0.7)
    assert np.array_equal(a0, mean_colour)
    want = albedo_round(lt.visible_vertex_colors(frames, meshes, F, cam, 0.7), meshes, F, l1, mean_colour, count)
    assert np.abs(a1 - want).max() < 1e-9
    # no shadows by default (the wall shadows the ball's right side)
    a1n, l1n = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=1, n_lights=40, shadows=False)
    assert np.array_equal(a1n, a1d) and np.array_equal(l1n[0].directions, l1d[0].directions)
    a1s, _ = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=1, n_lights=40, shadows=True)
    assert np.abs(a1s - a1d).max() > 0.01
    # shadows reach both the lights and the shading; masks reach the lights
    left = [np.zeros((64, 64), bool) for _ in frames]
    for m in left:
        m[:, :34] = True
    a_s, l_s = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=1, shadows=True, pixel_masks=left,
                                               n_lights=40)
    mean_colour, count = lt.estimate_albedo(frames, meshes, F, cam)
    want_lights = [lt.frame_lighting(f, Vt, F, cam, mean_colour, n_lights=40, shadows=True, pixel_mask=m)
                   for f, Vt, m in zip(frames, meshes, left, strict=True)]
    for got, want in zip(l_s, want_lights, strict=True):
        assert np.array_equal(got.directions, want.directions) and np.allclose(got.colors, want.colors)
    num, den = np.zeros_like(mean_colour), np.zeros_like(mean_colour)
    for (ids, colors), Vt, lw in zip(lt.visible_vertex_colors(frames, meshes, F, cam), meshes, want_lights,
                                     strict=True):
        S = lt.vertex_shading(Vt, F, lw, shadows=True)[ids]
        num[ids] += colors * S
        den[ids] += S * S
    seen = count > 0
    want = mean_colour.copy()
    ok = seen & np.all(den > 1e-12, axis=1)
    want[ok] = num[ok] / den[ok]
    want = np.clip(want * mean_colour[seen].mean(0) / want[seen].mean(0), 0, None)
    assert np.abs(a_s - want).max() < 1e-9
    # three rounds by default
    a3, l3 = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=3, n_lights=40)
    ad, ld = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, n_lights=40)
    a2, _ = lt.estimate_albedo_and_lighting(frames, meshes, F, cam, iterations=2, n_lights=40)
    assert np.array_equal(ad, a3) and not np.allclose(ad, a2, atol=1e-9)


def test_vertex_samples_pass_on_min_cos_and_erode_by_a_square_of_two_erode_px_plus_one():
    import cv2

    from bodystudio.capture.render import render

    V, F = icosphere(3, 0.5)
    cam = front_camera(64)
    image = position_image(cam)
    albedo = np.full((len(V), 3), 0.5)
    ((ids, _),) = lt.visible_vertex_colors([image], [V], F, cam, 0.6)
    assert len(lt.vertex_samples(image, V, F, cam, albedo, min_cos=0.6, erode_px=0)[0]) == len(ids)
    mask = render(V, F, cam).mask.astype(np.uint8)
    ((ids, _),) = lt.visible_vertex_colors([image], [V], F, cam)
    uv = np.round(cam.project(V[ids])).astype(int)
    for erode_px in (1, 2, 3):
        inner = cv2.erode(mask, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)) > 0
        want = V[ids[inner[uv[:, 1], uv[:, 0]]]]
        got = lt.vertex_samples(image, V, F, cam, albedo, erode_px=erode_px)[0]
        assert np.array_equal(got, want), erode_px
        if erode_px == 2:
            assert np.array_equal(lt.vertex_samples(image, V, F, cam, albedo)[0], want)
    assert len(lt.vertex_samples(image, V, F, cam, albedo, erode_px=1)[0]) > len(got)  # erode_px 3: fewer


def test_estimate_albedo_passes_on_min_cos_and_needs_frames():
    V, F = icosphere(3, 0.5)
    cam = front_camera()
    frame = np.full((cam.height, cam.width, 3), 0.4)
    _, count = lt.estimate_albedo([frame], [V], F, cam, min_cos=0.8)
    ((ids, _),) = lt.visible_vertex_colors([frame], [V], F, cam, 0.8)
    assert np.array_equal(np.flatnonzero(count), np.sort(ids))
    with pytest.raises(InputError, match=exact("estimate_albedo needs one posed mesh per frame, got 0 frames and 0 "
                                               "meshes")):
        lt.estimate_albedo([], [], F, cam)


def test_frame_lighting_is_eq_7_on_the_frames_samples_with_its_defaults():
    """4000 pixel rows drawn with seed 0, the hemisphere about the body-to-camera axis, no shadows, ambient on."""
    V, F, nb = ball_behind_a_wall()
    cam = Camera.look_at("front", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fx=330.0, width=128, height=128)
    light = lt.Lighting(unit([[1.0, 0.2, 0.4], [0.0, 0.3, 1.0]]), [[0.8] * 3, [0.3] * 3], [0.2] * 3)
    albedo = np.where(V[:, 1:2] > 0, [0.8, 0.5, 0.4], [0.3, 0.5, 0.7])
    image = render_ball(cam, V, F, light, albedo)
    axis = unit(cam.center - V.mean(0))

    def written_out(samples=4000, seed=0, mask=None, **kw):
        rows = lt.surface_samples(image, V, F, cam, albedo, samples, seed=seed, pixel_mask=mask)
        assert len(rows[0]) == min(samples, 6000)
        return lt.estimate_lighting(*rows, axis, 60, mesh=(V, F), **kw)

    def same(a, b):
        return np.array_equal(a.directions, b.directions) and np.allclose(a.colors, b.colors, atol=1e-12) and \
            np.allclose(a.ambient, b.ambient, atol=1e-12)

    from bodystudio.capture.render import render

    assert render(V, F, cam).mask.sum() > 6000
    assert same(lt.frame_lighting(image, V, F, cam, albedo, n_lights=60), written_out())
    assert not same(written_out(), written_out(samples=4001)) and not same(written_out(), written_out(seed=1))
    assert same(lt.frame_lighting(image, V, F, cam, albedo, n_lights=60, max_samples=500, seed=3),
                written_out(500, 3))
    left = np.zeros((128, 128), bool)
    left[:, :60] = True
    got = lt.frame_lighting(image, V, F, cam, albedo, n_lights=60, max_samples=10_000, pixel_mask=left)
    rows = lt.surface_samples(image, V, F, cam, albedo, 10_000, pixel_mask=left)
    assert same(got, lt.estimate_lighting(*rows, axis, 60))
    shadowed = lt.frame_lighting(image, V, F, cam, albedo, n_lights=60, shadows=True)
    assert same(shadowed, written_out(shadows=True)) and not same(shadowed, written_out())
    flat = lt.frame_lighting(image, V, F, cam, albedo, n_lights=60, ambient=False, solver="nnls")
    assert same(flat, written_out(ambient=False, solver="nnls")) and np.array_equal(flat.ambient, np.zeros(3))
    # 60 lights on the hemisphere can stand in for the ambient on a ball seen from one side; 8 cannot
    coarse = lt.frame_lighting(image, V, F, cam, albedo, n_lights=8, ambient=False)
    assert np.array_equal(coarse.ambient, np.zeros(3))
    assert lt.frame_lighting(image, V, F, cam, albedo, n_lights=8).ambient[0] > 0.05


def test_self_shadowing_of_a_lone_convex_ball_changes_nothing():
    """Shadow rays start 2 mm off the surface, outwards: a convex mesh never blocks its own lit side."""
    V, F = icosphere(3, 0.5)
    light = lt.Lighting(unit([[0.3, 0.5, 1.0], [-1.0, 0.2, 0.0]]), [[0.6] * 3, [0.3] * 3], [0.1] * 3)
    assert np.abs(lt.vertex_shading(V, F, light, shadows=True) - lt.vertex_shading(V, F, light)).max() < 1e-12


def test_visible_vertex_colors_reach_every_image_border_and_near_surfaces():
    """A grid with one vertex per pixel centre, one pixel beyond the image on each side: exactly the in-image
    vertices are seen, including column and row 0 and the last ones; a surface 0.3 m from the camera is seen."""
    W = H = 8
    cam = Camera.look_at("c", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fx=30.0, width=W, height=H)
    k = np.arange(-1, 9)
    u, v = np.meshgrid(k, k)
    grid = np.column_stack([(u.ravel() - 3.5) * 0.1, -(v.ravel() - 3.5) * 0.1, np.zeros(u.size)])
    idx = np.arange(u.size).reshape(u.shape)
    quads = [(idx[i, j], idx[i, j + 1], idx[i + 1, j + 1], idx[i + 1, j]) for i in range(9) for j in range(9)]
    F = np.array([t for a, b, c, d in quads for t in ((a, c, b), (a, d, c))])  # facing the camera
    assert np.allclose(cam.project(grid), np.column_stack([u.ravel(), v.ravel()]), atol=1e-9)
    image = position_image(cam)
    ((ids, colors),) = lt.visible_vertex_colors([image], [grid], F, cam, min_cos=0.0)
    seen = {(int(u.ravel()[i]), int(v.ravel()[i])) for i in ids}
    assert seen == {(c, r) for c in range(W) for r in range(H)}
    # near the camera (depth 0.5 m to 0.7 m): still seen
    Vb, Fb = icosphere(3, 0.1)
    near = front_camera()
    ((ids, _),) = lt.visible_vertex_colors([position_image(near)], [Vb + [0, 0, 2.4]], Fb, near)
    assert len(ids) > 100 and near.world_to_camera(Vb[ids] + [0, 0, 2.4])[:, 2].max() < 1.0


def test_estimate_lighting_with_shadows_casts_from_2_mm_off_the_surface():
    """The visibility of Eq. 7's matrix written out: rays from each sample 2 mm along its normal, against the mesh."""
    V, F, nb = ball_behind_a_wall()
    V = V.copy()
    V[nb:, 0] = 0.8  # the wall 0.3 m from the ball's right side
    rng = np.random.default_rng(0)
    pick = rng.choice(nb, 300, replace=False)
    from bodystudio.capture.render import vertex_normals_area_weighted

    N = vertex_normals_area_weighted(V[:nb], F[: len(F) - 2])[pick]
    P = V[pick]
    albedo = np.full((300, 3), 0.5)
    directions = lt.golden_spiral_hemisphere(30, [0.0, 0.0, 1.0])
    truth = np.zeros((30, 3))
    truth[[3, 11, 22]] = [[0.5] * 3, [0.3] * 3, [0.2] * 3]
    vis = lt.light_visibility(P + 2e-3 * N, directions, V, F)
    assert 0 < vis.mean() < 1
    observed = albedo * (0.1 + (np.clip(N @ directions.T, 0, None) * vis) @ truth)
    got = lt.estimate_lighting(P, N, albedo, observed, [0.0, 0.0, 1.0], 30, shadows=True, mesh=(V, F))
    G = lt.lambert_light_matrix(N, directions, vis)
    X = lt.solve_lights(G, albedo, observed)  # fast_nnls by default
    active = X[:-1].sum(1) > 1e-9
    assert np.array_equal(got.directions, directions[active]) and np.allclose(got.colors, X[:-1][active])
    assert np.allclose(got.colors, truth[[3, 11, 22]], atol=1e-6)


def test_surface_samples_defaults_turn_normals_to_the_camera_and_draw_without_repeats():
    from bodystudio.capture.render import render

    V, F = icosphere(3, 0.5)
    cam = Camera.look_at("front", (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), fx=330.0, width=128, height=128)
    image = position_image(cam)
    albedo = np.full((len(V), 3), 0.5)
    n_px = render(V, F, cam).mask.sum()
    assert n_px > 5000
    default = lt.surface_samples(image, V, F, cam, albedo)
    assert len(default[0]) == 4000
    assert np.array_equal(default[0], lt.surface_samples(image, V, F, cam, albedo, 4000, 2, 0)[0])
    # inside-out faces: the normals still face the camera
    inverted = lt.surface_samples(image, V, F[:, ::-1], cam, albedo, 10_000, 0)[1]
    outward = lt.surface_samples(image, V, F, cam, albedo, 10_000, 0)[1]
    assert np.allclose(inverted, outward, atol=1e-12)
    # a draw of all but one pixel repeats none
    P = lt.surface_samples(image, V, F, cam, albedo, n_px - 1, 0)[0]
    assert len(np.unique(P, axis=0)) == n_px - 1
    # erode_px 1 is a 3x3 erosion
    import cv2

    inner = cv2.erode(render(V, F, cam).mask.astype(np.uint8), np.ones((3, 3), np.uint8)).sum()
    assert len(lt.surface_samples(image, V, F, cam, albedo, 10_000, 1)[0]) == inner


def test_shadow_rays_of_a_floor_under_a_roof():
    """Normals exactly along y (a floor): the rays start 2 mm up, the roof blocks the steep lights only."""
    roof = np.array([[-1.0, 1.0, -1.0], [1.0, 1.0, -1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    rng = np.random.default_rng(1)
    P = np.column_stack([rng.uniform(-0.3, 0.3, 40), np.zeros(40), rng.uniform(-0.3, 0.3, 40)])
    N = np.tile([0.0, 1.0, 0.0], (40, 1))
    directions = lt.golden_spiral_hemisphere(20, [0.0, 1.0, 0.0])
    vis = lt.light_visibility(P + 2e-3 * N, directions, roof, F)
    assert vis[:, 0].max() == 0 and vis[:, -1].min() == 1  # the zenith light blocked, the horizon one not
    albedo = np.full((40, 3), 0.5)
    G = np.clip(N @ directions.T, 0, None) * vis
    partly = np.flatnonzero((vis.min(0) == 0) & (vis.max(0) == 1))  # lights the roof hides from some points only
    assert len(partly) >= 2
    truth = np.zeros(20)
    truth[partly[:2]] = [0.6, 0.4]
    observed = albedo * (0.1 + G @ truth)[:, None]
    got = lt.estimate_lighting(P, N, albedo, observed, [0.0, 1.0, 0.0], 20, shadows=True, mesh=(roof, F))
    X = lt.solve_lights(lt.lambert_light_matrix(N, directions, vis), albedo, observed, "fast_nnls")
    active = X[:-1].sum(1) > 1e-9
    assert np.array_equal(got.directions, directions[active]) and np.allclose(got.colors, X[:-1][active])
    unshadowed = lt.estimate_lighting(P, N, albedo, observed, [0.0, 1.0, 0.0], 20)
    assert not (np.array_equal(got.directions, unshadowed.directions) and np.allclose(got.colors, unshadowed.colors))
