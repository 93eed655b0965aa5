"""Mutation tests of rec15i / rec15j's set-up of the pose refinement, made once per skeleton (issue 17, branch mutT;
docs/mutation/reconstruct-articulated_fit.md "rec15i / rec15j"): ``_fit_segments_cached`` on a six-bone tree whose
segment bookkeeping is written out by hand (nearest refined ancestors, leaves-first order, subtrees and refined
descendants as lists and CSR, the prior's segments and diagonal), its memo (the same objects on a second call, keyed
by the skeleton object and the bone names, bounded, read only); ``_vertex_segments_cached``'s memo the same way.
"""

import numpy as np
import pytest

from bodystudio.reconstruct import articulated_fit as af

NAMES = ("root", "spine", "neck", "l_arm", "l_fore", "r_arm")
FITTED = ("spine", "l_arm", "l_fore", "r_arm")


class _Skeleton:
    """root -> spine -> (neck, l_arm -> l_fore, r_arm)."""

    parents = np.array([-1, 0, 1, 1, 3, 1])
    n_bones = 6

    def index(self, name):
        return NAMES.index(name)


def test_the_segment_bookkeeping_of_a_small_tree():
    out = af._fit_segments_cached(_Skeleton(), FITTED)
    (bones, D, fitted_parent, order, subtree_bones, child_segments, order_arr, sub_ptr, sub_idx, child_ptr,
     child_idx, prior_segments, prior_diag) = out
    np.testing.assert_array_equal(bones, [1, 3, 4, 5])
    np.testing.assert_array_equal(D, af._subtree_matrix(_Skeleton(), np.array([1, 3, 4, 5])))
    np.testing.assert_array_equal(fitted_parent, [-1, 0, 1, 0])
    assert list(order) == [2, 1, 3, 0]  # deepest first, ties in segment order
    np.testing.assert_array_equal(order_arr, [2, 1, 3, 0])
    assert order_arr.dtype == np.int64
    assert [list(s) for s in subtree_bones] == [[1, 2, 3, 4, 5], [3, 4], [4], [5]]
    assert [list(c) for c in child_segments] == [[0, 1, 2, 3], [1, 2], [2], [3]]
    for arr, want in ((sub_ptr, [0, 5, 7, 8, 9]), (sub_idx, [1, 2, 3, 4, 5, 3, 4, 4, 5]),
                      (child_ptr, [0, 4, 6, 7, 8]), (child_idx, [0, 1, 2, 3, 1, 2, 2, 3])):
        np.testing.assert_array_equal(arr, want)
        assert arr.dtype == np.int64
    np.testing.assert_array_equal(prior_segments, [1, 2, 3])
    np.testing.assert_array_equal(prior_diag, np.arange(6, 15))
    for a in out:
        if isinstance(a, np.ndarray):
            assert not a.flags.writeable
    with pytest.raises(ValueError):
        D[0, 0] = 2.0


def test_the_set_up_is_made_once_per_skeleton_and_bones_and_the_memo_is_bounded():
    af._FIT_SEGMENTS_CACHE.clear()
    skel = _Skeleton()
    first = af._fit_segments_cached(skel, FITTED)
    assert af._fit_segments_cached(skel, FITTED) is first
    assert af._FIT_SEGMENTS_CACHE[(id(skel), FITTED)] == (skel, first)
    other = af._fit_segments_cached(_Skeleton(), FITTED)
    assert other is not first
    np.testing.assert_array_equal(other[2], first[2])
    fewer = af._fit_segments_cached(skel, ("spine", "r_arm"))
    np.testing.assert_array_equal(fewer[2], [-1, 0])
    assert af._fit_segments_cached(skel, FITTED) is first
    # a stale entry (another skeleton object behind a reused id) is not handed out
    af._FIT_SEGMENTS_CACHE[(id(skel), FITTED)] = (_Skeleton(), "stale")
    assert af._fit_segments_cached(skel, FITTED) != "stale"
    af._FIT_SEGMENTS_CACHE.clear()
    keep = [_Skeleton() for _ in range(12)]
    for s in keep:
        af._fit_segments_cached(s, FITTED)
        assert 1 <= len(af._FIT_SEGMENTS_CACHE) <= 8
    assert len(af._FIT_SEGMENTS_CACHE) == 12 - 8


def test_the_vertex_segments_are_made_once_per_skin_and_segments():
    af._SEGMENT_CACHE.clear()
    rng = np.random.default_rng(0)
    bone_idx = rng.integers(0, 6, size=(40, 3)).astype(np.int64)
    D = af._subtree_matrix(_Skeleton(), np.array([1, 3, 4, 5]))
    ptr, seg = af._vertex_segments_cached(bone_idx, D)
    want_ptr, want_seg = af.vertex_segments(bone_idx, D)
    np.testing.assert_array_equal(ptr, want_ptr)
    np.testing.assert_array_equal(seg, want_seg)
    again = af._vertex_segments_cached(bone_idx, D)
    assert again[0] is ptr and again[1] is seg
    assert af._SEGMENT_CACHE[(id(bone_idx), D.shape, D.tobytes())][0] is bone_idx
    D2 = D.copy()
    D2[:, 3] = 0.0  # r_arm no longer fitted: another key, other segments
    ptr2, seg2 = af._vertex_segments_cached(bone_idx, D2)
    assert ptr2 is not ptr and len(seg2) < len(seg)
    af._SEGMENT_CACHE[(id(bone_idx), D.shape, D.tobytes())] = (bone_idx.copy(), "stale", "stale")
    assert af._vertex_segments_cached(bone_idx, D)[1] is not "stale"  # noqa: F632  (a held, different array)
    af._SEGMENT_CACHE.clear()
    keep = [rng.integers(0, 6, size=(5, 3)).astype(np.int64) for _ in range(10)]
    for b in keep:
        af._vertex_segments_cached(b, D)
        assert 1 <= len(af._SEGMENT_CACHE) <= 8
    assert len(af._SEGMENT_CACHE) == 10 - 8
