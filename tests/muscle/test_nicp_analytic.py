"""Analytic tests of the non-rigid ICP of Sec. 5 of Arm-Muscle Capture (muscle/nicp.py) on small meshes.

Each test checks what the maths fixes exactly: Umeyama's similarity of exact pairs, the rigid alignment of a
copy of the template, each Sec. 5.2 filter on a hand-built case with its threshold on both sides, the
cotangent ARAP operators (Sorkine & Alexa 2007) and their local step, and non-rigid ICP converging to a target
whose correspondences are known (issue 17: planted bugs must fail a fast test).
"""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from bodystudio.errors import InputError
from bodystudio.geometry.mesh import vertex_normals
from bodystudio.muscle import nicp
from bodystudio.muscle.nicp import CorrespondenceFilters, Correspondences


def _grid(n: int = 6, size: float = 0.1):
    """A flat n x n vertex grid in the z = 0 plane, normals +z, triangles split along the same diagonal."""
    x, y = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    V = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    F = []
    for r in range(n - 1):
        for c in range(n - 1):
            a = r * n + c
            F += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return V, np.array(F)


def _ellipsoid(n_lat: int = 10, n_lon: int = 16, radii=(0.05, 0.03, 0.12)):
    """A closed, asymmetric (three radii) UV ellipsoid: a rigid alignment of it is unique."""
    verts = [[0.0, 0.0, radii[2]]]
    for i in range(1, n_lat):
        th = np.pi * i / n_lat
        for j in range(n_lon):
            ph = 2 * np.pi * j / n_lon
            verts.append([radii[0] * np.sin(th) * np.cos(ph), radii[1] * np.sin(th) * np.sin(ph),
                          radii[2] * np.cos(th)])
    verts.append([0.0, 0.0, -radii[2]])
    V = np.array(verts)
    F = [[0, 1 + j, 1 + (j + 1) % n_lon] for j in range(n_lon)]
    for i in range(n_lat - 2):
        for j in range(n_lon):
            a, b = 1 + i * n_lon + j, 1 + i * n_lon + (j + 1) % n_lon
            F += [[a, a + n_lon, b], [b, a + n_lon, b + n_lon]]
    last = len(V) - 1
    F += [[last, 1 + (n_lat - 2) * n_lon + (j + 1) % n_lon, 1 + (n_lat - 2) * n_lon + j] for j in range(n_lon)]
    V = V + np.array([0.1, 0.0, 0.0])  # off the origin: rotation and translation do not commute
    return V, np.array(F)


def test_ellipsoid_normals_point_outwards():
    V, F = _ellipsoid()
    N = vertex_normals(V, F)
    assert np.all(np.einsum("kd,kd->k", N, V - V.mean(0)) > 0)


# --- Sec. 5.1 ------------------------------------------------------------------------------------------

def test_weighted_similarity_ignores_zero_weight_outliers_and_keeps_a_proper_rotation():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(40, 3))
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    B = 0.9 * A @ R.T + [0.1, 0.2, -0.3]
    B[:5] += rng.normal(0, 1.0, (5, 3))  # outliers
    w = np.r_[np.zeros(5), np.full(35, 2.0)]
    s, R2, t = nicp.similarity_transform(A, B, w)
    assert s == pytest.approx(0.9, abs=1e-12)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t, [0.1, 0.2, -0.3], atol=1e-12)
    assert nicp.similarity_transform(A, B)[0] != pytest.approx(0.9, abs=1e-3)  # the outliers do count unweighted
    s, R2, t = nicp.similarity_transform(A[5:], B[5:], with_scale=False)
    assert s == 1.0 and np.allclose(R2, R, atol=1e-12)
    # A mirror image: the best proper rotation (det +1), never a reflection.
    s, R2, _ = nicp.similarity_transform(A, A * [1, 1, -1])
    assert np.linalg.det(R2) == pytest.approx(1.0)
    # A single point (no spread): scale 1, the translation that maps it.
    s, R2, t = nicp.similarity_transform(np.ones((3, 3)), np.full((3, 3), 2.0))
    assert s == 1.0 and np.allclose(R2 @ np.ones(3) + t, 2.0)


def test_apply_similarity_is_s_R_p_plus_t():
    R = Rotation.from_rotvec([0.0, 0.0, np.pi / 2]).as_matrix()
    out = nicp.apply_similarity((2.0, R, np.array([1.0, 0.0, 0.0])), [[1, 0, 0], [0, 1, 0]])
    np.testing.assert_allclose(out, [[1, 2, 0], [-1, 0, 0]], atol=1e-12)


@pytest.fixture(scope="module")
def ellipsoid():
    return _ellipsoid()


@pytest.mark.parametrize("true, kw, want", [
    # A small similarity recovered exactly from the centroid start (coarse mode).
    ((1.05, [0.05, -0.04, 0.08], [0.004, -0.003, 0.006]), {}, None),
    # Scale clipped to the range: the similarity with the largest allowed scale.
    ((1.25, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), {"scale_range": (0.85, 1.15)}, 1.15),
    # Without scale: a rigid motion is recovered exactly.
    ((1.0, [0.03, 0.02, -0.05], [0.01, 0.0, -0.01]), {"with_scale": False}, None),
])
def test_rigid_alignment_recovers_a_similarity_of_the_template(ellipsoid, true, kw, want):
    V, F = ellipsoid
    s, rotvec, t = true
    R = Rotation.from_rotvec(rotvec).as_matrix()
    c = V.mean(0)
    P = s * (V - c) @ R.T + c + t  # a copy of the template, moved about its centre
    sensor = c + np.array([0.0, 0.0, 1.0])
    seen = np.einsum("kd,kd->k", vertex_normals(P, F), sensor - P) > 0  # a depth camera sees one side
    S = nicp.rigid_alignment_with_scale(V, F, P[seen], sensor, **kw)
    if want is None:
        np.testing.assert_allclose(nicp.apply_similarity(S, V), P, atol=1e-7)
    else:
        assert S[0] == pytest.approx(want, abs=1e-9)


def test_rigid_alignment_from_a_given_start_with_translation_only(ellipsoid):
    V, F = ellipsoid
    shift = np.array([0.004, -0.006, 0.005])
    sensor = V.mean(0) + np.array([0.0, 0.0, 1.0])
    start = (1.0, np.eye(3), np.zeros(3))
    S = nicp.rigid_alignment_with_scale(V, F, V + shift, sensor, initial=start, with_rotation=False)
    assert S[0] == 1.0 and np.allclose(S[1], np.eye(3))
    np.testing.assert_allclose(S[2], shift, atol=1e-9)
    # One iteration is not enough to go the whole way from a far start; thirty are.
    far = np.array([0.012, -0.01, 0.008])
    one = nicp.rigid_alignment_with_scale(V, F, V + far, sensor, initial=start, iterations=1, with_scale=False)
    full = nicp.rigid_alignment_with_scale(V, F, V + far, sensor, initial=start, with_scale=False)
    np.testing.assert_allclose(full[2], far, atol=1e-7)
    assert np.linalg.norm(one[2] - far) > 1e-4


def test_rigid_alignment_uses_only_the_masked_sensor_facing_vertices(ellipsoid):
    V, F = ellipsoid
    sensor = V.mean(0) + np.array([0.0, 0.0, 1.0])
    # The cloud: the front half only, with its far side moved 5 cm away (never paired from the front).
    front = vertex_normals(V, F) @ [0, 0, 1] > 0
    P = V[front] + [0.003, 0.0, 0.0]
    S = nicp.rigid_alignment_with_scale(V, F, P, sensor, initial=(1.0, np.eye(3), np.zeros(3)), with_scale=False,
                                        with_rotation=False)
    np.testing.assert_allclose(S[2], [0.003, 0.0, 0.0], atol=1e-9)
    # Masking out every front vertex but nine leaves fewer than 10 pairs.
    mask = np.zeros(len(V), bool)
    mask[np.flatnonzero(front)[:9]] = True
    with pytest.raises(InputError, match="fewer than 10 template-to-depth pairs"):
        nicp.rigid_alignment_with_scale(V, F, P, sensor, mask, initial=(1.0, np.eye(3), np.zeros(3)))
    with pytest.raises(InputError, match="needs a point cloud, got 9 points"):
        nicp.rigid_alignment_with_scale(V, F, P[:9], sensor)


def test_pairs_beyond_max_distance_are_not_used(ellipsoid):
    """A far outlier cluster next to the data: only pairs within max_distance pull the template."""
    V, F = ellipsoid
    sensor = V.mean(0) + np.array([0.0, 0.0, 1.0])
    P = np.r_[V + [0.002, 0.0, 0.0], V + [0.0, 0.0, 0.2]]
    S = nicp.rigid_alignment_with_scale(V, F, P, sensor, initial=(1.0, np.eye(3), np.zeros(3)), with_scale=False,
                                        max_distance_m=0.01)
    np.testing.assert_allclose(S[2], [0.002, 0.0, 0.0], atol=1e-7)


# --- Sec. 5.2 ------------------------------------------------------------------------------------------

def test_two_ring_neighbourhoods_of_a_grid():
    V, F = _grid(4)
    A1 = nicp.vertex_neighbourhoods(F, 16, rings=1)
    A2 = nicp.vertex_neighbourhoods(F, 16)
    assert A1.dtype == bool and A2.dtype == bool
    assert set(A1[5].indices) == {0, 1, 4, 6, 9, 10}  # the 1-ring of an interior vertex on this diagonal split
    assert set(A2[0].indices) == {1, 2, 4, 5, 6, 8, 9, 10}
    assert A2.diagonal().sum() == 0 and (A2 != A2.T).nnz == 0


def test_neighbour_medians_over_valid_neighbours():
    adj = sp.csr_matrix(np.array([[0, 1, 1, 1], [1, 0, 0, 0], [1, 0, 0, 1], [1, 0, 1, 0]], bool))
    values = np.array([10.0, 1.0, 2.0, 7.0])
    med = nicp._neighbour_medians(adj, values, np.array([True, True, True, False]))
    np.testing.assert_allclose(med, [1.5, 10.0, 10.0, 6.0])
    assert np.isnan(nicp._neighbour_medians(adj, values, np.array([False, True, True, True]))[1])
    # Angles: vertex 0's vector is orthogonal to 1's and parallel to 2's and 3's.
    vec = np.array([[1.0, 0, 0], [0, 2.0, 0], [3.0, 0, 0], [1.0, 1.0, 0]])
    ang = nicp._neighbour_angle_medians(adj, vec, np.ones(4, bool))
    np.testing.assert_allclose(ang, [np.pi / 4, np.pi / 2, np.pi / 8, np.pi / 4], atol=1e-12)


def _flat_case(n=6):
    """The grid, a sensor 1 m above it, each vertex paired with the point 5 mm above it (normals +z)."""
    V, F = _grid(n)
    N = vertex_normals(V, F)
    targets = V + [0.0, 0.0, 0.005]
    pairs = Correspondences(targets, np.tile([0.0, 0.0, 1.0], (len(V), 1)), np.arange(len(V)), np.ones(len(V), bool))
    return V, F, N, pairs, np.array([0.05, 0.05, 1.0]), nicp.vertex_neighbourhoods(F, len(V))


ALL_OFF = dict(arm_only=False, front_only=False, normals=False, neighbours=False, length=False, duplicates=False)


def _only(name, **kw):
    return CorrespondenceFilters(**{**ALL_OFF, name: True, **kw})


def test_clean_pairs_pass_every_filter():
    V, F, N, pairs, sensor, adj = _flat_case()
    out = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj)
    assert out.kept.all() and set(out.rejected_by.values()) == {0}
    assert list(out.rejected_by) == ["arm_only", "front_only", "normals", "neighbours", "length", "duplicates"]
    assert out.targets is pairs.targets and out.kept is not pairs.kept


def test_arm_only_and_front_only_filters():
    V, F, N, pairs, sensor, adj = _flat_case()
    arm = np.arange(len(V)) % 3 != 0
    out = nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, _only("arm_only"))
    np.testing.assert_array_equal(out.kept, arm)
    assert out.rejected_by == {"arm_only": int((~arm).sum()), "max_distance": 0}
    # Eq. 1: seen from below the grid, no vertex faces the sensor.
    below = nicp.filter_correspondences(V, N, pairs, [0.05, 0.05, -1.0], arm, adj, _only("front_only"))
    assert not below.kept.any() and below.rejected_by["front_only"] == len(V)
    above = nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, _only("front_only"))
    assert above.kept.all()


@pytest.mark.parametrize("angle_deg, kept", [(44.0, True), (46.0, False)])
def test_normals_filter_at_its_threshold(angle_deg, kept):
    V, F, N, pairs, sensor, adj = _flat_case()
    a = np.radians(angle_deg)
    pairs.target_normals[7] = [np.sin(a), 0.0, np.cos(a)]
    out = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("normals"))
    assert out.kept[7] == kept and out.kept.sum() == len(V) - (not kept)
    narrow = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj,
                                         _only("normals", T_N_deg=angle_deg - 1.0))
    assert not narrow.kept[7]


def test_neighbours_filter_drops_a_pair_whose_direction_disagrees():
    V, F, N, pairs, sensor, adj = _flat_case(7)
    i = 24  # the centre
    pairs.targets[i] = V[i] + [0.01, 0.0, 0.005]  # 63 deg off its neighbours' +z
    out = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("neighbours"))
    assert not out.kept[i] and out.kept.sum() == len(V) - 1 and out.rejected_by["neighbours"] == 1
    assert nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj,
                                       _only("neighbours", T_Ng_deg=70.0)).kept.all()
    # A pair shorter than min_direction is noise: never tested (and never compared).
    pairs.targets[i] = V[i] + [0.002, 0.0, 0.001]
    assert nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("neighbours")).kept.all()


def test_length_filter_against_the_neighbourhood_median_and_the_max_distance():
    V, F, N, pairs, sensor, adj = _flat_case(7)
    i = 24
    arm = np.ones(len(V), bool)
    # l = mean(median of the neighbours, |c_i|): |c_i| - 5 mm may reach 2 T_L = 16 mm (docstring of the filter).
    for extra, kept in ((0.0155, True), (0.0165, False)):
        pairs.targets[i] = V[i] + [0.0, 0.0, 0.005 + extra]
        out = nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, _only("length"))
        assert out.kept[i] == kept and out.kept.sum() == len(V) - (not kept)
    pairs.targets[i] = V[i] + [0.0, 0.0, 0.013]
    assert not nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, _only("length", T_L_m=0.0035)).kept[i]
    pairs.targets[i] = V[i] + [0.0, 0.0, 0.005]
    short = _only("length", max_distance_m=0.0049)
    assert not nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, short).kept.any()
    # With the length filter off, the max distance still applies on its own.
    pairs.targets[i] = V[i] + [0.0, 0.0, 0.05]
    out = nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, CorrespondenceFilters(**ALL_OFF))
    assert not out.kept[i] and out.rejected_by == {"max_distance": 1}


def test_length_filter_uses_the_median_of_the_neighbourhood_and_the_vertex():
    """Eq. 4 as implemented: l is the median of {median of the valid neighbours' lengths, |c_i|} (their mean)."""
    V, F, N, pairs, sensor, adj = _flat_case(4)
    ring = [1, 2, 4, 5, 6, 8, 9, 10]  # the 2-ring of corner vertex 0
    pairs.targets[ring[:4]] = V[ring[:4]] + [0.0, 0.0, 0.005]
    pairs.targets[ring[4:]] = V[ring[4:]] + [0.0, 0.0, 0.021]
    # |c_0| = 5 mm: l = (13 + 5) / 2 = 9 mm, 4 mm off (kept); against the ring's median alone 8 mm (refused).
    out = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("length"))
    assert out.kept[0]
    pairs.targets[0] = V[0] + [0.0, 0.0, 0.03]  # 30 mm: l = 21.5 mm, 8.5 mm off: refused
    assert not nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("length")).kept[0]


def test_duplicates_keep_the_vertex_whose_normal_agrees_best():
    V, F, N, pairs, sensor, adj = _flat_case()
    pairs.point_index[[3, 9, 20]] = 7  # four vertices (3, 7, 9, 20) share depth point 7
    N = N.copy()
    N[7] = Rotation.from_rotvec([0.1, 0, 0]).apply(N[7])
    N[3] = Rotation.from_rotvec([0.2, 0, 0]).apply(N[3])
    N[20] = Rotation.from_rotvec([0.3, 0, 0]).apply(N[20])
    out = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("duplicates"))
    assert out.kept[9] and not out.kept[3] and not out.kept[20] and not out.kept[7]
    assert out.rejected_by["duplicates"] == 3 and out.kept.sum() == len(V) - 3


def test_closest_point_correspondences_pair_each_vertex_with_its_nearest_point():
    P = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    Np = np.eye(3)
    pairs = nicp.closest_point_correspondences([[0.9, 0.1, 0], [0.1, 0.8, 0]], P, Np)
    np.testing.assert_array_equal(pairs.point_index, [1, 2])
    np.testing.assert_array_equal(pairs.targets, P[[1, 2]])
    np.testing.assert_array_equal(pairs.target_normals, Np[[1, 2]])
    assert pairs.kept.all() and pairs.rejected_by == {}


# --- Sec. 5.3 ------------------------------------------------------------------------------------------

def test_cotangent_weights_of_a_right_triangle_and_linear_precision_of_the_laplacian():
    V = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    sysm = nicp.arap_system(V, np.array([[0, 1, 2]]))
    W = dict(zip(map(tuple, sysm.edges), sysm.edge_weights, strict=True))
    # cot 45 / 2 on the legs' opposite... edge (1, 2) faces the right angle: cot 90 = 0, clamped to 1e-4.
    assert W[(0, 1)] == pytest.approx(0.5) and W[(0, 2)] == pytest.approx(0.5) and W[(1, 2)] == pytest.approx(1e-4)
    assert W[(1, 0)] == W[(0, 1)] and len(W) == 6
    L = sysm.laplacian.toarray()
    np.testing.assert_allclose(L, L.T)
    np.testing.assert_allclose(L.sum(1), 0.0, atol=1e-15)
    assert L[0, 0] == pytest.approx(1.0) and L[0, 1] == pytest.approx(-0.5)
    # On a flat grid the cotangent Laplacian of a linear function vanishes at every interior vertex.
    Vg, Fg = _grid(5)
    Lg = nicp.arap_system(Vg, Fg).laplacian
    f = Vg @ [2.0, -3.0, 0.0] + 1.0
    interior = np.array([r * 5 + c for r in range(1, 4) for c in range(1, 4)])
    np.testing.assert_allclose((Lg @ f)[interior], 0.0, atol=1e-12)


def test_best_rotations_of_a_rotated_copy_and_of_a_mirror_image(ellipsoid):
    V, F = ellipsoid
    sysm = nicp.arap_system(V, F)
    R = Rotation.from_rotvec([0.4, -0.3, 0.8]).as_matrix()
    Rs = nicp._best_rotations(sysm, V @ R.T + 0.1)
    np.testing.assert_allclose(Rs, np.broadcast_to(R, Rs.shape), atol=1e-9)
    Rm = nicp._best_rotations(sysm, V * [1, 1, -1])
    np.testing.assert_allclose(np.linalg.det(Rm), 1.0, atol=1e-9)


def test_arap_pulls_a_bent_plate_towards_targets_more_with_a_larger_data_weight():
    V, F = _grid(7)
    sysm = nicp.arap_system(V, F)
    target = V.copy()
    target[:, 2] = 0.5 * (V[:, 0] - 0.05) ** 2 * 20  # a gentle bend
    w = np.zeros(len(V))
    w[::3] = 1.0

    def err(X):
        return np.abs(X - target)[w > 0].max()

    weak = nicp.arap_deformation(sysm, V, target, w, data_weight=0.1, iterations=5)
    strong = nicp.arap_deformation(sysm, V, target, w, data_weight=10.0, iterations=5)
    assert err(strong) < 0.5 * err(weak) < 0.5 * err(V)
    # The data term only acts through the weighted vertices: scaling every weight scales lambda alone.
    np.testing.assert_allclose(nicp.arap_deformation(sysm, V, target, 2 * w, data_weight=1.0),
                               nicp.arap_deformation(sysm, V, target, w, data_weight=2.0), atol=1e-12)


def test_arap_iterations_converge_to_a_rigid_target(ellipsoid):
    """Every vertex pulled to a rotated copy: the local/global sweeps converge to it, more sweeps closer."""
    V, F = ellipsoid
    sysm = nicp.arap_system(V, F)
    R = Rotation.from_rotvec([0.0, 0.0, 0.6]).as_matrix()
    target = V @ R.T
    w = np.ones(len(V))
    errs = [np.abs(nicp.arap_deformation(sysm, V, target, w, iterations=k) - target).max() for k in (1, 3, 30)]
    assert errs[2] < 1e-4 and errs[2] < 0.5 * errs[1] < 0.5 * errs[0]


def test_plane_targets_project_the_vertex_on_the_points_tangent_plane():
    V = np.array([[0.0, 0, 0], [1.0, 1.0, 1.0]])
    pairs = Correspondences(np.array([[0.3, 0.2, 0.1], [1.0, 1.0, 0.0]]), np.array([[0, 0, 1.0], [0, 0, -1.0]]),
                            np.arange(2), np.ones(2, bool))
    np.testing.assert_allclose(nicp.plane_targets(V, pairs), [[0, 0, 0.1], [1.0, 1.0, 0.0]], atol=1e-15)


# --- non-rigid ICP ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def shifted_copy(ellipsoid):
    """The template and a copy of it moved (4, 0, 6) mm, seen from +z: the cloud is the copy's vertices."""
    V, F = ellipsoid
    P = V + [0.004, 0.0, 0.006]
    return (V, F, P, vertex_normals(P, F), V.mean(0) + np.array([0.0, 0.0, 1.0]), nicp.vertex_neighbourhoods(F, len(V)),
            nicp.arap_system(V, F), vertex_normals(V, F) @ [0, 0, 1] > 0.3)


def _icp(shifted_copy, **kw):
    V, F, P, Np, sensor, adj, sysm, _ = shifted_copy
    opts = nicp.NicpOptions(filters=CorrespondenceFilters(neighbours=False, length=False), **kw)
    return nicp.nonrigid_icp(sysm, F, V, P, Np, sensor, np.ones(len(V), bool), adj, opts)


def test_nonrigid_icp_with_point_targets_converges_to_the_shifted_copy(shifted_copy):
    """Closest points change as the template moves: one iteration gets part of the way, twelve all of it."""
    V, F, P, Np, sensor, adj, sysm, front = shifted_copy

    def err(X):
        return np.linalg.norm(X - P, axis=1)[front].mean()

    X1, _ = _icp(shifted_copy, iterations=1, point_to_plane=False)
    X, pairs = _icp(shifted_copy, iterations=12, point_to_plane=False)
    assert err(X) < 1e-8 and 1e-4 < err(X1) < 0.5 * err(V)  # measured 1e-11; 1.7 mm of 7.2 mm
    assert pairs.kept[front].all()
    np.testing.assert_array_equal(pairs.point_index[front], np.flatnonzero(front))  # each vertex on its own copy


def test_nonrigid_icp_with_plane_targets_closes_the_normal_gap(shifted_copy):
    """Point-to-plane: the distance along the data normals goes to ~0 (tangential sliding is free)."""
    V, F, P, Np, sensor, adj, sysm, front = shifted_copy

    def gap(X):
        return np.abs(np.einsum("kd,kd->k", X - P, Np))[front].mean()

    X1, _ = _icp(shifted_copy, iterations=1)
    X, _ = _icp(shifted_copy, iterations=12)
    assert gap(X) < 0.1 * gap(V) and gap(X) < 0.6 * gap(X1)  # measured 0.17 vs 0.40 mm, from 3.2 mm
    assert np.linalg.norm(X - P, axis=1)[front].mean() > 1e-3  # not the point targets


# --- the survivors of the first mutation run (docs/mutation/muscle-nicp.md) -------------------------------

def test_cotangent_weights_of_an_irregular_centimetre_mesh_are_the_hand_computed_cotangents():
    """Two triangles of different shapes and sizes (1-3 cm): every weight is half the cotangent opposite it."""
    V = np.array([[0.0, 0, 0], [0.03, 0, 0], [0.01, 0.02, 0], [0.025, -0.012, 0.004]])
    F = np.array([[0, 1, 2], [1, 0, 3]])
    W = {}
    for f in F:
        for k in range(3):
            i, j, o = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
            a, b = V[i] - V[o], V[j] - V[o]
            cot = a @ b / np.linalg.norm(np.cross(a, b))
            for e in ((i, j), (j, i)):
                W[e] = W.get(e, 0.0) + max(0.5 * cot, 0.0)
    sysm = nicp.arap_system(V, F)
    got = {}
    for (i, j), w in zip(map(tuple, sysm.edges), sysm.edge_weights, strict=True):
        got[(i, j)] = got.get((i, j), 0.0) + w
    assert set(got) == set(W)
    for e in W:
        assert got[e] == pytest.approx(max(W[e], 1e-4), rel=1e-12), e


def test_an_unreferenced_last_vertex_keeps_the_operators_square():
    V, F = _grid(3)
    V = np.r_[V, [[1.0, 1.0, 1.0]]]  # not in any face
    assert nicp.arap_system(V, F).laplacian.shape == (10, 10)
    assert nicp.vertex_neighbourhoods(F, 10).shape == (10, 10)
    assert nicp._neighbour_medians(sp.csr_matrix((0, 0), dtype=bool), np.zeros(0), np.zeros(0, bool)).shape == (0,)
    assert nicp._neighbour_angle_medians(sp.csr_matrix((0, 0), dtype=bool), np.zeros((0, 3)),
                                         np.zeros(0, bool)).shape == (0,)


def test_arap_without_data_returns_a_copy_of_the_start():
    V, F = _grid(4)
    sysm = nicp.arap_system(V, F)
    X = nicp.arap_deformation(sysm, V, V + 1.0, np.zeros(len(V)))
    np.testing.assert_array_equal(X, V)
    assert X is not V


def _round_off_unit_vector():
    """A vector whose normalised dot product with itself rounds above 1 (arccos would give NaN)."""
    V = np.random.default_rng(0).normal(size=(2000, 3))
    U = V / np.linalg.norm(V, axis=1, keepdims=True)
    k = int(np.flatnonzero(np.einsum("kd,kd->k", U, U) > 1.0)[0])
    return V[k]


def test_angle_medians_of_parallel_and_opposite_vectors_survive_round_off():
    v = _round_off_unit_vector()
    adj = sp.csr_matrix(np.array([[0, 1], [1, 0]], bool))
    np.testing.assert_array_equal(nicp._neighbour_angle_medians(adj, np.stack([v, v]), np.ones(2, bool)), 0.0)
    np.testing.assert_allclose(nicp._neighbour_angle_medians(adj, np.stack([v, -v]), np.ones(2, bool)), np.pi)


def test_normals_filter_keeps_identical_normals_despite_round_off():
    V, F, N, pairs, sensor, adj = _flat_case()
    n = _round_off_unit_vector()
    n = n / np.linalg.norm(n)
    N = np.tile(n, (len(V), 1))
    pairs.target_normals[:] = n
    out = nicp.filter_correspondences(V, N, pairs, sensor, np.ones(len(V), bool), adj, _only("normals"))
    assert out.kept.all()


def test_neighbours_rejected_by_an_earlier_filter_are_not_compared():
    V, F, N, pairs, sensor, adj = _flat_case(7)
    i = 24
    ring = adj[i].indices
    pairs.targets[ring] = V[ring] + [0.01, 0.0, 0.005]  # 63 deg off the centre's +z, but outside the arm
    arm = np.ones(len(V), bool)
    arm[ring] = False
    f = CorrespondenceFilters(**{**ALL_OFF, "arm_only": True, "neighbours": True})
    assert nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, f).kept[i]
    arm[:] = True
    assert not nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, f).kept[i]


def test_a_pair_without_valid_neighbours_is_judged_on_its_own_length():
    V, F, N, pairs, sensor, adj = _flat_case(7)
    i = 24
    arm = np.zeros(len(V), bool)
    arm[i] = True  # every neighbour rejected first: no neighbourhood median
    f = CorrespondenceFilters(**{**ALL_OFF, "arm_only": True, "length": True})
    out = nicp.filter_correspondences(V, N, pairs, sensor, arm, adj, f)
    assert out.kept[i] and out.kept.sum() == 1


def test_integer_masks_act_as_boolean_masks(ellipsoid):
    V, F, N, pairs, sensor, adj = _flat_case()
    arm = (np.arange(len(V)) % 3 != 0)
    out = nicp.filter_correspondences(V, N, pairs, sensor, arm.astype(int), adj, _only("arm_only"))
    np.testing.assert_array_equal(out.kept, arm)
    assert out.kept.dtype == bool  # a boolean mask downstream (X[pairs.kept])
    Ve, Fe = ellipsoid
    sensor = Ve.mean(0) + np.array([0.0, 0.0, 1.0])
    front = vertex_normals(Ve, Fe) @ [0, 0, 1] > 0
    P = Ve[front] + [0.003, 0.0, 0.0]
    start = (1.0, np.eye(3), np.zeros(3))
    S = nicp.rigid_alignment_with_scale(Ve, Fe, P, sensor, front.astype(int), initial=start, with_scale=False)
    np.testing.assert_allclose(S[2], [0.003, 0.0, 0.0], atol=1e-9)


def test_rigid_alignment_at_exactly_ten_points_and_ten_pairs(ellipsoid):
    V, F = ellipsoid
    sensor = V.mean(0) + np.array([0.0, 0.0, 1.0])
    front = np.flatnonzero(vertex_normals(V, F) @ [0, 0, 1] > 0)
    start = (1.0, np.eye(3), np.zeros(3))
    # Ten points are a point cloud; far from the template they give no pairs.
    with pytest.raises(InputError, match="^rigid alignment found fewer than 10 template-to-depth pairs; start the "
                                         "sequence with the arm in the template's base pose facing the sensor$"):
        nicp.rigid_alignment_with_scale(V, F, V[front[:10]] + 1.0, sensor, initial=start)
    # Ten masked vertices on their ten points: ten pairs are enough.
    mask = np.zeros(len(V), bool)
    mask[front[:10]] = True
    S = nicp.rigid_alignment_with_scale(V, F, V[front[:10]] + [0.002, 0, 0], sensor, mask, initial=start,
                                        with_scale=False, with_rotation=False)
    np.testing.assert_allclose(S[2], [0.002, 0, 0], atol=1e-9)


def test_rigid_alignment_without_scale_keeps_scale_one_on_a_scaled_copy(ellipsoid):
    V, F = ellipsoid
    c = V.mean(0)
    P = 1.05 * (V - c) + c
    sensor = c + np.array([0.0, 0.0, 1.0])
    seen = np.einsum("kd,kd->k", vertex_normals(P, F), sensor - P) > 0
    assert nicp.rigid_alignment_with_scale(V, F, P[seen], sensor, with_scale=False)[0] == 1.0


def test_nonrigid_icp_iteration_is_pairs_filters_plane_targets_then_arap(shifted_copy):
    """One iteration by hand, with every option passed through (filters, data weight, ARAP sweeps)."""
    V, F, P, Np, sensor, adj, sysm, _ = shifted_copy
    arm = np.ones(len(V), bool)
    opts = nicp.NicpOptions(iterations=1, arap_iterations=2, data_weight=3.0)
    X, pairs = nicp.nonrigid_icp(sysm, F, V, P, Np, sensor, arm, adj, opts)
    want = nicp.filter_correspondences(V, vertex_normals(V, F), nicp.closest_point_correspondences(V, P, Np),
                                       sensor, arm, adj, opts.filters)
    np.testing.assert_array_equal(pairs.kept, want.kept)
    assert pairs.rejected_by == want.rejected_by
    ref = nicp.arap_deformation(sysm, V, nicp.plane_targets(V, want), want.kept.astype(float), 3.0, 2)
    np.testing.assert_allclose(X, ref, atol=1e-15)
    X0, none = nicp.nonrigid_icp(sysm, F, V, P, Np, sensor, arm, adj, nicp.NicpOptions(iterations=0))
    np.testing.assert_array_equal(X0, V)
    assert none is None and X0 is not V


def test_the_centroid_start_widens_the_pair_distance_for_its_first_iterations(ellipsoid):
    """From the centroid start (no ``initial``) the first iterations pair up to 3 max_distance: a 10 deg,
    14 mm similarity is recovered with a 3 mm pair limit; the same start given as ``initial`` is trusted
    (no widening) and finds too few pairs."""
    V, F = ellipsoid
    c = V.mean(0)
    sensor = c + np.array([0.0, 0.0, 1.0])
    R = Rotation.from_rotvec([0.1, -0.1, 0.15]).as_matrix()
    P = 1.05 * (V - c) @ R.T + c + [0.01, -0.01, 0.0]
    seen = np.einsum("kd,kd->k", vertex_normals(P, F), sensor - P) > 0
    S = nicp.rigid_alignment_with_scale(V, F, P[seen], sensor, max_distance_m=0.003)
    np.testing.assert_allclose(nicp.apply_similarity(S, V)[seen], P[seen], atol=1e-9)
    front = np.einsum("kd,kd->k", vertex_normals(V, F), sensor - V) > 0
    start = (1.0, np.eye(3), P[seen].mean(0) - V[front].mean(0))
    with pytest.raises(InputError, match="fewer than 10"):
        nicp.rigid_alignment_with_scale(V, F, P[seen], sensor, initial=start, max_distance_m=0.003)
