"""MLS warp (Eq. 5 of Real-time Reshaping; Schaefer et al. 2006 closed forms) against answers known in closed form.

Each test builds its own small handle layout, so it runs in well under a second: the similarity / rigid
closed forms against the complex-number formula written out per point, degenerate (collinear) handles,
the grid field's region of interest and per-person groups, and the foreground warp's edge colours; a person
cut by the image's edge, moved into the image, goes on beyond it (MIR12g).
"""

import cv2
import numpy as np
import pytest

from bodystudio.errors import InputError
from bodystudio.mirror.warp import (
    EPS_PX2,
    OUTSIDE_PX,
    edge_clamped,
    mls_grid_nodes,
    mls_transforms,
    mls_warp_field,
    rim_vertices,
    visible_vertex_pairs,
    warp_foreground,
)


def _handles(n=40, seed=0, lo=(100, 60), hi=(500, 420)):
    return np.random.default_rng(seed).uniform(lo, hi, (n, 2))


def _direct_similarity(v, p, q, alpha, rigid):
    """Eq. 5 with similarity (rigid) M for one point ``v``, in complex numbers: ``M(x) = (x - p*) z + q*`` with
    ``z = sum w conj(p^) q^ / sum w |p^|^2`` (``z / |z|`` for rigid), ``w = 1 / (|v - p|^2 + eps)^alpha``."""
    w = 1.0 / (np.sum((v - p) ** 2, axis=1) + EPS_PX2) ** alpha
    ps, qs = w @ p / w.sum(), w @ q / w.sum()
    ph = (p - ps) @ np.array([1.0, 1j])
    qh = (q - qs) @ np.array([1.0, 1j])
    z = np.sum(w * np.conj(ph) * qh) / np.sum(w * np.abs(ph) ** 2)
    if rigid:
        z /= abs(z)
    out = ((v - ps) @ np.array([1.0, 1j])) * z
    return np.array([out.real, out.imag]) + qs


@pytest.mark.parametrize("kind", ["similarity", "rigid"])
@pytest.mark.parametrize("alpha", [1.0, 2.0])
def test_similarity_and_rigid_match_the_closed_form_written_out(kind, alpha):
    """A non-similar deformation (noise on every handle): each point's transform is the weighted complex fit."""
    p = _handles(25, seed=11)
    q = p @ np.array([[1.1, 0.3], [-0.2, 0.95]]) + np.random.default_rng(12).normal(0, 6, p.shape)
    v = np.random.default_rng(13).uniform(80, 520, (40, 2))
    lin, mapped = mls_transforms(v, p, q, kind, alpha=alpha)
    for k in range(len(v)):
        np.testing.assert_allclose(mapped[k], _direct_similarity(v[k], p, q, alpha, kind == "rigid"), atol=1e-7)
    # the linear part is the scaled rotation [[zr, zi], [-zi, zr]] (row vectors)
    np.testing.assert_allclose(lin[:, 0, 0], lin[:, 1, 1], atol=1e-12)
    np.testing.assert_allclose(lin[:, 0, 1], -lin[:, 1, 0], atol=1e-12)
    # the local sums over a radius that holds every handle are the global ones
    _, local = mls_transforms(v, p, q, kind, alpha=alpha, radius_px=2000.0)
    np.testing.assert_allclose(local, mapped, atol=1e-8)


@pytest.mark.parametrize("kind", ["affine", "similarity", "rigid"])
def test_handles_map_onto_their_targets_to_the_eps_regularisation(kind):
    """A point on a handle has weight 1/eps^alpha = 10^6 against < 10^-6 for the others (>= 5 px apart)."""
    p = np.array([[100.0, 100.0], [140.0, 105.0], [120.0, 150.0], [90.0, 160.0], [160.0, 140.0]])
    q = p + np.array([[3.0, -2.0], [-4.0, 1.0], [2.0, 5.0], [0.0, -3.0], [1.0, 1.0]])
    _, mapped = mls_transforms(p, p, q, kind, alpha=2.0)
    np.testing.assert_allclose(mapped, q, atol=1e-5)
    # and the handles shifted by 1e-3 still land there: the transform varies smoothly
    _, near = mls_transforms(p + 1e-3, p, q, kind, alpha=2.0)
    np.testing.assert_allclose(near, q, atol=1e-2)


@pytest.mark.parametrize("kind", ["similarity", "rigid"])
def test_a_global_similarity_is_reproduced_by_the_field_everywhere_in_the_region(kind):
    p = _handles(30, seed=14)
    th = np.deg2rad(-11.0)
    s = 1.0 if kind == "rigid" else 0.9
    R = s * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    b = np.array([-6.0, 4.0])
    # backward field: output pixel x' samples the input at M(x') with M mapping target -> source points
    field = mls_warp_field(p @ R.T + b, p, kind=kind, alpha=2.0, roi_margin_px=1000, radius_px=32.0)
    rows, cols = np.mgrid[5:475:23, 7:635:29]
    pix = np.stack([cols.ravel(), rows.ravel()], 1).astype(float)
    expect = pix @ R.T + b
    seen = (expect > OUTSIDE_PX + 1).all(1)  # sources left of / above the image are clamped to OUTSIDE_PX
    assert seen.mean() > 0.9
    np.testing.assert_allclose(field[rows.ravel(), cols.ravel()][seen], expect[seen], atol=2e-3)
    np.testing.assert_array_equal(field[rows.ravel(), cols.ravel()][(expect < OUTSIDE_PX).all(1)], OUTSIDE_PX)


def test_collinear_handles_have_no_affine_fit_and_leave_the_field_outside():
    """Handles on one line: the affine moment matrix is singular, the similarity one is not."""
    t = np.linspace(0, 1, 12)
    p = np.c_[200 + 200 * t, 240 + 0 * t]
    q = p + np.array([5.0, 3.0])
    v = np.array([[300.0, 250.0], [260.0, 200.0]])
    lin, mapped = mls_transforms(v, p, q, "affine")
    assert np.isnan(mapped).all() and np.isnan(lin).all()
    _, sim = mls_transforms(v, p, q, "similarity")
    np.testing.assert_allclose(sim, v + [5.0, 3.0], atol=1e-8)
    # nearly collinear (1e-4 px off the line) is still a fit
    p2 = p + np.c_[0 * t, 1e-4 * np.sin(7 * t)]
    _, ok = mls_transforms(v, p2, p2 + [5.0, 3.0], "affine")
    assert np.isfinite(ok).all()
    field = mls_warp_field(q, p, kind="affine", roi_margin_px=40)
    assert np.all(field == OUTSIDE_PX)
    field = mls_warp_field(q, p, kind="similarity", roi_margin_px=40)
    np.testing.assert_allclose(field[240, 300], [305.0, 243.0], atol=1e-3)


def test_the_field_is_solved_only_within_the_margin_of_the_target_points():
    """Nodes within roi_margin_px (+1 node) of a target point carry the warp; pixels beyond map outside."""
    p = np.array([[300.0, 240.0], [330.0, 240.0], [315.0, 270.0], [300.0, 265.0]])
    field = mls_warp_field(p + [4.0, -2.0], p, kind="similarity", roi_margin_px=40)
    rows, cols = np.mgrid[0:480, 0:640]
    d = np.min(np.hypot(cols[..., None] - p[:, 0], rows[..., None] - p[:, 1]), axis=2)
    solved = np.all(field != OUTSIDE_PX, axis=2)
    inside = d < 36  # within the margin less the two half-cells of rounding
    expect = np.stack([cols, rows], -1) + np.array([4.0, -2.0])
    np.testing.assert_allclose(field[inside], expect[inside], atol=1e-3)
    assert solved[inside].all()
    assert not solved[d > 40 + 2 * 4 * np.sqrt(2) + 4].any()  # margin + reach cell + bilinear support
    assert solved.sum() < 1.6 * np.count_nonzero(d < 48)
    # a margin of 8 px: the region shrinks accordingly
    small = np.all(mls_warp_field(p + [4.0, -2.0], p, kind="similarity", roi_margin_px=8) != OUTSIDE_PX, axis=2)
    assert small[d < 4].all() and not small[d > 8 + 2 * 4 * np.sqrt(2) + 4].any()
    assert small.sum() < 0.5 * solved.sum()


def test_each_person_is_warped_by_their_own_pairs():
    """Two groups of pairs, one moved +6 px in x, the other -5 px in y: each region takes its own translation
    exactly; with one group for all, the nodes of one person feel the other's pairs (alpha 1: 1/d^2 weights)."""
    a = _handles(12, seed=21, lo=(100, 150), hi=(200, 300))
    b = _handles(12, seed=22, lo=(300, 150), hi=(400, 300))
    t = np.vstack([a, b])
    s = np.vstack([a + [6.0, 0.0], b + [0.0, -5.0]])
    groups = np.r_[np.zeros(12, int), np.full(12, 7)]
    rows, cols = np.mgrid[160:290:7, 110:190:7]
    field = mls_warp_field(s, t, kind="similarity", alpha=1.0, roi_margin_px=60, groups=groups)
    np.testing.assert_allclose(field[rows, cols], np.stack([cols + 6.0, rows + 0.0], -1), atol=1e-3)
    np.testing.assert_allclose(field[rows, cols + 200], np.stack([cols + 200.0, rows - 5.0], -1), atol=1e-3)
    mixed = mls_warp_field(s, t, kind="similarity", alpha=1.0, roi_margin_px=60)
    assert np.abs(mixed[rows, cols] - np.stack([cols + 6.0, rows + 0.0], -1)).max() > 0.1
    # a group with fewer than 3 pairs is not solved: its region maps outside, the other group's is unchanged
    few = np.r_[np.zeros(12, int), np.full(10, 2), [1, 1]]
    t2 = np.vstack([a, b[:10], [[470.0, 420.0], [480.0, 425.0]]])
    s2 = np.vstack([a + [6.0, 0.0], b[:10] + [0.0, -5.0], [[470.0, 420.0], [480.0, 425.0]]])
    f2 = mls_warp_field(s2, t2, kind="similarity", alpha=2.0, roi_margin_px=20, groups=few)
    assert np.all(f2[422, 475] == OUTSIDE_PX)
    ij = np.round(b[:10]).astype(int)
    np.testing.assert_allclose(f2[ij[:, 1], ij[:, 0]], ij + np.array([0.0, -5.0]), atol=1e-3)


def test_non_finite_pairs_are_dropped_with_their_group_labels():
    a = _handles(6, seed=31, lo=(100, 150), hi=(200, 300))
    b = _handles(6, seed=32, lo=(420, 150), hi=(520, 300))
    t = np.vstack([[np.nan, np.nan], a, b])
    s = np.vstack([[1.0, 1.0], a + [6.0, 0.0], b + [0.0, -5.0]])
    groups = np.r_[1, np.zeros(6, int), np.ones(6, int)]
    field = mls_warp_field(s, t, kind="similarity", alpha=2.0, roi_margin_px=30, groups=groups)
    ij = np.round(b).astype(int)
    np.testing.assert_allclose(field[ij[:, 1], ij[:, 0]], ij + np.array([0.0, -5.0]), atol=1e-3)
    ij = np.round(a).astype(int)
    np.testing.assert_allclose(field[ij[:, 1], ij[:, 0]], ij + np.array([6.0, 0.0]), atol=1e-3)
    with pytest.raises(InputError, match="group labels"):
        mls_warp_field(s, t, groups=groups[:-1])
    # a non-finite source point drops its pair the same way
    s2, t2 = np.vstack([[np.inf, 0.0], s[1:]]), np.vstack([[300.0, 300.0], t[1:]])
    np.testing.assert_array_equal(mls_warp_field(s2, t2, kind="similarity", alpha=2.0, roi_margin_px=30,
                                                 groups=groups), field)


def test_grid_nodes_on_a_non_square_grid():
    xs, ys = mls_grid_nodes((48, 64), (12, 32))  # 2 px per column, 4 px per row
    np.testing.assert_allclose(xs, 2.0 * np.arange(32) + 0.5)
    np.testing.assert_allclose(ys, 4.0 * np.arange(12) + 1.5)
    # the default is the mirror's 160 x 120 grid on 640 x 480
    xs, ys = mls_grid_nodes()
    np.testing.assert_allclose(ys[[0, -1]], [1.5, 477.5])
    np.testing.assert_allclose(xs[[0, -1]], [1.5, 637.5])


def test_field_on_a_small_image_and_grid():
    """Another image and grid size than the mirror's: the field is still the affine map, up-sampled exactly."""
    p = _handles(20, seed=41, lo=(10, 8), hi=(110, 80))
    A = np.array([[1.05, -0.04], [0.02, 0.97]])
    field = mls_warp_field(p @ A.T + [2.0, -1.0], p, shape=(90, 120), grid=(30, 40), kind="affine",
                           roi_margin_px=500)
    assert field.shape == (90, 120, 2)
    rows, cols = np.mgrid[4:86:9, 4:116:11]
    pix = np.stack([cols.ravel(), rows.ravel()], 1).astype(float)
    np.testing.assert_allclose(field[rows.ravel(), cols.ravel()], pix @ A.T + [2.0, -1.0], atol=1e-3)
    with pytest.raises(InputError, match="grid"):
        mls_warp_field(p, p, shape=(90, 120), grid=(30, 121))
    with pytest.raises(InputError, match="grid"):
        mls_warp_field(p, p, shape=(0, 120), grid=(30, 40))


def _shift_field(h, w, dx, dy):
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    return np.stack([cols - dx, rows - dy], -1).astype(np.float32)


def test_foreground_warp_moves_colour_and_alpha_and_keeps_edges_the_persons_colour():
    """A red square on green moved by (2.5, 0) px: alpha is the moved mask with half-covered edge columns, and the
    edge pixels stay pure red (the background is never dragged in), not the half-dark premultiplied colour."""
    h, w = 40, 50
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[...] = (0, 200, 0)
    mask = np.zeros((h, w), bool)
    mask[10:30, 10:30] = True
    rgb[mask] = (220, 30, 10)
    out, alpha = warp_foreground(rgb, mask, _shift_field(h, w, 2.5, 0.0))
    assert alpha.dtype == np.float32 and out.dtype == np.uint8
    np.testing.assert_allclose(alpha[20, 13:32], 1.0, atol=1e-6)
    np.testing.assert_allclose(alpha[20, [12, 32]], 0.5, atol=0.01)
    assert alpha[20, 11] == 0 and alpha[20, 33] == 0
    inside = alpha > 0
    assert np.abs(out[inside].astype(int) - (220, 30, 10)).max() <= 1
    assert np.all(out[~inside] == 0)
    # the identity field returns the foreground unchanged
    out0, alpha0 = warp_foreground(rgb, mask, _shift_field(h, w, 0.0, 0.0))
    np.testing.assert_array_equal(alpha0, mask.astype(np.float32))
    np.testing.assert_array_equal(out0[mask], rgb[mask])
    # a field pointing outside the image shows nothing
    out1, alpha1 = warp_foreground(rgb, mask, np.full((h, w, 2), OUTSIDE_PX, np.float32))
    assert not alpha1.any() and not out1.any()


def test_rim_vertices_of_a_cylinder_by_the_default_cosine():
    """A cylinder seen side-on from far away: |cos| < 0.3 (the default) is the band of vertices within asin(0.3)
    of the silhouette, 2 x 2 x asin(0.3) / 2 pi = 19.4 % of the columns."""
    n, m = 72, 5
    th = np.arange(n) * 2 * np.pi / n
    V = np.array([[np.cos(t), y, np.sin(t)] for y in np.linspace(-1, 1, m) for t in th])
    F = []
    for r in range(m - 1):
        for c in range(n):
            a, b, cc, d = r * n + c, r * n + (c + 1) % n, (r + 1) * n + c, (r + 1) * n + (c + 1) % n
            F += [[a, cc, b], [b, cc, d]]
    F = np.array(F)
    eye = np.array([0.0, 0.0, 1e4])
    ids = rim_vertices(V, F, eye)
    cos_true = np.abs(np.sin(th))  # normal (cos t, 0, sin t), ray along z
    expect = np.flatnonzero(np.tile(cos_true < 0.3, m))
    np.testing.assert_array_equal(ids, expect)
    assert len(ids) == m * np.count_nonzero(cos_true < 0.3)
    # an eye 3.6 radii from the axis: the ray is V - eye (n . (V - eye) = 1 - 3.6 sin t): another band
    eye = np.array([0.0, 0.0, 3.6])
    ray = V - eye
    cos_near = np.abs(np.einsum("ij,ij->i", V * [1, 0, 1], ray)) / np.linalg.norm(ray, axis=1)
    assert np.min(np.abs(cos_near - 0.3)) > 0.005  # no vertex at the threshold
    np.testing.assert_array_equal(rim_vertices(V, F, eye), np.flatnonzero(cos_near < 0.3))
    assert not np.array_equal(np.flatnonzero(cos_near < 0.3), expect)


def _grid(half, n, z):
    u = np.linspace(-half, half, n)
    X, Y = np.meshgrid(u, u)
    V = np.c_[X.ravel(), Y.ravel(), np.full(n * n, z)]
    F = []
    for r in range(n - 1):
        for c in range(n):
            if c < n - 1:
                a = r * n + c
                F += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return V, np.array(F)


def _occluder_scene(half=0.3):
    """A 0.6 m square (``half`` 0.3) at 2 m in front of a 2 m square at 3 m; an off-centre 320 x 200 camera at the
    origin looking down +z. The front square hides the back one within |x|, |y| < 0.45 m."""
    from bodystudio.geometry.camera import Camera

    Vf, Ff = _grid(half, 11, 2.0)
    Vb, Fb = _grid(1.0, 21, 3.0)
    V = np.vstack([Vf, Vb])
    F = np.vstack([Ff, Fb + len(Vf)])
    K = np.array([[200.0, 0.0, 150.0], [0.0, 200.0, 110.0], [0.0, 0.0, 1.0]])
    cam = Camera("c", K, np.zeros(5), np.eye(3), np.zeros(3), 320, 200)
    return V, F, cam, len(Vf)


def test_visible_pairs_keep_the_front_and_drop_what_it_hides():
    V, F, cam, n_front = _occluder_scene()
    shift = np.array([0.02, -0.01, 0.0])  # the target a little moved: both bodies are tested for visibility
    s, t, ids = visible_vertex_pairs(V, V + shift, F, cam)
    assert s.shape == t.shape == (len(ids), 2)
    np.testing.assert_allclose(s, cam.project(V[ids]), atol=1e-9)
    np.testing.assert_allclose(t, cam.project(V[ids] + shift), atol=1e-9)
    back = np.arange(n_front, len(V))
    cheb = np.abs(V[back, :2]).max(1)
    kept = np.isin(np.arange(len(V)), ids)
    assert kept[:n_front].all()  # the front square is seen whole
    assert not kept[back[cheb < 0.25]].any()  # 4 quarter-size pixels inside the hidden region
    assert kept[back[cheb > 0.7]].all()  # and 4 outside it
    # evenly spread ids: the first and the last vertex among 10
    _, _, few = visible_vertex_pairs(V, V, F, cam, n_handles=10)
    np.testing.assert_array_equal(few, np.linspace(0, len(V) - 1, 10).round().astype(int)[kept[
        np.linspace(0, len(V) - 1, 10).round().astype(int)]])
    assert few[0] == 0 and few[-1] == len(V) - 1
    # rim vertices are added to the spread ones (0, 280, 561): with rim_cos 1 every vertex but the one seen
    # exactly head-on (the front square's centre, id 60)
    _, _, every = visible_vertex_pairs(V, V, F, cam)
    _, _, rim = visible_vertex_pairs(V, V, F, cam, n_handles=3, rim_cos=1.0)
    np.testing.assert_array_equal(rim, np.setdiff1d(every, [60]))
    # a body outside the image gives no pairs
    _, _, none = visible_vertex_pairs(V + [5.0, 0.0, 0.0], V + [5.0, 0.0, 0.0], F, cam)
    assert len(none) == 0


def test_visible_pairs_validate_their_inputs():
    V, F, cam, _ = _occluder_scene()
    with pytest.raises(InputError, match=r"source and target vertices must both be \(n, 3\)"):
        visible_vertex_pairs(V[:, :2], V[:, :2], F, cam)
    with pytest.raises(InputError, match=r"must both be \(n, 3\), got \(562, 3\) and \(561, 3\)"):
        visible_vertex_pairs(V, V[:-1], F, cam)
    for bad in (0.0, -0.1, 1.01):
        with pytest.raises(InputError, match=r"rim_cos must lie in \(0, 1\]"):
            visible_vertex_pairs(V, V, F, cam, rim_cos=bad)


@pytest.mark.parametrize("half, cols, rows", [(0.32, (29, 46), (19, 36)), (0.29, (29, 45), (19, 35))])
def test_visibility_is_judged_on_the_quarter_size_z_buffer_pixel_and_its_8_neighbours(half, cols, rows):
    """Lines of back vertices (3 m) across the front square's (2 m) edges: a vertex is hidden when its pixel of
    the quarter-size z-buffer or one of the 8 around it shows the front square. The 0.64 m front square covers the
    quarter-size pixels whose centres it contains: columns 30..45 and rows 20..35 (its edges fall at 29.125 and
    45.125, 19.125 and 35.125, so a buffer a quarter pixel off moves them past a centre), and a back vertex is
    dropped exactly when its pixel lies in columns 29..46 and rows 19..36. The 0.58 m square's left and top edges
    fall at 29.875 and 19.875 instead (covering 30..44, 20..34): a buffer a quarter pixel off the other way shows
    there."""
    V, F, cam, _ = _occluder_scene(half)
    steps = np.arange(-0.9, 0.9, 0.0123)
    probes = np.vstack([np.c_[steps, 0 * steps, 3 + 0 * steps], np.c_[0 * steps, steps, 3 + 0 * steps]])
    Vp = np.vstack([V, probes])
    _, _, ids = visible_vertex_pairs(Vp, Vp, F, cam, n_handles=len(Vp))
    uv = cam.project(probes)
    fc, fr = (uv[:, 0] + 0.5) * 0.25 - 0.5, (uv[:, 1] + 0.5) * 0.25 - 0.5  # quarter-size pixel coordinates
    col, row = np.round(fc), np.round(fr)
    hidden = (col >= cols[0]) & (col <= cols[1]) & (row >= rows[0]) & (row <= rows[1])
    clear = (np.abs(np.abs(fc - np.floor(fc)) - 0.5) > 0.03) & (np.abs(np.abs(fr - np.floor(fr)) - 0.5) > 0.03)
    kept = np.isin(len(V) + np.arange(len(probes)), ids)
    assert clear.sum() > 0.8 * len(probes) and hidden.sum() > 40 and (~hidden).sum() > 100
    np.testing.assert_array_equal(kept[clear], ~hidden[clear])


def test_visible_pairs_need_both_bodies_to_show_the_vertex_and_the_image_to_hold_it():
    """A vertex hidden in the source body only is dropped (both bodies must see it); vertices exactly on the first
    and last pixel centres are kept, a quarter pixel beyond them dropped; a near occluder (0.9 m) hides what is
    behind it; a vertex in the camera's plane (z = 0) is dropped without spoiling the others."""
    from bodystudio.geometry.camera import Camera

    V, F, cam, n_front = _occluder_scene()
    away = V.copy()
    away[:n_front, 0] += 30.0  # the target's front square far out of view: the back is all visible in the target
    _, _, ids = visible_vertex_pairs(V, away, F, cam)
    back = np.arange(n_front, len(V))
    hidden = back[np.abs(V[back, :2]).max(1) < 0.25]
    assert len(hidden) > 5 and not np.isin(hidden, ids).any()
    _, _, ids_t = visible_vertex_pairs(away, V, F, cam)  # and the other way round
    assert not np.isin(hidden, ids_t).any()

    K = np.array([[256.0, 0.0, 159.5], [0.0, 256.0, 99.5], [0.0, 0.0, 1.0]])
    cam = Camera("edge", K, np.zeros(5), np.eye(3), np.zeros(3), 320, 200)
    tri = np.array([[-0.05, -0.05, 0.9], [0.05, -0.05, 0.9], [0.0, 0.05, 0.9]])  # a small occluder at 0.9 m
    # x / z * 256 + 159.5 lands on u = 0 and 319 exactly for x = -+1.24609375 (z = 2); 0.25 px more is outside
    xs = np.array([-159.75, -159.5, -159.25, 159.25, 159.5, 159.75]) / 128.0
    ys = np.array([-99.75, -99.5, -99.25, 99.25, 99.5, 99.75]) / 128.0
    probes = np.vstack([np.c_[xs, 0 * xs, 2 + 0 * xs], np.c_[0 * ys, ys, 2 + 0 * ys],
                        [[0.0, 0.0, 1.5], [0.2, 0.1, 0.5], [0.1, 0.1, 0.0],
                         [0.2, 0.1, -2.0], [0.0, 3.0, 1.0]]])  # behind the camera; far below the image
    Vp = np.vstack([tri, probes])
    s, _, ids = visible_vertex_pairs(Vp, Vp, np.array([[0, 1, 2]]), cam, n_handles=len(Vp))
    uv = cam.project(probes[:12])
    np.testing.assert_allclose(uv[[1, 4], 0], [0.0, 319.0], atol=0)
    np.testing.assert_allclose(uv[[7, 10], 1], [0.0, 199.0], atol=0)
    # kept: the triangle, the probes on the first / last centres (1, 2, 3, 4 of x; 7, 8, 9, 10 of y) and the
    # vertex at 0.5 m in front of everything; dropped: those beyond, the one behind the triangle, the one at z = 0
    want = [0, 1, 2] + [3 + k for k in (1, 2, 3, 4, 7, 8, 9, 10, 13)]
    np.testing.assert_array_equal(ids, want)


def test_foreground_warp_refuses_images_of_other_shapes():
    mask = np.zeros((40, 50), bool)
    field = np.zeros((40, 50, 2), np.float32)
    for rgb in (np.zeros((40, 50), np.uint8), np.zeros((40, 50, 4), np.uint8)):
        with pytest.raises(InputError, match=r"^warp_foreground: image .* must share the image size \(H, W, 3\) / "
                                             r"\(H, W\) / \(H, W, 2\)$"):
            warp_foreground(rgb, mask, field)
    with pytest.raises(InputError, match="image size"):
        warp_foreground(np.zeros((40, 50, 3), np.uint8), mask, field[:, :49])


@pytest.mark.parametrize("shade", [0, 255])
def test_a_black_or_white_person_keeps_its_exact_shade_at_the_warped_edges(shade):
    """Premultiplied colour divided by the warped coverage: for black (0) and white (255) the division is exact,
    so every pixel the warped person covers, edges included, has the person's shade, at any sub-pixel shift."""
    h, w = 40, 50
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[...] = (0, 200, 0) if shade == 255 else (90, 200, 160)
    mask = np.zeros((h, w), bool)
    mask[10:30, 10:30] = True
    rgb[mask] = shade
    for dx, dy in ((0.1, 0.3), (0.5, 0.5), (0.9, 0.25)):
        out, alpha = warp_foreground(rgb, mask, _shift_field(h, w, dx, dy))
        edge = (alpha > 0) & (alpha < 1)
        assert edge.sum() > 40
        assert np.all(out[alpha > 0] == shade)


def test_field_defaults_and_grid_validation():
    """The defaults are Eq. 5's weights 1 / d^2 (alpha 1) and a 24 px margin; a grid must have 2..H rows and
    2..W columns; any positive radius is accepted."""
    p = _handles(25, seed=51)
    q = p + np.random.default_rng(52).normal(0, 4, p.shape)
    field = mls_warp_field(q, p, kind="similarity")
    np.testing.assert_array_equal(field, mls_warp_field(q, p, kind="similarity", roi_margin_px=24.0, alpha=1.0))
    assert not np.array_equal(field, mls_warp_field(q, p, kind="similarity", roi_margin_px=25.0, alpha=1.0))
    assert not np.array_equal(field, mls_warp_field(q, p, kind="similarity", roi_margin_px=24.0, alpha=2.0))
    for grid in ((120, 1), (481, 160), (120, 641), (1, 160)):
        with pytest.raises(InputError, match="grid"):
            mls_warp_field(q, p, grid=grid)
    assert mls_warp_field(q, p, grid=(480, 640), roi_margin_px=4).shape == (480, 640, 2)
    assert np.isfinite(mls_warp_field(q, p, kind="similarity", alpha=2.0, radius_px=0.5)).all()


def test_target_points_beyond_the_image_edges_solve_the_edge_nodes_only():
    """Handles straddling the top-left and the bottom-right corners (some outside the image): the nodes at those
    corners carry the translation, the other two corners, far from every handle, stay outside; a 2 x 2 grid is
    the coarsest allowed."""
    rng = np.random.default_rng(61)
    tl = rng.uniform([-40, -30], [60, 50], (15, 2))
    br = rng.uniform([580, 430], [680, 520], (15, 2))
    p = np.vstack([tl, br])
    groups = np.r_[np.zeros(15, int), np.ones(15, int)]
    field = mls_warp_field(p + [3.0, -2.0], p, kind="similarity", groups=groups)
    for r, c in ((2, 2), (2, 5), (477, 637), (470, 630)):  # the outer 1.5 px take the edge node (resize)
        np.testing.assert_allclose(field[r, c], [c + 3.0, r - 2.0], atol=1e-3)
    for r, c in ((0, 639), (479, 0), (240, 320)):
        assert np.all(field[r, c] == OUTSIDE_PX)
    coarse = mls_warp_field(p + [3.0, -2.0], p, grid=(2, 2), kind="similarity", groups=groups, roi_margin_px=1000)
    assert coarse.shape == (480, 640, 2)


def test_local_sums_are_eq5_over_the_handles_within_the_radius():
    """With radius_px the sums run over the handles within that distance only (when there are 3 or more): the
    same closed form as written out over that subset, and not the all-handle result."""
    p = _handles(40, seed=71)
    q = p @ np.array([[1.05, 0.1], [-0.08, 0.97]]) + np.random.default_rng(72).normal(0, 5, p.shape)
    v = np.random.default_rng(73).uniform(150, 450, (12, 2))
    radius = 120.0
    for kind in ("similarity", "rigid"):
        _, local = mls_transforms(v, p, q, kind, alpha=1.0, radius_px=radius)
        _, full = mls_transforms(v, p, q, kind, alpha=1.0)
        for k in range(len(v)):
            near = np.linalg.norm(p - v[k], axis=1) <= radius
            assert near.sum() >= 3
            np.testing.assert_allclose(local[k], _direct_similarity(v[k], p[near], q[near], 1.0, kind == "rigid"),
                                       atol=1e-7)
        assert np.abs(local - full).max() > 0.1
    # the field passes its radius on
    t = _handles(30, seed=74)
    s = t + np.random.default_rng(75).normal(0, 5, t.shape)
    f_local = mls_warp_field(s, t, kind="similarity", roi_margin_px=30, radius_px=40.0)
    f_full = mls_warp_field(s, t, kind="similarity", roi_margin_px=30)
    assert np.abs(f_local - f_full).max() > 0.05


def test_mls_transforms_defaults_and_validation():
    p = _handles(12, seed=81)
    q = p + np.random.default_rng(82).normal(0, 4, p.shape)
    v = _handles(5, seed=83)
    lin, mapped = mls_transforms(v, p, q)  # affine, alpha 1, every handle
    lin1, mapped1 = mls_transforms(v, p, q, "affine", alpha=1.0, radius_px=None)
    np.testing.assert_array_equal(mapped, mapped1)
    assert not np.allclose(mapped, mls_transforms(v, p, q, "similarity")[1])
    assert not np.allclose(mapped, mls_transforms(v, p, q, "affine", alpha=2.0)[1])
    # one point as a flat pair is one point
    np.testing.assert_allclose(mls_transforms(v[0], p, q)[1], mapped[:1])
    with pytest.raises(InputError, match=r"MLS kind 'bilinear'; valid: affine, similarity, rigid"):
        mls_transforms(v, p, q, "bilinear")
    for radius in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match=r"MLS radius_px must be a positive number of pixels \(or None"):
            mls_transforms(v, p, q, radius_px=radius)
    assert np.isfinite(mls_transforms(v, p, q, "similarity", radius_px=0.5)[1]).all()
    # exactly 3 pairs are enough; (n, 3) points are refused
    _, three = mls_transforms(v, p[:3], p[:3] + 2.0, "similarity")
    np.testing.assert_allclose(three, v + 2.0, atol=1e-9)
    with pytest.raises(InputError, match=r"same shape \(n, 2\)"):
        mls_transforms(v, np.c_[p, p[:, :1]], np.c_[q, q[:, :1]])
    with pytest.raises(InputError, match="at least 3 finite point pairs, got 2"):
        mls_transforms(v, p[:2], q[:2])


def test_a_group_of_three_pairs_is_solved_and_nodes_at_exactly_the_reach_are_in():
    """Three pairs are a group's minimum; a line of handles makes the nodes at exactly reach = 24 / 4 + 1 = 7
    cells solved, so the pixels between 6 and 7 cells out carry the warp."""
    a = np.array([[200.0, 200.0], [230.0, 210.0], [215.0, 240.0]])
    b = _handles(10, seed=91, lo=(400, 150), hi=(500, 300))
    groups = np.r_[0, 0, 0, np.ones(10, int)]
    field = mls_warp_field(np.vstack([a + [4.0, 1.0], b]), np.vstack([a, b]), kind="similarity", groups=groups)
    np.testing.assert_allclose(field[215, 215], [219.0, 216.0], atol=1e-3)
    line = np.c_[np.full(81, 320.0), np.arange(200.0, 281.0)]  # node column 80 (pixel 321.5)
    field = mls_warp_field(line + [2.0, 0.0], line, kind="similarity")
    # pixel 347 lies between node columns 86 and 87 (345.5, 349.5): 6 and exactly 7 cells from the line
    np.testing.assert_allclose(field[240, 347], [349.0, 240.0], atol=1e-3)
    assert np.all(field[240, 352] == OUTSIDE_PX)  # between 7 and 8 cells: outside


def test_visible_pairs_take_800_evenly_spread_candidates_by_default():
    """A 900-vertex wall in full view: the default candidates are the 800 ids of linspace(0, 899, 800), rounded."""
    V, F = _grid(1.0, 30, 3.0)
    cam = _occluder_scene()[2]
    _, _, ids = visible_vertex_pairs(V, V, F, cam)
    np.testing.assert_array_equal(ids, np.unique(np.linspace(0, 899, 800).round().astype(int)))


def test_a_person_cut_by_the_image_edge_goes_on_beyond_it_when_moved_into_the_image():
    """MIR12g: a person whose body is cut by the left edge (columns 0-49, rows 100-299) moved 10 px to the right:
    the warped silhouette is columns 0-59, the edge's pixels standing in for the body beyond it (before: a 10 px
    gap along the edge); a field pointing farther out than EDGE_REACH_PX, or at OUTSIDE_PX (no foreground), stays
    empty. The identity field and the unclamped remap fail it."""
    H, W = 480, 640
    fg = np.zeros((H, W), bool)
    fg[100:300, :50] = True
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[fg] = (200, 120, 40)
    rgb[100:300, 0] = (10, 220, 30)  # the edge column's colour fills what lies beyond it
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)

    def shifted(dx):
        return np.stack([xs - dx, ys], axis=-1)

    want = np.zeros_like(fg)
    want[100:300, :60] = True
    colour, alpha = warp_foreground(rgb, fg, shifted(10.0))
    warped = alpha > 0.5
    assert (warped == want).mean() > 0.999 and warped[100:300, :10].all()
    assert (colour[150, :9] == (10, 220, 30)).all() and (colour[150, 20] == (200, 120, 40)).all()
    assert not (warp_foreground(rgb, fg, np.stack([xs, ys], -1))[1][100:300, 50:60] > 0.5).any()  # identity
    unclamped = cv2.remap(fg.astype(np.uint8), shifted(10.0), None, cv2.INTER_LINEAR, borderValue=0)
    assert not unclamped[100:300, :9].any()  # what the remap alone gives: the gap
    # farther out than the reach: no foreground (the field's own limit on the left)
    far = warp_foreground(rgb, fg, shifted(30.0))[1] > 0.5
    assert not far[100:300, :13].any() and far[100:300, 17:80].all()
    # OUTSIDE_PX marks no foreground, even next to the edge
    field = shifted(10.0)
    field[:, :10] = OUTSIDE_PX
    assert not (warp_foreground(rgb, fg, field)[1][:, :10] > 0).any()
    # the other three edges: a body cut by the top, right and bottom edge moved 10 px into the image
    for sl, d, grown in (((slice(0, 50), slice(200, 400)), (0.0, 10.0), (slice(0, 60), slice(200, 400))),
                         ((slice(100, 300), slice(590, W)), (-10.0, 0.0), (slice(100, 300), slice(580, W))),
                         ((slice(430, H), slice(200, 400)), (0.0, -10.0), (slice(420, H), slice(200, 400)))):
        cut = np.zeros_like(fg)
        cut[sl] = True
        moved = np.stack([xs - d[0], ys - d[1]], axis=-1)
        a = warp_foreground(rgb, cut, moved)[1] > 0.5
        expected = np.zeros_like(fg)
        expected[grown] = True
        assert (a == expected).mean() > 0.999 and a[grown].all(), d
    # the clamp leaves a field inside the image as it is (the same array), and copies before it changes one
    inside = shifted(0.0)
    assert edge_clamped(inside, (H, W)) is inside
    moved = shifted(10.0)
    before = moved.copy()
    edge_clamped(moved, (H, W))
    assert np.array_equal(moved, before)
