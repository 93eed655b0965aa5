"""Mutation tests (issue 17) of mir12e's cached rest chain of the mirror's one-pass skinning
(``mirror.track._cached_rest_chain``, ``rest_chain``): the cache per skeleton object and its bound, the rest-frame
products against the forward kinematics' definition (seconds)."""

import copy

import numpy as np

from bodystudio.body.statistical import load_statistical_model


def _skeleton():
    model = load_statistical_model("6k", progress=False)
    return model.skeleton(np.zeros(len(model.stddev)))


def test_rest_chain_is_the_parent_relative_rest_frames_and_their_inverses():
    from bodystudio.mirror.track import rest_chain

    sk = _skeleton()
    rel, inv = rest_chain(sk)
    A, parents = sk.rest_frames, np.asarray(sk.parents)
    for j in range(len(parents)):
        want = A[j] if parents[j] < 0 else np.linalg.inv(A[parents[j]]) @ A[j]
        np.testing.assert_allclose(rel[j], want, atol=1e-12)
        np.testing.assert_allclose(inv[j] @ A[j], np.eye(4), atol=1e-12)
    assert (parents < 0).sum() == 1 and not np.allclose(rel, A)  # the children's products are exercised


def test_cached_rest_chain_is_per_skeleton_object_and_bounded():
    from bodystudio.mirror import track

    track._CHAIN_CACHE.clear()
    sk = _skeleton()
    first = track._cached_rest_chain(sk)
    assert track._cached_rest_chain(sk) is first  # a hit returns the cached chain
    assert track._CHAIN_CACHE[id(sk)][0] is sk  # the skeleton is held, so its id is not reused
    other = copy.deepcopy(sk)
    other.rest_frames[:, :3, 3] += 0.1  # another skeleton object: its own chain
    chain = track._cached_rest_chain(other)
    assert chain is not first
    np.testing.assert_allclose(chain[1], track.rest_chain(other)[1], atol=0)
    sizes = []
    for _ in range(20):
        track._cached_rest_chain(copy.copy(sk))
        sizes.append(len(track._CHAIN_CACHE))
    assert min(sizes) >= 1 and max(sizes) == 8  # at most eight skeletons held
