"""The compiled kernels of the tracked frame (issue 15's frame time) against the numpy expressions they
replaced, on small random inputs (seconds): the skinned parts and the articulated fit's normal equations,
and the warm start of a tracked frame's deformation."""

import cv2
import numpy as np

from bodystudio.geometry.camera import Camera
from bodystudio.reconstruct.articulated_fit import data_normal_equations, skinned_parts
from bodystudio.reconstruct.tracking import carry_deformed_mesh


def _random_rig(rng, n=60, B=7, K=3, n_seg=4):
    T = np.tile(np.eye(4), (B, 1, 1))
    for b in range(B):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        T[b, :3, :3] = q * rng.uniform(0.9, 1.1)
        T[b, :3, 3] = rng.normal(size=3)
    rest = rng.normal(size=(n, 3))
    bone_idx = np.stack([rng.choice(B, K, replace=False) for _ in range(n)]).astype(np.int64)
    bone_w = rng.uniform(0.0, 1.0, (n, K))
    bone_w[rng.uniform(size=(n, K)) < 0.3] = 0.0  # zero weights are skipped: the sums must not change
    bone_w[:, 0] += 0.1
    bone_w /= bone_w.sum(axis=1, keepdims=True)
    D = (rng.uniform(size=(B, n_seg)) < 0.4).astype(np.float64)
    D[0] = 0.0  # a bone that follows no fitted segment
    heads = rng.normal(size=(n_seg, 3))
    return T, rest, bone_idx, bone_w, D, heads


def test_skinned_parts_equal_the_dense_gather():
    rng = np.random.default_rng(3)
    T, rest, bone_idx, bone_w, _, _ = _random_rig(rng)
    C, V = skinned_parts(T, rest, bone_idx, bone_w)
    rest_h = np.concatenate([rest, np.ones((len(rest), 1))], axis=1).T
    C_ref = bone_w[:, :, None] * (T[:, :3, :] @ rest_h)[bone_idx, :, np.arange(len(rest))[:, None]]
    np.testing.assert_allclose(C, C_ref, atol=1e-13)
    np.testing.assert_allclose(V, C_ref.sum(axis=1), atol=1e-13)
    # dense LBS with the same weights (Eq. 12): sum_k w_k (R_k v + t_k)
    W = np.zeros((len(rest), len(T)))
    np.add.at(W, (np.arange(len(rest))[:, None], bone_idx), bone_w)
    R = np.einsum("nb,bij->nij", W, T[:, :3, :3])
    np.testing.assert_allclose(V, np.einsum("nij,nj->ni", R, rest) + W @ T[:, :3, 3], atol=1e-12)


def test_normal_equations_equal_the_dense_jacobian():
    rng = np.random.default_rng(4)
    T, rest, bone_idx, bone_w, D, heads = _random_rig(rng)
    C, _ = skinned_parts(T, rest, bone_idx, bone_w)
    rows = np.sort(rng.choice(len(rest), 40, replace=False)).astype(np.int64)
    r, w, G = rng.normal(size=40), rng.uniform(0.1, 1.0, 40), rng.normal(size=(40, 3))
    H, g = data_normal_equations(C, bone_idx, bone_w, D, heads, rows, r, w, G)
    # the numpy path it replaced: lever arms of every vertex about every segment's head, the full Jacobian
    W = np.zeros((len(rest), len(T)))
    np.add.at(W, (np.arange(len(rest))[:, None], bone_idx), bone_w)
    a = W @ D
    lever = (C.transpose(0, 2, 1) @ D[bone_idx]).transpose(0, 2, 1) - a[:, :, None] * heads[None]
    J = np.concatenate([G, np.cross(lever[rows], G[:, None, :]).reshape(len(G), -1)], axis=1)
    np.testing.assert_allclose(H, J.T @ (w[:, None] * J), atol=1e-11)
    np.testing.assert_allclose(g, J.T @ (w * r), atol=1e-11)
    assert np.abs(H[3:, 3:]).max() > 1.0  # the rotation blocks are exercised, not only the translation


def test_listed_normal_equations_are_the_scanning_ones_bit_for_bit():
    """rec15i: each row reads its segments from :func:`vertex_segments` (fixed for a fit) instead of scanning all;
    the same ``H`` and ``g`` bit for bit, with zero weights, a bone in no segment and rows repeated."""
    from bodystudio.reconstruct.articulated_fit import data_normal_equations_listed, vertex_segments

    rng = np.random.default_rng(6)
    T, rest, bone_idx, bone_w, D, heads = _random_rig(rng, n=80, n_seg=6)
    bone_idx[0] = 0  # vertex 0 follows bone 0 alone, which is in no segment
    C, _ = skinned_parts(T, rest, bone_idx, bone_w)
    rows = np.r_[rng.choice(np.arange(1, len(rest)), 59, replace=False), [0, 3, 3]].astype(np.int64)
    r, w, G = rng.normal(size=62), rng.uniform(0.1, 1.0, 62), rng.normal(size=(62, 3))
    ptr, seg = vertex_segments(bone_idx, D)
    listed = [set(seg[ptr[i]:ptr[i + 1]]) for i in range(len(rest))]
    assert listed == [{j for j in range(D.shape[1]) if D[bone_idx[i], j].any()} for i in range(len(rest))]
    assert any(not s for s in listed) and any(len(s) > 1 for s in listed)
    H, g = data_normal_equations_listed(C, bone_idx, bone_w, D, heads, rows, r, w, G, ptr, seg)
    H_ref, g_ref = data_normal_equations(C, bone_idx, bone_w, D, heads, rows, r, w, G)
    assert np.array_equal(H, H_ref) and np.array_equal(g, g_ref) and np.abs(H[3:, 3:]).max() > 1.0


def test_carry_deformed_mesh_moves_the_offsets_with_the_pose():
    rng = np.random.default_rng(5)
    P_prev = rng.normal(size=(30, 3))
    offsets = rng.normal(0.0, 0.005, (30, 3))
    P = P_prev + [0.02, -0.01, 0.03]
    np.testing.assert_allclose(carry_deformed_mesh(P_prev + offsets, P_prev, P), P + offsets, atol=1e-15)


def test_pose_template_sparse_skinning_equals_the_dense_blend(body_2k):
    from bodystudio.body.skinning import linear_blend_skinning
    from bodystudio.reconstruct.pose_init import pose_template

    rng = np.random.default_rng(6)
    T = np.tile(np.eye(4), (body_2k.skeleton.n_bones, 1, 1))
    for b in range(len(T)):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        T[b, :3, :3], T[b, :3, 3] = q, rng.normal(0.0, 0.3, 3)
    got = pose_template(body_2k, T).vertices
    np.testing.assert_allclose(got, linear_blend_skinning(body_2k.vertices, body_2k.weights, T), atol=1e-12)
    assert np.abs(got - body_2k.vertices).max() > 0.1


def test_fields_inside_transform_on_the_small_box_equals_the_full_box():
    """SilhouetteFields takes the inside distances on the silhouette's box grown by 1 px (not by the margin):
    the same field as both exact transforms over the whole margin box, also for masks touching the image edge."""
    import cv2

    from bodystudio.geometry.camera import Camera
    from bodystudio.reconstruct.tracking import SilhouetteFields

    H, W, margin = 60, 80, 12
    cams = [Camera.look_at(f"c{i}", (0, 0, 3), (0, 0, 0), fx=100.0, width=W, height=H) for i in range(3)]
    yy, xx = np.mgrid[:H, :W]
    masks = {"c0": ((yy - 30) ** 2 + (xx - 40) ** 2 < 15 ** 2) | ((yy > 20) & (yy < 26) & (xx > 10) & (xx < 70)),
             "c1": (xx < 25) & (yy > 5),  # touches the left and bottom edges
             "c2": ((yy - 10) ** 2 / 4 + (xx - 70) ** 2 < 40) | ((xx > 30) & (xx < 34) & (yy > 40))}
    fields = SilhouetteFields(cams, masks, margin_px=margin)
    for cam in cams:
        full = masks[cam.name]
        ys, xs = np.nonzero(full.any(axis=1))[0], np.nonzero(full.any(axis=0))[0]
        y0, y1 = max(ys[0] - margin, 0), min(ys[-1] + margin + 1, H)
        x0, x1 = max(xs[0] - margin, 0), min(xs[-1] + margin + 1, W)
        inside = full[y0:y1, x0:x1].astype(np.uint8)
        out_d = cv2.distanceTransform(1 - inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        in_d = cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        ref = np.where(inside > 0, 0.5 - in_d, out_d - 0.5)
        assert fields.offset[cam.name] == (x0, y0)
        np.testing.assert_allclose(fields.sdf[cam.name], ref, atol=1e-5)
        assert fields.sdf[cam.name].min() < -3.0  # deep inside pixels are exercised


def _fields_before(cameras, masks, margin):
    """The per-camera fields and packed array as SilhouetteFields built them before the box of
    ``cv2.boundingRect`` and the in-place writes (np.any boxes, separate arrays packed afterwards)."""
    sdfs, offsets = [], []
    for cam in cameras:
        full = np.asarray(masks[cam.name]) > 0
        H, W = full.shape
        ys, xs = np.nonzero(np.any(full, axis=1))[0], np.nonzero(np.any(full, axis=0))[0]
        if len(ys):
            y0, y1 = max(ys[0] - margin, 0), min(ys[-1] + margin + 1, H)
            x0, x1 = max(xs[0] - margin, 0), min(xs[-1] + margin + 1, W)
        else:
            y0, y1, x0, x1 = 0, H, 0, W
        inside = full[y0:y1, x0:x1].astype(np.uint8)
        sdf = cv2.distanceTransform(1 - inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) - np.float32(0.5)
        if len(ys):
            b0, b1 = max(ys[0] - 1, y0), min(ys[-1] + 2, y1)
            a0, a1 = max(xs[0] - 1, x0), min(xs[-1] + 2, x1)
            core = inside[b0 - y0:b1 - y0, a0 - x0:a1 - x0]
            in_d = cv2.distanceTransform(core, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            np.copyto(sdf[b0 - y0:b1 - y0, a0 - x0:a1 - x0], np.float32(0.5) - in_d, where=core > 0)
        sdfs.append(sdf)
        offsets.append((x0, y0))
    packed = np.zeros((len(sdfs), max(s.shape[0] for s in sdfs), max(s.shape[1] for s in sdfs)), np.float32)
    for k, sdf in enumerate(sdfs):
        packed[k, :sdf.shape[0], :sdf.shape[1]] = sdf
    return sdfs, offsets, packed


def test_fields_equal_the_construction_before():
    """rec15c's faster SilhouetteFields (box by cv2.boundingRect, bool masks read as bytes, the transforms
    written into the packed array) gives the fields, offsets and packed array of the construction before:
    bool and 0/255 masks, an empty view, a full view and one touching the image's corner. To a few float32
    ulp, not bit for bit: OpenCV's precise transform itself differs by an ulp from call to call on the same
    input (c2's box: two distinct results in 300 calls on one thread, measured), so any two builds may, and
    the half-pixel shift can double it (1.0000001 and 1.0 become -0.5000001 and -0.5: 2 ulp there)."""
    from bodystudio.reconstruct.tracking import SilhouetteFields

    H, W, margin = 70, 90, 12
    cams = [Camera.look_at(f"c{i}", (0, 0, 3), (0, 0, 0), fx=100.0, width=W, height=H) for i in range(5)]
    yy, xx = np.mgrid[:H, :W]
    masks = {"c0": ((yy - 30) ** 2 + (xx - 40) ** 2 < 15 ** 2) | ((yy > 20) & (yy < 26) & (xx > 10) & (xx < 70)),
             "c1": (xx < 25) & (yy > 5),
             "c2": ((yy - 10) ** 2 / 4 + (xx - 70) ** 2 < 40) | ((xx > 30) & (xx < 34) & (yy > 40)),
             "c3": np.zeros((H, W), bool), "c4": np.ones((H, W), bool)}
    for mk in (masks, {k: v.astype(np.uint8) * 255 for k, v in masks.items()}):
        fields = SilhouetteFields(cams, mk, margin_px=margin)
        sdfs, offsets, packed = _fields_before(cams, mk, margin)
        for cam, sdf, off in zip(cams, sdfs, offsets, strict=True):
            assert fields.offset[cam.name] == off
            assert fields.sdf[cam.name].dtype == np.float32 and fields.sdf[cam.name].shape == sdf.shape
            np.testing.assert_array_max_ulp(fields.sdf[cam.name], sdf, maxulp=4)
        np.testing.assert_array_max_ulp(fields._packed_sdf, packed, maxulp=4)
        np.testing.assert_array_equal(fields._shapes, [s.shape for s in sdfs])
        assert np.array_equal(fields._packed_sdf == 0, packed == 0)  # the padding, and no value lost
    assert fields.sdf["c0"].min() < -5.0 and fields.sdf["c0"].max() > 5.0


def test_fit_stops_when_the_data_energy_plateaus(body_2k, synthetic_capture):
    """``min_decrease``: the articulated fit stops at the first iteration whose data energy fell by less than that
    fraction, and until then takes exactly the steps of the fixed-iteration fit."""
    from test_pose_refine import _perturbed

    from bodystudio.reconstruct.articulated_fit import PoseRefineParams, refine_bone_transforms
    from bodystudio.reconstruct.pose_init import initialise_pose
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, silhouette_data_term

    cap = synthetic_capture
    fields = SilhouetteFields(cap["rig"], cap["masks"])
    T0 = initialise_pose(body_2k, _perturbed(cap["joints"])).bone_transforms
    base = silhouette_data_term(fields, TrackParams())
    energies = []

    def term(V, N):
        out = base(V, N)
        energies.append(float(np.sum(out[2] * out[1] ** 2)))
        return out

    T_full = refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=8), data_term=term)
    full = list(energies)
    assert len(full) == 8  # the step tolerance alone does not stop this fit early
    rel = np.array(full[1:]) / np.array(full[:-1])
    stop = int(np.argmax(rel > 0.9)) + 1  # the first evaluation that fell by less than 10 %
    assert 1 < stop < 8, rel
    energies.clear()
    T_stop = refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=8, min_decrease=0.1),
                                    data_term=term)
    assert len(energies) == stop + 1 and np.allclose(energies, full[:stop + 1])
    T_fixed = refine_bone_transforms(body_2k, T0, None, PoseRefineParams(iterations=stop), data_term=base)
    np.testing.assert_allclose(T_stop, T_fixed, atol=1e-12)
    assert np.abs(T_stop - T_full).max() > 1e-6  # it did stop before the full fit's end


def test_sparse_skin_weights_keep_every_non_zero():
    """More than six influences on a vertex: the sparse blend still equals the dense one."""
    from bodystudio.body.skinning import linear_blend_skinning
    from bodystudio.geometry.skinning import blend_skin, sparse_skin_weights

    rng = np.random.default_rng(7)
    W = rng.uniform(0.0, 1.0, (20, 9))
    W[:10, 4:] = 0.0
    W /= W.sum(axis=1, keepdims=True)
    T, V = _random_rig(rng, n=20, B=9)[:2]
    idx, w = sparse_skin_weights(W, k=None)
    got = blend_skin(np.ascontiguousarray(T[:, :3, :]), np.ascontiguousarray(idx), np.ascontiguousarray(w), V,
                     np.empty((0, 3)))[0]
    np.testing.assert_allclose(got, linear_blend_skinning(V, W, T), atol=1e-12)


def test_kept_constraints_are_the_boolean_selection():
    """``_kept`` (rec15j: the kept rows' ids once and ``take``) selects what boolean indexing selects, in order,
    with and without the optional camera / pixel-distance columns; all kept returns the constraints themselves."""
    from bodystudio.reconstruct.rapid_skin import _kept
    from bodystudio.reconstruct.solver import SilhouetteConstraints

    rng = np.random.default_rng(3)
    m = 200
    full = SilhouetteConstraints(rng.integers(0, 50, m), rng.normal(size=(m, 3)), rng.normal(size=(m, 3)),
                                 rng.random(m), rng.integers(0, 4, m), rng.random(m))
    keep = rng.random(m) > 0.3
    for sil in (full, SilhouetteConstraints(full.vertex, full.origin, full.direction, full.k)):
        out = _kept(sil, keep)
        for name in ("vertex", "origin", "direction", "k", "camera", "pixel_distance"):
            a, b = getattr(out, name), getattr(sil, name)
            assert (a is None and b is None) or np.array_equal(a, b[keep])
        assert _kept(sil, np.ones(m, bool)) is sil
