"""trust4's realistic segmentation noise of capture/faults.py (``rewrite_masks`` and the ``mask_*`` generators), on
tiny masks whose noisy versions are known by hand or from an independent construction (issue 17's mutation tests).

tests/reliability/test_reconstruct_mask_noise.py plants this noise into a whole synthetic session and reconstructs
it (minutes); here each generator is checked exactly in milliseconds: the jitter against the analytic signed
distance of a half-plane and of a disc (scipy's exact Euclidean distance) plus scipy's Gaussian filter, the shadow's
ellipse by its extreme pixels, the holes at the positions and radii the random generator drew, the lost limb's
rectangle by hand, the combination in its order, and ``rewrite_masks``' walk over the session's mask files with one
random generator, the manifest restamped.
"""

import hashlib
import json

import cv2
import numpy as np
import pytest
from scipy import ndimage

from bodystudio.capture import faults


def _jitter_reference(m: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(signed distance, field) of ``mask_jitter`` from an independent construction: scipy's exact Euclidean
    distance transform and scipy's Gaussian filter (OpenCV's border reflect-101 is scipy's "mirror", and its kernel
    for sigma 3 reaches 4 sigma, as scipy's), the field scaled to the drawn standard deviation."""
    rng = np.random.default_rng(seed)
    z = rng.normal(size=m.shape).astype(np.float32)
    g = ndimage.gaussian_filter(z.astype(np.float64), 3.0, mode="mirror", truncate=4.0)
    g *= rng.uniform(1.0, 3.0) / g.std()
    signed = ndimage.distance_transform_edt(m) - ndimage.distance_transform_edt(~m)
    return signed, g


def test_jitter_of_a_half_plane_moves_each_row_by_the_smooth_field():
    """A vertical edge (columns 0..39 inside): the signed distance is 40 - c inside and -(c - 39) outside, exactly
    (OpenCV's 5x5 mask is exact along a row); the noisy mask is where it plus the field is positive. The field has the
    drawn standard deviation (1..3 px), zero mean, and is smooth: neighbouring rows' edges move alike."""
    m = np.zeros((80, 80), bool)
    m[:, :40] = True
    c = np.arange(80)
    signed = np.where(c < 40, 40 - c, -(c - 39)).astype(float)[None, :].repeat(80, axis=0)
    for seed in (0, 1, 2):
        _, field = _jitter_reference(m, seed)
        out = faults.mask_jitter(m, "cam_00", 0, np.random.default_rng(seed))
        assert out.dtype == bool and out.shape == m.shape
        sure = np.abs(signed + field) > 1e-4
        assert np.array_equal(out[sure], (signed + field)[sure] > 0)
        assert 1.0 <= field.std() <= 3.0
        # the field moves the outline, far from it nothing changes
        assert out[:, :25].all() and not out[:, 55:].any()
        moved = out.sum(axis=1) - 40
        assert np.abs(moved).max() >= 1 and np.corrcoef(moved[:-1], moved[1:])[0, 1] > 0.8
    m_before = m.copy()
    faults.mask_jitter(m, "cam_00", 0, np.random.default_rng(0))
    assert np.array_equal(m, m_before)


@pytest.mark.parametrize("seed", [3, 4])
def test_jitter_of_a_disc_follows_the_euclidean_signed_distance(seed):
    """A disc of radius 14: the signed distance is Euclidean (OpenCV's 5x5 approximation is within 0.25 px of the
    exact one here; an L1 or chessboard distance is not, on the diagonals)."""
    yy, xx = np.mgrid[:60, :60]
    m = (yy - 30) ** 2 + (xx - 30) ** 2 <= 14 ** 2
    signed, field = _jitter_reference(m, seed)
    out = faults.mask_jitter(m, "cam_03", 5, np.random.default_rng(seed))
    sure = np.abs(signed + field) > 0.3
    assert np.array_equal(out[sure], (signed + field)[sure] > 0)
    assert np.count_nonzero(out != m) > 20  # the outline did move


def test_shadow_is_an_ellipse_under_the_feet_one_and_a_half_body_widths_wide():
    """A body of columns 30..49 (width 19 between its outer pixels) and rows 20..119 (height 99): the shadow is a
    filled ellipse centred at (mean column 39, lowest row 119) with half-axes int(0.75 * 19) = 14 and
    int(0.04 * 99) = 3 pixels, merged into the mask."""
    m = np.zeros((140, 100), bool)
    m[20:120, 30:50] = True
    out = faults.mask_shadow(m, "cam_00", 0, None)
    assert out.dtype == bool and (out >= m).all()
    added = out & ~m
    rows, cols = np.nonzero(added)
    assert (cols.min(), cols.max()) == (39 - 14, 39 + 14)
    assert rows.max() == 119 + 3 and rows.min() >= 119 - 3
    assert out[119, 25:54].all() and not out[119, [24, 54]].any()
    assert out[119:123, 39].all() and not out[123, 39]
    # OpenCV's ellipse, drawn by hand: exactly the union
    want = m.astype(np.uint8).copy()
    cv2.ellipse(want, (39, 119), (14, 3), 0, 0, 360, 1, -1)
    assert np.array_equal(out, want > 0)
    assert not np.array_equal(out, m)


def test_shadow_of_a_short_body_is_at_least_two_pixels_high_and_an_empty_mask_has_none():
    """A body 11 rows high (int(0.04 * 10) = 0): the ellipse is 2 px high, not flat; the mask's mean column, not
    the middle of its extent, centres it; an empty mask stays empty."""
    m = np.zeros((40, 120), bool)
    m[10:21, 20:30] = True
    m[20, 30:60] = True  # a foot to the right: the mean column is 28.8, the middle of the extent 39.5
    ys, xs = np.nonzero(m)
    cx = int(xs.mean())
    assert cx == 28
    out = faults.mask_shadow(m, "cam_01", 2, None)
    want = m.astype(np.uint8).copy()
    cv2.ellipse(want, (cx, 20), (int(0.75 * 39), 2), 0, 0, 360, 1, -1)
    assert np.array_equal(out, want > 0)
    assert out[22, cx] and not out[23, cx]
    empty = np.zeros((8, 9), bool)
    out = faults.mask_shadow(empty, "cam_01", 2, None)
    assert out.shape == (8, 9) and not out.any()


class _Spy:
    """A random generator that records the draws ``mask_holes`` makes."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.calls = []

    def integers(self, *a, **k):
        v = self.rng.integers(*a, **k)
        self.calls.append(("integers", a, int(v)))
        return v

    def choice(self, *a, **k):
        v = self.rng.choice(*a, **k)
        self.calls.append(("choice", a, k, v))
        return v


def test_holes_are_discs_at_mask_pixels_with_the_drawn_count_and_radii():
    """6..12 holes, each a filled disc of radius 2..4 px centred on a distinct pixel of the mask; nothing else
    changes."""
    m = np.zeros((50, 120), bool)
    m[10:40, 5:115] = True
    m[25, :] = False  # not a plain rectangle: the centres are the mask's pixels in np.nonzero's order
    ys, xs = np.nonzero(m)
    for seed in range(6):
        spy = _Spy(seed)
        out = faults.mask_holes(m, "cam_00", 0, spy)
        (_, a, n), (_, ca, ck, idx), *radii = spy.calls
        assert a == (6, 13) and 6 <= n <= 12
        assert ca == (len(ys),) and ck == {"size": n, "replace": False} and len(set(idx.tolist())) == n
        assert len(radii) == n and all(r[1] == (2, 5) and 2 <= r[2] <= 4 for r in radii)
        want = m.astype(np.uint8).copy()
        for i, r in zip(idx, radii, strict=True):
            cv2.circle(want, (int(xs[i]), int(ys[i])), r[2], 0, -1)
        assert out.dtype == bool and np.array_equal(out, want > 0)
        assert (out <= m).all() and np.count_nonzero(m & ~out) >= 13


def test_holes_count_and_sizes_over_seeds_and_an_empty_mask():
    """Over 150 seeds on a large full mask every count 6..12 and every radius 2..4 occurs (discs of 13, 29 and 49
    pixels when apart); an empty mask is returned empty, drawing nothing."""
    m = np.ones((200, 200), bool)
    counts, areas = set(), set()
    for seed in range(150):
        spy = _Spy(seed)
        out = faults.mask_holes(m, "cam_00", 0, spy)
        counts.add(spy.calls[0][2])
        n, labels = cv2.connectedComponents((~out).astype(np.uint8), connectivity=8)
        areas |= set(np.bincount(labels.ravel())[1:].tolist())
    assert counts == set(range(6, 13))
    assert {13, 29, 49} <= areas
    spy = _Spy(0)
    out = faults.mask_holes(np.zeros((5, 6), bool), "cam_00", 0, spy)
    assert out.shape == (5, 6) and not out.any()
    assert spy.calls == []


def test_limb_lost_in_cam_00s_first_frame_only():
    """Body rows 10..109 (height 99), columns 20..69 (width 49): rows int(10 + 14.85) = 24 to int(10 + 54.45) = 64
    (exclusive) of the columns from int(69 - 9.8) = 59 on are cleared, in cam_00's frame 0 only."""
    m = np.zeros((130, 90), bool)
    m[10:110, 20:70] = True
    out = faults.mask_limb_lost(m, "cam_00", 0, None)
    want = m.copy()
    want[24:64, 59:] = False
    assert np.array_equal(out, want)
    assert m[24:64, 59:70].all()  # the input is left alone
    for cam, frame in (("cam_00", 1), ("cam_01", 0), ("cam_10", 3)):
        assert np.array_equal(faults.mask_limb_lost(m, cam, frame, None), m)


def test_limb_lost_bounds_follow_the_mask_not_the_image():
    """An off-centre body (rows 30..69, columns 50..59): rows int(30 + 5.85) = 35 to int(30 + 21.45) = 51,
    columns from int(59 - 1.8) = 57."""
    m = np.zeros((100, 100), bool)
    m[30:70, 50:60] = True
    out = faults.mask_limb_lost(m, "cam_00", 0, None)
    want = m.copy()
    want[35:51, 57:] = False
    assert np.array_equal(out, want)


def test_all_noise_is_jitter_then_shadow_then_holes_then_the_lost_limb():
    yy, xx = np.mgrid[:120, :90]
    m = ((yy - 50) ** 2 / 40 ** 2 + (xx - 45) ** 2 / 15 ** 2) <= 1
    for cam, frame in (("cam_00", 0), ("cam_02", 1)):
        rng = np.random.default_rng(11)
        want = faults.mask_jitter(m, cam, frame, rng)
        want = faults.mask_shadow(want, cam, frame, rng)
        want = faults.mask_holes(want, cam, frame, rng)
        want = faults.mask_limb_lost(want, cam, frame, rng)
        out = faults.mask_all_noise(m, cam, frame, np.random.default_rng(11))
        assert np.array_equal(out, want)
    assert not np.array_equal(faults.mask_all_noise(m, "cam_00", 0, np.random.default_rng(11)),
                              faults.mask_all_noise(m, "cam_00", 1, np.random.default_rng(11)))


# --- rewrite_masks over a session folder -------------------------------------------------------------------------

def _make_session(tmp_path):
    S = tmp_path / "s"
    files = {}

    def put(rel, data: bytes):
        p = S / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
        files[rel] = hashlib.sha256(data).hexdigest()

    rng = np.random.default_rng(0)
    for cam in ("cam_01", "cam_00"):
        for f in ("000003.png", "000000.png"):
            m = (rng.random((6, 8)) > 0.5).astype(np.uint8) * 255
            m[0, 0], m[0, 1] = 1, 0  # any non-zero value is the person
            put(f"{cam}/mask/{f}", cv2.imencode(".png", m)[1].tobytes())
        put(f"{cam}/image/000000.png", cv2.imencode(".png", np.full((6, 8, 3), 9, np.uint8))[1].tobytes())
    put("kinect/depth/000000.png", cv2.imencode(".png", np.full((4, 4), 700, np.uint16))[1].tobytes())
    put("calibration/cameras.json", b"{}")
    (S / "session.json").write_text(json.dumps({"version": 1, "files": files, "subject": "x"}))
    return S


def test_rewrite_masks_applies_the_change_to_every_mask_file_in_order_with_one_generator(tmp_path):
    S = _make_session(tmp_path)
    before = {str(p.relative_to(S)): p.read_bytes() for p in S.rglob("*") if p.is_file()}
    calls = []

    def change(m, cam, frame, rng):
        calls.append((cam, frame, m.copy(), float(rng.random())))
        out = np.zeros(m.shape, bool)  # a bool mask, as the mask_* generators return
        out[:, : 1 + len(calls)] = True
        return out

    faults.rewrite_masks(S, change, seed=5)
    assert [(c[0], c[1]) for c in calls] == [("cam_00", 0), ("cam_00", 3), ("cam_01", 0), ("cam_01", 3)]
    assert [c[3] for c in calls] == list(np.random.default_rng(5).random(4))  # one generator, seeded once
    manifest = json.loads((S / "session.json").read_text())
    assert manifest["version"] == 1 and manifest["subject"] == "x"
    for k, (cam, frame, m, _) in enumerate(calls):
        rel = f"{cam}/mask/{frame:06d}.png"
        src = cv2.imdecode(np.frombuffer(before[rel], np.uint8), cv2.IMREAD_UNCHANGED)
        assert m.dtype == bool and m.shape == (6, 8) and np.array_equal(m, src > 0) and m[0, 0] and not m[0, 1]
        written = cv2.imread(str(S / rel), cv2.IMREAD_UNCHANGED)
        want = np.zeros((6, 8), np.uint8)
        want[:, : 2 + k] = 255
        assert written.dtype == np.uint8 and np.array_equal(written, want)
        assert manifest["files"][rel] == hashlib.sha256((S / rel).read_bytes()).hexdigest()
    for rel, data in before.items():
        if "/mask/" not in rel and rel != "session.json":
            assert (S / rel).read_bytes() == data and manifest["files"][rel] == hashlib.sha256(data).hexdigest()


def test_rewrite_masks_default_seed_is_7_and_a_colour_mask_is_read_as_grey(tmp_path):
    """A mask saved with three channels is read as one grey channel (the change sees a 2-D mask)."""
    S = _make_session(tmp_path)
    rel = "cam_00/mask/000000.png"
    colour = np.zeros((6, 8, 3), np.uint8)
    colour[2:4, 2:5] = 255
    cv2.imwrite(str(S / rel), colour)
    faults.restamp(S, rel)
    seen = {}

    def change(m, cam, frame, rng):
        seen[(cam, frame)] = (m, float(rng.random()))
        return m

    faults.rewrite_masks(S, change)
    m, first = seen[("cam_00", 0)]
    assert m.shape == (6, 8) and m.sum() == 6 and m[2:4, 2:5].all()
    assert first == np.random.default_rng(7).random()
