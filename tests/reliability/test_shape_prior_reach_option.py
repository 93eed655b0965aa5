"""``reconstruct_session(..., shape_prior="carried", shape_prior_reach=X)`` (issue 15, rec15q): the carried shape
prior kept only for initialised frames whose back the silhouettes' rims reach less than X of. Off by default (0);
a share outside [0, 1] (or not finite) and a gate without ``carried`` are one-line errors naming the setting and the
fix, raised before any frame is deformed. Wiring and effect: tests/reconstruct/test_shape_prior_reach.py."""

import inspect

import pytest

import bodystudio.reconstruct.sequence as seq
from bodystudio.errors import InputError
from tests.reconstruct.test_shape_prior_carried import _carried_run


def test_the_gate_is_the_auto_settings():
    """None: the tracked default's gate (0.4) with shape_prior 'auto' and tracking, else 0 (off)."""
    for fn in (seq.reconstruct_session, seq.reconstruct_frames):
        assert inspect.signature(fn).parameters["shape_prior_reach"].default is None
    assert seq.resolve_shape_prior(True)[1] == 0.4 and seq.resolve_shape_prior(True, "carried")[1] == 0.0


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), float("inf")])
def test_a_share_outside_zero_one_is_refused_before_any_frame(monkeypatch, tmp_path, bad):
    with pytest.raises(InputError, match=r"^shape_prior_reach .*: give a share of the back's vertices in \[0, 1\] "
                                         r"\(0: off\)$"):
        _carried_run(monkeypatch, tmp_path, reach=bad)


@pytest.mark.parametrize("prior", ["off", "run", "frame"])
def test_the_gate_needs_the_carried_prior(monkeypatch, tmp_path, prior):
    with pytest.raises(InputError, match=rf"^shape_prior_reach 0.4 gates the carried shape prior; use it with "
                                         rf"shape_prior 'carried' \(not '{prior}'\) or leave it 0$"):
        _carried_run(monkeypatch, tmp_path, reach=0.4, prior=prior)


@pytest.mark.parametrize("ok", [0.0, 0.4, 1.0])
def test_shares_accepted_and_recorded(monkeypatch, tmp_path, ok):
    monkeypatch.setattr(seq, "back_patch", lambda body: None)
    monkeypatch.setattr(seq, "rim_reach", lambda vertices, patch: 0.0)
    _rec, _fits, _poses, writer = _carried_run(monkeypatch, tmp_path, reach=ok)
    assert writer.meta["shape_prior_reach"] == ok
