"""register/initial_pose.py against independent references (issue 17, branch mutDD): the weighted median and the
coarse skeleton of a hand-made point set worked out by hand (area weights from one big triangle), the edge graph of
two triangles, geodesic tips and rings against a heapq Dijkstra, the bone turn against the rotation it must add in
world axes, and the whole initial pose on the 2k body posed by a known pose: the bone-by-bone limb alignment must
bring the limbs closer than the straight aim alone (a skipped alignment fails the bounds).
"""

import heapq
from functools import cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Pose
from bodystudio.body.skinning import forward_kinematics, linear_blend_skinning, skinning_transforms
from bodystudio.errors import InputError
from bodystudio.register import initial_pose as ip


@cache
def _body():
    from bodystudio.body import build_body

    return build_body(resolution="2k")


@cache
def _case():
    """The 2k body posed by a known pose (left arm out and bent, right arm forward, legs apart): the 'scan'."""
    body = _body()
    sk = body.skeleton
    rot = np.zeros((sk.n_bones, 3))
    rot[sk.index("upperarm_l")] = [0, 0, 0.6]
    rot[sk.index("lowerarm_l")] = [0.8, 0, 0]
    rot[sk.index("upperarm_r")] = [0.3, 0, -0.4]
    rot[sk.index("thigh_l")] = [-0.3, 0, 0.1]
    rot[sk.index("calf_r")] = [0.5, 0, 0]
    pose = Pose(rot, np.array([0.1, 0.0, -0.2]))
    scan = linear_blend_skinning(body.vertices, body.weights, skinning_transforms(sk, pose))
    return body, pose, scan


def _dijkstra(V, F, source, limit=np.inf):
    """Shortest paths along the mesh edges by a heap (independent of scipy)."""
    nbr = [dict() for _ in range(len(V))]
    for f in F:
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            d = float(np.linalg.norm(V[a] - V[b])) + 1e-12
            nbr[a][b] = nbr[b][a] = d
    dist = np.full(len(V), np.inf)
    dist[source] = 0.0
    heap = [(0.0, source)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > dist[u]:
            continue
        for v, w in nbr[u].items():
            if d + w < dist[v] and d + w <= limit:
                dist[v] = d + w
                heapq.heappush(heap, (d + w, v))
    return dist


def test_weighted_median_by_hand():
    assert ip.weighted_median(np.array([3.0, 1.0, 2.0]), np.ones(3)) == 2.0
    assert ip.weighted_median(np.array([4.0, 1.0, 3.0, 2.0]), np.ones(4)) == 2.0  # half the weight reached at 2
    assert ip.weighted_median(np.array([1.0, 2.0, 3.0, 4.0]), np.array([1.0, 1.0, 1.0, 10.0])) == 4.0
    assert ip.weighted_median(np.array([5.0]), np.array([2.0])) == 5.0
    assert isinstance(ip.weighted_median(np.array([1, 2, 3]), np.ones(3)), float)
    with pytest.raises(ValueError, match="^weighted_median of no samples$"):
        ip.weighted_median(np.zeros(0), np.zeros(0))


# a hand-made standing 'scan', 2 m tall: the head top, a hip band (three core points and one far out), hands with a
# higher candidate that the 0.3 height penalty rejects, two points per foot, two vertices mid-shin for the areas
POINTS = np.array([
    [0.05, 2.0, 0.02],  # 0 head top
    [0.0, 1.04, 0.10], [0.1, 1.05, -0.10], [-0.1, 1.03, 0.2],  # 1-3 hip band core (|y - 1.04| < 0.04)
    [0.5, 1.04, 0.3],  # 4 in the band, 0.45 from the median plane: not core
    [0.8, 1.5, 0.0], [0.9, 1.9, 0.0],  # 5, 6 left hand candidates: 0.8 - 0.3 * 0.46 > 0.9 - 0.3 * 0.86
    [-0.7, 1.2, 0.1], [-0.75, 1.8, 0.0],  # 7, 8 right hand candidates
    [0.15, 0.0, 0.2], [0.2, 0.05, 0.1],  # 9, 10 left foot: the most forward (z) is the tip
    [-0.15, 0.02, 0.25], [-0.1, 0.1, 0.3],  # 11, 12 right foot
    [-0.05, 0.4, 0.0], [-0.02, 0.4, 0.05],  # 13, 14 mid-shin (neither upper, lower nor band)
])


def test_coarse_skeleton_of_a_hand_made_point_set():
    c = ip.coarse_scan_skeleton(POINTS)
    assert c.floor_y == 0.0 and c.stature_m == 2.0
    np.testing.assert_array_equal(c.head_top, POINTS[0])
    # median plane x = 0.0 (the 8th of 15 sorted x); core x {0, 0.1, -0.1} -> 0.0, z {0.1, -0.1, 0.2} -> 0.1
    np.testing.assert_allclose(c.pelvis, [0.0, 1.04, 0.1])
    np.testing.assert_array_equal(c.hand_tips[1.0], POINTS[5])
    np.testing.assert_array_equal(c.hand_tips[-1.0], POINTS[7])
    np.testing.assert_array_equal(c.foot_tips[1.0], POINTS[9])
    np.testing.assert_array_equal(c.foot_tips[-1.0], POINTS[12])


def test_a_raised_hand_is_the_tip_though_a_point_near_the_body_scores_better():
    # the left side's only point beyond 0.05 statures (0.1 m) is a hand raised to 1.95 m: score
    # 0.35 - 0.3 * 0.91 = 0.077, below the hip point (0.1, 1.05)'s 0.097; the tip is still taken among the points
    # out to the side
    # a point far out at 0.5 m (below the upper part, 0.35 statures = 0.7 m) is no hand candidate
    P = np.vstack([np.delete(POINTS, [4, 5, 6], axis=0), [[0.35, 1.95, 0.0], [0.9, 0.5, 0.0]]])
    for shift in (0.0, 0.5):  # also with the body 0.5 m off the origin
        c = ip.coarse_scan_skeleton(P + [shift, 0.0, 0.0])
        np.testing.assert_array_equal(c.hand_tips[1.0], [0.35 + shift, 1.95, 0.0])
        np.testing.assert_array_equal(c.hand_tips[-1.0], POINTS[7] + [shift, 0.0, 0.0])


def test_coarse_skeleton_weighs_by_vertex_area():
    # one big triangle on vertices 3, 13, 14: only they have area; the median plane is then x = -0.05 and the
    # hip core's only weighted point is vertex 3
    F = np.array([[3, 13, 14]])
    P = POINTS.copy()
    P[13] = [-0.05, 0.4, -1.0]
    P[14] = [-0.02, 0.3, 1.0]
    c = ip.coarse_scan_skeleton(P, F)
    np.testing.assert_allclose(c.pelvis, [-0.1, 1.04, 0.2])


def test_coarse_skeleton_fallbacks_and_refusal():
    # no point out to the right beyond 0.05 statures, no foot point left of the pelvis: the candidates fall back to
    # the whole upper / lower part
    P = POINTS[[0, 1, 2, 3, 5, 6, 9, 10, 13]].copy()
    c = ip.coarse_scan_skeleton(P)
    upper = P[P[:, 1] > 0.7]
    score = -(upper[:, 0] - c.pelvis[0]) - 0.3 * np.maximum(upper[:, 1] - c.pelvis[1], 0)
    np.testing.assert_array_equal(c.hand_tips[-1.0], upper[np.argmax(score)])
    lower = P[P[:, 1] < 0.16]
    np.testing.assert_array_equal(c.foot_tips[-1.0], lower[np.argmax(lower[:, 2])])
    # a band of far points only: the core falls back to the band
    Q = np.array([[0.0, 2.0, 0.0], [0.9, 1.04, 0.3], [0.95, 1.05, 0.1], [0.0, 0.0, 0.0], [0.0, 0.5, 0.0],
                  [0.0, 0.6, 0.0], [0.0, 0.55, 0.0], [0.0, 0.45, 0.0], [0.0, 0.5, 0.1]])
    c = ip.coarse_scan_skeleton(Q)
    np.testing.assert_allclose(c.pelvis, [0.9, 1.04, 0.1])
    for drop in ([1, 2], [3]):  # no hip band; nothing near the feet
        R = np.delete(Q, drop, axis=0)
        with pytest.raises(InputError) as e:
            ip.coarse_scan_skeleton(R)
        h = np.ptp(R[:, 1])
        assert str(e.value) == (f"the scan has no surface points at hip height or near the feet ({len(R)} vertices "
                                f"over {h:.2f} m): too coarse, or not a person standing upright; give a body scan with "
                                "vertices every few centimetres (remesh it)")


def test_edge_length_graph_of_two_triangles():
    V = np.array([[0.0, 0, 0], [3, 0, 0], [0, 4, 0], [3, 4, 0]])
    G = ip.edge_length_graph(V, np.array([[0, 1, 2], [1, 3, 2]]))
    assert G.shape == (4, 4) and G.nnz == 10 and (G != G.T).nnz == 0
    want = {(0, 1): 3, (0, 2): 4, (1, 2): 5, (1, 3): 4, (2, 3): 3}
    for (a, b), d in want.items():
        assert G[a, b] == pytest.approx(d, abs=1e-9) and G[a, b] > d
    assert G[0, 3] == 0 and G[0, 0] == 0


def test_limb_tips_and_rings_against_a_heap_dijkstra():
    body, _, scan = _case()
    F = body.faces
    coarse = ip.coarse_scan_skeleton(scan, F)
    tips = ip.limb_tips(scan, F, coarse)
    h = coarse.stature_m
    band = np.abs(scan[:, 1] - (coarse.floor_y + 0.72 * h)) < 0.03 * h
    front = band & (np.abs(scan[:, 0] - coarse.pelvis[0]) < 0.05 * h)
    chest = int(np.flatnonzero(front)[np.argmax(scan[front, 2])])
    g = _dijkstra(scan, F, chest)
    above = scan[:, 1] > coarse.floor_y + 0.45 * h
    for side in (1.0, -1.0):
        arm = above & (side * (scan[:, 0] - coarse.pelvis[0]) > 0.05 * h)
        far = int(np.flatnonzero(arm)[np.argmax(g[arm])])
        assert tips["hand", side] == far and g[far] > 0.3 * h
    legs = ~above
    first = int(np.flatnonzero(legs)[np.argmax(g[legs])])
    second = int(np.flatnonzero(legs)[np.argmax(np.minimum(g, _dijkstra(scan, F, first))[legs])])
    assert {tips["foot", 1.0], tips["foot", -1.0]} == {first, second}
    # the left foot (+x) is the one with the left thigh (+x)
    assert scan[tips["foot", 1.0], 0] > scan[tips["foot", -1.0], 0]
    # rings: geodesic distance within 8 mm of each asked distance
    d = np.array([0.1, 0.25])
    rings = ip.geodesic_rings(scan, F, tips["hand", 1.0], d)
    g_tip = _dijkstra(scan, F, tips["hand", 1.0])
    for r, dist in zip(rings, d, strict=True):
        np.testing.assert_array_equal(r, np.flatnonzero(np.abs(g_tip - dist) < ip.RING_HALF_WIDTH_M))
        assert len(r) >= 3
    assert ip.RING_HALF_WIDTH_M == 0.008


def test_limb_tips_of_a_hand_cut_off_and_no_legs():
    body, _, scan = _case()
    coarse = ip.coarse_scan_skeleton(scan, body.faces)
    h = coarse.stature_m
    # only the faces above mid-height: nothing below the crotch is reachable, no toe tips; the raised hand is found
    F = body.faces[np.all(scan[body.faces, 1] > coarse.floor_y + 0.5 * h, axis=1)]
    tips = ip.limb_tips(scan, F, coarse)
    assert tips["foot", 1.0] == tips["foot", -1.0] == -1 and tips["hand", 1.0] >= 0
    # nothing reachable beyond 0.05 statures to the left (those faces dropped): no hand tip on that side
    left = scan[:, 0] - coarse.pelvis[0] > 0.05 * h
    F = body.faces[~np.any(left[body.faces], axis=1)]
    tips = ip.limb_tips(scan, F, coarse)
    assert tips["hand", 1.0] == -1 and tips["hand", -1.0] >= 0
    # the same with a toe renumbered as vertex 1 (far from the chest): "no tip" is not vertex 1
    toe = tips["foot", 1.0]
    order = np.r_[0, toe, np.delete(np.arange(len(scan)), [0, toe])]
    tips = ip.limb_tips(scan[order], np.argsort(order)[F], coarse)
    assert tips["hand", 1.0] == -1 and tips["foot", 1.0] == 1


def test_rotate_bone_towards_adds_the_world_rotation():
    body = _body()
    sk = body.skeleton
    rng = np.random.default_rng(3)
    pose = Pose(rng.normal(size=(sk.n_bones, 3)) * 0.2, np.array([0.1, 0.2, 0.3]))
    j = sk.index("lowerarm_l")
    a, b = np.array([0.0, 1.0, 0.2]), np.array([0.5, 0.3, -0.2])
    out = ip._rotate_bone_towards(sk, pose, j, a, b)
    G0, G1 = forward_kinematics(sk, pose)[:, :3, :3], forward_kinematics(sk, out)[:, :3, :3]
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis), a @ b)
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    np.testing.assert_allclose(G1[j], R @ G0[j], atol=1e-10)
    np.testing.assert_allclose(R @ a / np.linalg.norm(a), b / np.linalg.norm(b), atol=1e-12)
    others = np.arange(sk.n_bones) != j
    np.testing.assert_array_equal(out.rotations[others], pose.rotations[others])
    np.testing.assert_array_equal(out.translation, pose.translation)
    # capped at max_angle
    out = ip._rotate_bone_towards(sk, pose, j, a, b, max_angle=0.1)
    G1 = forward_kinematics(sk, out)[:, :3, :3]
    Rc = Rotation.from_rotvec(axis / np.linalg.norm(axis) * 0.1).as_matrix()
    np.testing.assert_allclose(G1[j], Rc @ G0[j], atol=1e-10)
    # parallel directions (any length): unchanged; the test is relative to both lengths
    assert ip._rotate_bone_towards(sk, pose, j, a, 3.0 * a) is pose
    # 1 mm off a direction 10^8 m long: 1e-11 rad apart, parallel by the relative test (not by an absolute one)
    a2, eps = np.array([0.1, 0.7, 0.3]), np.array([0.0, 0.0, 1e-3])
    for d_model, d_scan in ((a2, a2 * 1.3e8 + eps), (a2 * 1.3e8 + eps, a2)):
        assert np.linalg.norm(np.cross(d_model, d_scan)) > 1e-4
        assert ip._rotate_bone_towards(sk, pose, j, d_model, d_scan) is pose


def _limb_error(body, pose, scan, bones):
    sk = body.skeleton
    got = linear_blend_skinning(body.vertices, body.weights, skinning_transforms(sk, pose))
    owned = body.weights[:, [sk.index(b) for b in bones]].sum(1) > 0.5
    return float(np.median(np.linalg.norm(got[owned] - scan[owned], axis=1)))


LEFT_ARM = ("upperarm_l", "lowerarm_l", "hand_l")
RIGHT_LEG = ("thigh_r", "calf_r", "foot_r")


def test_chain_end_vertices_by_brute_force():
    body = _body()
    sk, V, W = body.skeleton, body.vertices, body.weights
    for root, kind in (("upperarm_l", "hand"), ("upperarm_r", "hand"), ("thigh_l", "foot"), ("thigh_r", "foot")):
        side = root[-2:]
        prefixes = ("hand", "index", "middle", "ring", "pinky", "thumb") if kind == "hand" else ("foot", "ball")
        cols = [i for i, b in enumerate(sk.bone_names) if b.endswith(side) and b.startswith(prefixes)]
        owned = [v for v in range(len(V)) if W[v, cols].sum() > 0.5]
        head = sk.heads[sk.index(root)]
        score = np.linalg.norm(V - head, axis=1) if kind == "hand" else V[:, 2]
        assert ip._chain_end_vertex(sk, W, V, root, kind) == max(owned, key=lambda v, s=score: s[v])


def test_initial_pose_translation_and_straight_aim():
    body, pose, scan = _case()
    sk = body.skeleton
    coarse = ip.coarse_scan_skeleton(scan)
    p = ip.initial_pose(sk, body.weights, body.vertices, scan)
    pelvis = sk.heads[sk.index("pelvis")]
    np.testing.assert_allclose(p.translation, [coarse.pelvis[0] - pelvis[0], coarse.floor_y - body.vertices[:, 1].min(),
                                               coarse.pelvis[2] - pelvis[2]], atol=1e-12)
    np.testing.assert_array_equal(ip.initial_pose(sk, body.weights, body.vertices, scan, coarse).rotations, p.rotations)
    # each limb root turned so that the chain end points at the coarse tip (the legs at most 0.35 rad)
    moved = {sk.index(r) for r, _, _ in ip.LIMB_CHAINS}
    assert all(np.allclose(p.rotations[j], 0) for j in range(sk.n_bones) if j not in moved)
    M = forward_kinematics(sk, p)
    posed = linear_blend_skinning(body.vertices, body.weights, skinning_transforms(sk, p))
    M0 = forward_kinematics(sk, Pose(np.zeros((sk.n_bones, 3)), p.translation))
    for root, side, kind in ip.LIMB_CHAINS[:2]:
        j = sk.index(root)
        end = ip._chain_end_vertex(sk, body.weights, body.vertices, root, kind)
        target = coarse.hand_tips[side]
        d = posed[end] - M[j, :3, 3]
        e = target - M[j, :3, 3]
        assert np.degrees(np.arccos(d @ e / np.linalg.norm(d) / np.linalg.norm(e))) < 0.01
    for root, _, _ in ip.LIMB_CHAINS[2:]:
        j = sk.index(root)
        turn = Rotation.from_matrix(M[j, :3, :3] @ M0[j, :3, :3].T).magnitude()
        assert turn <= 0.35 + 1e-9


def test_bone_by_bone_alignment_beats_the_straight_aim():
    body, pose, scan = _case()
    sk, F = body.skeleton, body.faces
    straight = ip.initial_pose(sk, body.weights, body.vertices, scan)
    aligned = ip.initial_pose(sk, body.weights, body.vertices, scan, faces=F, scan_faces=F)
    assert ip.initial_pose(sk, body.weights, body.vertices, scan, faces=F).rotations.tolist() == \
        straight.rotations.tolist()
    # median vertex error per limb (m): straight aim / bone by bone, measured 0.141 / 0.007 (bent left arm),
    # 0.046 / 0.014 (right arm), 0.043 / 0.021 (right leg, its foot 0.029 / 0.014)
    assert _limb_error(body, aligned, scan, LEFT_ARM) < 0.012 < 0.1 < _limb_error(body, straight, scan, LEFT_ARM)
    assert _limb_error(body, aligned, scan, ("lowerarm_l",)) < 0.01
    assert _limb_error(body, aligned, scan, ("hand_l",)) < 0.01
    assert _limb_error(body, aligned, scan, ("upperarm_r", "lowerarm_r", "hand_r")) < 0.02
    assert _limb_error(body, aligned, scan, RIGHT_LEG) < 0.03
    assert _limb_error(body, aligned, scan, ("calf_r",)) < 0.03
    assert _limb_error(body, aligned, scan, ("foot_r",)) < 0.02


def test_align_limb_without_rings_keeps_the_pose():
    body, pose, scan = _case()
    sk, F = body.skeleton, body.faces
    start = Pose(np.zeros((sk.n_bones, 3)), pose.translation)
    tips = ip.limb_tips(scan, F, ip.coarse_scan_skeleton(scan, F))
    model_tips = ip.limb_tips(body.vertices, F, ip.coarse_scan_skeleton(body.vertices, F))
    # a scan of one triangle round the tip: no ring has 3 vertices
    tip = tips["hand", 1.0]
    tiny = body.faces[np.any(body.faces == tip, axis=1)][:1]
    out = ip.align_limb(sk, body.weights, body.vertices, F, scan, tiny, start, "hand", "l", model_tips["hand", 1.0],
                        tip)
    assert out is start
    out = ip.align_limb(sk, body.weights, body.vertices, F, scan, F, start, "hand", "l", model_tips["hand", 1.0], tip)
    assert _limb_error(body, out, scan, LEFT_ARM) < 0.012
    changed = np.flatnonzero(np.any(out.rotations != start.rotations, axis=1))
    assert set(changed) == {sk.index(b) for b in LEFT_ARM}


def _coarse_by_loops(V, area):
    """coarse_scan_skeleton written out from its docstring with loops and a sorting weighted median."""
    def wmedian(x, w):
        pairs = sorted(zip(x, w, strict=True))
        total, acc = sum(w), 0.0
        for xi, wi in pairs:
            acc += wi
            if acc >= 0.5 * total:
                return xi
        return pairs[-1][0]

    floor, top = V[:, 1].min(), V[np.argmax(V[:, 1])]
    h = V[:, 1].max() - floor
    plane = wmedian(V[:, 0], area)
    band = [i for i in range(len(V)) if abs(V[i, 1] - (floor + 0.52 * h)) < 0.02 * h]
    core = [i for i in band if abs(V[i, 0] - plane) < 0.12 * h] or band
    pelvis = np.array([wmedian(V[core, 0], area[core]), floor + 0.52 * h, wmedian(V[core, 2], area[core])])
    upper = [i for i in range(len(V)) if V[i, 1] > floor + 0.35 * h]
    lower = [i for i in range(len(V)) if V[i, 1] < floor + 0.08 * h]
    hands, feet = {}, {}
    for side in (1.0, -1.0):
        cand = [i for i in upper if side * (V[i, 0] - pelvis[0]) > 0.05 * h] or upper
        hands[side] = V[max(cand, key=lambda i, s=side: s * (V[i, 0] - pelvis[0])
                            - 0.3 * max(V[i, 1] - pelvis[1], 0.0))]
        cand = [i for i in lower if side * (V[i, 0] - pelvis[0]) > 0] or lower
        feet[side] = V[max(cand, key=lambda i: V[i, 2])]
    return floor, top, pelvis, hands, feet


@pytest.mark.parametrize("seed", range(6))
def test_coarse_skeleton_of_shifted_jittered_point_sets_against_loops(seed):
    # POINTS shuffled (the head top not first), moved off the origin, jittered, with a hand raised so high that its
    # height penalty makes a point near the body score better, and random vertex weights from one triangle fan
    rng = np.random.default_rng(seed)
    P = np.vstack([POINTS, [[0.35, 2.3, 0.0]], rng.normal(size=(12, 3)) * [0.3, 0.5, 0.2] + [0, 1.0, 0]])
    P = P + rng.normal(size=P.shape) * 0.01 + rng.normal(size=3) * [0.5, 0.3, 0.5]
    P = P[rng.permutation(len(P))]
    c = ip.coarse_scan_skeleton(P)
    floor, top, pelvis, hands, feet = _coarse_by_loops(P, np.ones(len(P)))
    assert c.floor_y == floor
    np.testing.assert_array_equal(c.head_top, top)
    np.testing.assert_allclose(c.pelvis, pelvis, atol=1e-12)
    for side in (1.0, -1.0):
        np.testing.assert_array_equal(c.hand_tips[side], hands[side])
        np.testing.assert_array_equal(c.foot_tips[side], feet[side])
    F = np.array([[i, (i + 1) % len(P), (i + 5) % len(P)] for i in range(0, len(P), 2)])
    from bodystudio.geometry.mesh import vertex_areas

    c = ip.coarse_scan_skeleton(P, F)
    floor, top, pelvis, hands, feet = _coarse_by_loops(P, vertex_areas(P, F))
    np.testing.assert_allclose(c.pelvis, pelvis, atol=1e-12)
    for side in (1.0, -1.0):
        np.testing.assert_array_equal(c.hand_tips[side], hands[side])


def test_initial_pose_of_a_model_off_the_origin():
    # the same model moved by d (skeleton and rest mesh): the initial translation moves by -d but for the floor
    from bodystudio.body.skeleton import Skeleton

    body, _, scan = _case()
    sk = body.skeleton
    d = np.array([0.07, 0.02, -0.05])
    moved = Skeleton(sk.bone_names, sk.parents, sk.heads + d, sk.tails + d, sk.rolls)
    p0 = ip.initial_pose(sk, body.weights, body.vertices, scan)
    p1 = ip.initial_pose(moved, body.weights, body.vertices + d, scan)
    np.testing.assert_allclose(p1.translation, p0.translation - d, atol=1e-12)
    np.testing.assert_allclose(p1.rotations, p0.rotations, atol=1e-9)


@cache
def _leg_case():
    """The 2k body with the right leg swung 0.8 rad forward: more than the straight aim's 0.35 rad cap."""
    body = _body()
    sk = body.skeleton
    rot = np.zeros((sk.n_bones, 3))
    rot[sk.index("thigh_r")] = [-0.8, 0, 0]
    scan = linear_blend_skinning(body.vertices, body.weights, skinning_transforms(sk, Pose(rot, np.zeros(3))))
    return body, scan


def test_the_straight_aim_swings_a_leg_at_most_0_35_rad_towards_its_toe():
    body, scan = _leg_case()
    sk = body.skeleton
    coarse = ip.coarse_scan_skeleton(scan)
    p = ip.initial_pose(sk, body.weights, body.vertices, scan)
    start = Pose(np.zeros((sk.n_bones, 3)), p.translation)
    for root, side, kind in ip.LIMB_CHAINS[2:]:
        j = sk.index(root)
        end = ip._chain_end_vertex(sk, body.weights, body.vertices, root, kind)
        angles = []
        for q in (start, p):
            posed = linear_blend_skinning(body.vertices[[end]], body.weights[[end]], skinning_transforms(sk, q))[0]
            o = forward_kinematics(sk, q)[j, :3, 3]
            d, e = posed - o, coarse.foot_tips[side] - o
            angles.append(np.arccos(np.clip(d @ e / np.linalg.norm(d) / np.linalg.norm(e), -1, 1)))
        # turned towards the toe by the whole angle, or by 0.35 rad when it is larger
        assert angles[1] == pytest.approx(max(angles[0] - 0.35, 0.0), abs=1e-6)
        if side < 0:
            assert angles[0] > 0.4  # the swung leg needs more than the cap (0.41 rad)


def test_the_model_tips_come_from_the_models_own_area_weighted_skeleton(monkeypatch):
    body, _, scan = _case()
    F = body.faces
    seen = []
    real = ip.limb_tips
    monkeypatch.setattr(ip, "limb_tips", lambda V, F_, c: seen.append(c) or real(V, F_, c))
    ip.initial_pose(body.skeleton, body.weights, body.vertices, scan, faces=F, scan_faces=F)
    want = ip.coarse_scan_skeleton(body.vertices, F)
    np.testing.assert_array_equal(seen[0].pelvis, want.pelvis)
    assert not np.array_equal(ip.coarse_scan_skeleton(body.vertices).pelvis, want.pelvis)


def test_a_limb_without_a_tip_is_left_to_the_straight_aim():
    body, _, scan = _case()
    sk, F = body.skeleton, body.faces
    coarse = ip.coarse_scan_skeleton(scan, F)
    left = scan[:, 0] - coarse.pelvis[0] > 0.05 * coarse.stature_m
    F_scan = F[~np.any(left[F], axis=1)]
    assert ip.limb_tips(scan, F_scan, coarse)["hand", 1.0] == -1
    p = ip.initial_pose(sk, body.weights, body.vertices, scan, coarse, faces=F, scan_faces=F_scan)
    for b in ("lowerarm_l", "hand_l"):
        np.testing.assert_array_equal(p.rotations[sk.index(b)], 0.0)
    assert np.any(p.rotations[sk.index("lowerarm_r")] != 0)


def test_tips_at_vertex_zero_are_tips():
    # the model and the scan renumbered so that both left hand tips are vertex 0: the arm is still aligned
    body, _, scan = _case()
    sk, F = body.skeleton, body.faces
    m_tip = ip.limb_tips(body.vertices, F, ip.coarse_scan_skeleton(body.vertices, F))["hand", 1.0]
    s_tip = ip.limb_tips(scan, F, ip.coarse_scan_skeleton(scan, F))["hand", 1.0]
    assert m_tip == s_tip  # the scan is the posed model: the same vertex
    order = np.r_[m_tip, np.delete(np.arange(len(scan)), m_tip)]
    inv = np.argsort(order)
    V, W, S, F2 = body.vertices[order], body.weights[order], scan[order], inv[F]
    assert ip.limb_tips(S, F2, ip.coarse_scan_skeleton(S, F2))["hand", 1.0] == 0
    p = ip.initial_pose(sk, W, V, S, faces=F2, scan_faces=F2)
    got = linear_blend_skinning(V, W, skinning_transforms(sk, p))
    owned = W[:, [sk.index(b) for b in LEFT_ARM]].sum(1) > 0.5
    assert np.median(np.linalg.norm(got[owned] - S[owned], axis=1)) < 0.012


@pytest.mark.parametrize("owner", ["hand_l", "index_01_l", "middle_01_l", "ring_01_l", "pinky_01_l", "thumb_01_l",
                                   "foot_l", "ball_l"])
def test_chain_end_of_a_stand_in_rig_whose_farthest_vertex_belongs_to_one_bone(owner):
    # each hand / finger / foot bone owns one vertex; the one of `owner` is the farthest from the shoulder (the most
    # forward for a foot): it is the chain end only if `owner` counts as part of the hand (foot)
    from types import SimpleNamespace

    names = ("upperarm_l", "hand_l", "index_01_l", "middle_01_l", "ring_01_l", "pinky_01_l", "thumb_01_l",
             "thigh_l", "foot_l", "ball_l", "hand_r", "foot_r")
    sk = SimpleNamespace(bone_names=names, heads=np.zeros((len(names), 3)), index=names.index)
    V = np.zeros((len(names), 3))
    V[:, 0] = np.arange(len(names)) * 0.01 + 0.1  # ordinary distances
    V[:, 2] = np.arange(len(names)) * 0.001
    k = names.index(owner)
    V[k] = [2.0, 0.0, 2.0]  # the farthest and the most forward
    V[names.index("hand_r")] = V[names.index("foot_r")] = [3.0, 0.0, 3.0]  # other side: never counted
    W = np.eye(len(names))
    kind = "foot" if owner in ("foot_l", "ball_l") else "hand"
    root = "thigh_l" if kind == "foot" else "upperarm_l"
    assert ip._chain_end_vertex(sk, W, V, root, kind) == k


def test_crossed_feet_are_told_apart_by_their_thighs():
    # legs crossed (each thigh swung 0.35 rad across): the left toe lies right of the right one; the tips still
    # follow the legs, as on the rest body (the same vertices: the scan is the posed model)
    body = _body()
    sk, F = body.skeleton, body.faces
    rot = np.zeros((sk.n_bones, 3))
    rot[sk.index("thigh_l")] = [0, 0, 0.35]
    rot[sk.index("thigh_r")] = [0, 0, -0.35]
    scan = linear_blend_skinning(body.vertices, body.weights, skinning_transforms(sk, Pose(rot, np.zeros(3))))
    rest = ip.limb_tips(body.vertices, F, ip.coarse_scan_skeleton(body.vertices, F))
    tips = ip.limb_tips(scan, F, ip.coarse_scan_skeleton(scan, F))
    assert scan[tips["foot", 1.0], 0] < scan[tips["foot", -1.0], 0]  # crossed
    assert (tips["foot", 1.0], tips["foot", -1.0]) == (rest["foot", 1.0], rest["foot", -1.0])
