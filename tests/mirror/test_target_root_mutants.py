"""Mutation tests of MIR12s's ``reshape.TARGET_ROOT`` (docs/mutation/mirror-reshape.md, "MIR12s's target root"): the
module setting read when ``keep_root`` is None, "model" (the root moved by the regressor like every joint) and
"source" (the source's rest root kept), on a stand-in model whose regressor shifts every joint by the coefficients.
< 0.1 s."""
from types import SimpleNamespace as NS

import numpy as np
import pytest

import bodystudio.mirror.reshape as reshape
from bodystudio.body.skeleton import Skeleton

HEADS = np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.5, 0.0]])
TAILS = np.array([[0.0, 0.0, 0.2], [0.0, 1.4, 0.0], [0.0, 1.8, 0.0]])


def _skeleton(shift):
    return Skeleton(("Root", "pelvis", "spine"), np.array([-1, 0, 1]), HEADS + shift, TAILS + shift, np.zeros(3))


@pytest.mark.parametrize("setting, keep_root, kept", [("model", None, False), ("source", None, True),
                                                      ("model", True, True), ("source", False, False)])
def test_the_module_setting_decides_the_root_when_keep_root_is_none(monkeypatch, setting, keep_root, kept):
    monkeypatch.setattr(reshape, "TARGET_ROOT", setting)
    model = NS(skeleton=lambda c: _skeleton(np.asarray(c, dtype=np.float64)))
    source = NS(coeffs=np.zeros(3), skeleton=_skeleton(np.zeros(3)))
    move = np.array([0.01, -0.03, 0.02])
    sk = reshape.target_skeleton(source, None, model, move, keep_root=keep_root)
    np.testing.assert_allclose(sk.heads[1:], HEADS[1:] + move, atol=1e-12)
    np.testing.assert_allclose(sk.heads[0], HEADS[0] + (0.0 if kept else move), atol=1e-12)
    np.testing.assert_allclose(sk.tails[0], TAILS[0] + (0.0 if kept else move), atol=1e-12)
    assert reshape.TARGET_ROOT == setting and setting in ("model", "source")
