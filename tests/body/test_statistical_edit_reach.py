"""The semantic edit (Eq. 4 of Real-time Reshaping, then Newton on the mesh) never returns a body it did not make.

Planted cases on the 2k model: full Newton steps from a 17 cm shorter start once diverged (a -568 kg body returned
with exit 0); a step that does not lower the residual is now halved, and an edit the shape space cannot make with
the other measurements held is refused in one line.
"""

import numpy as np
import pytest

from bodystudio.body.statistical import _REACH_FACTOR, _TOLERANCE, MESH_ATTRIBUTE_NAMES, load_statistical_model
from bodystudio.errors import InputError


@pytest.fixture(scope="module")
def sm():
    return load_statistical_model(resolution="2k", progress=False)


@pytest.fixture(scope="module")
def bodies(sm):
    rng = np.random.default_rng(0)
    return [rng.standard_normal(sm.n_components) * sm.stddev * 0.8 for _ in range(3)]


def _off(sm, c0, c, deltas):
    before, after = sm.measure(c0), sm.measure(c)
    return {n: abs(after[n] - before[n] - deltas.get(n, 0.0)) / _TOLERANCE[n] for n in MESH_ATTRIBUTE_NAMES}


def test_a_hard_edit_is_reached_not_overshot(sm, bodies):
    """17 cm shorter, the rest held: full steps ended the hips 1.6 cm off (and 0.6 kg); the halved steps reach it."""
    c0 = bodies[2]
    c = sm.edit(c0, {"stature_m": -0.17})
    off = _off(sm, c0, c, {"stature_m": -0.17})
    assert max(off.values()) <= _REACH_FACTOR, off
    assert off["hip_m"] <= 1.5 and off["stature_m"] <= 1.0


def test_an_unreachable_edit_is_refused_not_returned(sm, bodies):
    """17 cm shorter and 15 kg lighter at the same girths and limb lengths: the full steps diverged to -568 kg."""
    with pytest.raises(InputError, match=r"edit \(stature_m -0.17, mass_kg -15\) is not reachable .* use a smaller"):
        sm.edit(bodies[2], {"stature_m": -0.17, "mass_kg": -15.0})
    with pytest.raises(InputError, match="chest_m ends"):
        sm.edit(np.zeros(sm.n_components), {"stature_m": -0.3})


def test_reachable_edits_hit_every_target(sm, bodies):
    for c0 in bodies:
        for deltas in ({"stature_m": 0.17, "mass_kg": 15.0}, {"stature_m": -0.1, "mass_kg": 10.0},
                       {"mass_kg": -15.0}):
            off = _off(sm, c0, sm.edit(c0, deltas), deltas)
            assert max(off.values()) <= _REACH_FACTOR, (deltas, off)


def test_no_newton_steps_is_the_linear_step_and_never_refused(sm, bodies):
    c = sm.edit(bodies[2], {"stature_m": -0.17, "mass_kg": -15.0}, iterations=0)
    np.testing.assert_allclose(c, bodies[2] + np.array([-0.17, -15.0] + [0.0] * (len(sm.attribute_names) - 2))
                               @ sm.semantic_directions)
