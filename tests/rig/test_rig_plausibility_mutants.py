"""Fast analytic tests of the rig's self-check (rig/plausibility.py), for mutation testing (issue 17).

tests/reliability/test_rig_plausibility.py rigs synthetic scans (seconds per case); here hand-made arrays: skin
weights whose largest bone is known (regions, fingers to their hand), a flat square scan with model vertices at
known heights above it (covered within 10 mm or not), and a stand-in fit whose coverage and fit error put the
verdict on each side of every threshold.
"""

from types import SimpleNamespace

import numpy as np
import pytest

BONES = ("root", "spine_01", "head", "neck_01", "hand_l", "hand_r", "foot_l", "ball_l", "foot_r", "ball_r",
         "upperarm_l", "lowerarm_l", "upperarm_r", "lowerarm_r", "thigh_l", "calf_l", "thigh_r", "calf_r",
         "index_01_l", "thumb_03_r", "pinky_02_l", "middle_01_r", "ring_03_l")
WANT = ("torso", "torso", "head", "head", "hand_l", "hand_r", "foot_l", "foot_l", "foot_r", "foot_r",
        "arm_l", "arm_l", "arm_r", "arm_r", "leg_l", "leg_l", "leg_r", "leg_r",
        "hand_l", "hand_r", "hand_l", "hand_r", "hand_l")
REGIONS = ("head", "hand_l", "hand_r", "foot_l", "foot_r", "arm_l", "arm_r", "leg_l", "leg_r", "torso")


def _weights(owners, n_bones=len(BONES)):
    """One vertex per owner: 0.6 on its bone, 0.4 spread over two others."""
    W = np.zeros((len(owners), n_bones))
    for i, b in enumerate(owners):
        W[i, b] = 0.6
        W[i, (b + 1) % n_bones] += 0.25
        W[i, (b + 2) % n_bones] += 0.15
    return W


def test_region_of_vertices_by_largest_weight():
    from bodystudio.rig.plausibility import region_of_vertices

    reg = region_of_vertices(_weights(range(len(BONES))), BONES)
    assert tuple(reg) == REGIONS
    for name in REGIONS:
        assert reg[name].dtype == bool
        np.testing.assert_array_equal(reg[name], np.array(WANT) == name, err_msg=name)
    # a bone missing from the names is skipped; a name that is not a finger (e.g. "indexer") stays torso
    reg = region_of_vertices(_weights([0, 1, 2]), ["root", "indexer_l", "thumbs"])
    assert reg["torso"].tolist() == [True, True, True] and not any(reg[r].any() for r in REGIONS[:-1])


def _scan():
    """A 2 m square at z = 0 (two triangles)."""
    V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    return V, np.array([[0, 1, 2], [0, 2, 3]])


def test_region_coverage_within_ten_mm():
    from bodystudio.rig.plausibility import region_coverage

    V, F = _scan()
    z = np.array([0.0, 0.0099, 0.0100, 0.0101, 0.05, -0.0099, 0.3, 0.002])
    M = np.c_[np.linspace(-0.5, 0.5, len(z)), np.zeros(len(z)), z]
    regions = {"a": np.array([1, 1, 1, 1, 0, 0, 0, 0], bool), "b": np.array([0, 0, 0, 0, 1, 1, 1, 1], bool),
               "empty": np.zeros(8, bool), "all": np.ones(8, bool)}
    cov = region_coverage(M, regions, V, F.astype(np.int32))
    assert cov["a"] == pytest.approx(0.75) and cov["b"] == pytest.approx(0.5) and cov["all"] == pytest.approx(5 / 8)
    assert np.isnan(cov["empty"])
    assert set(cov) == set(regions)
    assert all(isinstance(v, float) for v in cov.values())


class _Fit:
    """A stand-in fit: one vertex per region label in ``labels``, at ``height`` m above the square scan."""

    def __init__(self, labels, heights, p90=2.0, median=1.0):
        owner = {r: BONES.index(b) for r, b in (("torso", "root"), ("head", "head"), ("hand_l", "hand_l"),
                                                ("hand_r", "hand_r"), ("foot_l", "foot_l"), ("foot_r", "foot_r"),
                                                ("arm_l", "upperarm_l"), ("arm_r", "upperarm_r"),
                                                ("leg_l", "thigh_l"), ("leg_r", "thigh_r"))}
        self.weights = _weights([owner[r] for r in labels])
        self.skeleton = SimpleNamespace(bone_names=BONES)
        self.vertices = np.c_[np.linspace(-0.5, 0.5, len(labels)), np.zeros(len(labels)), heights]
        self.fit_err_mm_p90, self.fit_err_mm_median = p90, median


def _fit(cov, p90=2.0, median=1.0):
    """Ten vertices per region in ``cov`` (share ``cov[r]`` covered), ten covered torso vertices."""
    labels, heights = [], []
    for r, c in {**cov, "torso": cov.get("torso", 1.0)}.items():
        k = int(round(10 * c))
        labels += [r] * 10
        heights += [0.0] * k + [0.05] * (10 - k)
    return _Fit(labels, np.array(heights), p90, median)


def test_whole_scan_is_ok():
    from bodystudio.rig import plausibility as rp

    V, F = _scan()
    v = rp.rig_plausibility(_fit({"head": 1.0, "foot_l": 0.9}, p90=6.0, median=1.5), V, F, "scan.ply")
    assert v["ok"] is True and v["warnings"] == [] and v["problems"] == []
    assert v["thresholds"] == {"covered_mm": 10.0, "fit_p90_refuse_mm": 10.0, "fit_p90_warn_mm": 6.0,
                               "region_missing": 0.4, "region_warn": 0.6}
    assert v["coverage"]["head"] == 1.0 and v["coverage"]["foot_l"] == pytest.approx(0.9)
    assert v["coverage"]["hand_r"] is None  # no vertex in the region
    assert v["fit_err_mm_median"] == 1.5 and v["fit_err_mm_p90"] == 6.0
    assert set(v["coverage"]) == set(REGIONS)


def test_missing_regions_are_a_problem_listed_lowest_first():
    from bodystudio.rig import plausibility as rp

    V, F = _scan()
    v = rp.rig_plausibility(_fit({"foot_l": 0.3, "foot_r": 0.0, "head": 0.4, "hand_l": 0.5}, p90=14.5, median=4.9),
                            V, F, "nofeet.ply")
    assert v["ok"] is False and v["warnings"] == []
    assert v["problems"] == [
        "nofeet.ply has no feet: the fitted body's foot_r 0.00, foot_l 0.30 of its skin has no scan surface within "
        "10 mm (a whole scan: >= 0.72), so the skeleton there is invented (fit error p90 14.5 mm); rescan the whole "
        "person (cut off by the scanner's volume or floor?)"]
    v = rp.rig_plausibility(_fit({"head": 0.3, "leg_l": 0.2, "arm_r": 0.1, "hand_r": 0.0}), V, F)
    assert v["problems"][0].startswith(
        "the scan has no arms and no hands and no head and no legs: the fitted body's hand_r 0.00, arm_r 0.10, "
        "leg_l 0.20, head 0.30 of its skin")
    v = rp.rig_plausibility(_fit({"torso": 0.3}), V, F)
    assert v["problems"][0].startswith("the scan has no trunk: the fitted body's torso 0.30")


def test_fit_error_refuses_and_warns():
    from bodystudio.rig import plausibility as rp

    V, F = _scan()
    v = rp.rig_plausibility(_fit({"head": 1.0}, p90=10.01, median=4.25), V, F, "pose.ply")
    assert v["ok"] is False and v["warnings"] == []
    assert v["problems"] == [
        "the body model does not fit pose.ply (fit error 4.2 mm median, 10.0 mm at the 90th percentile; a whole "
        "person standing in an A or T pose: <= 2.5 mm): the person is in another pose than the fit can find (arms "
        "above the head, sitting, crossed limbs) or part of the scan is not the person; scan them standing in an A "
        "or T pose"]
    v = rp.rig_plausibility(_fit({"head": 1.0}, p90=10.0), V, F)
    assert v["ok"] is True and v["problems"] == []
    assert v["warnings"] == ["the fit error's 90th percentile is 10.0 mm (a whole person in an A or T pose: <= 2.5 mm):"
                             " a limb may sit in the wrong place; check the avatar"]
    v = rp.rig_plausibility(_fit({"head": 1.0}, p90=6.01), V, F)
    assert len(v["warnings"]) == 1 and v["ok"] is True
    # a missing region wins over the fit error (one problem, the region's)
    v = rp.rig_plausibility(_fit({"head": 0.0}, p90=30.0), V, F)
    assert len(v["problems"]) == 1 and "has no head" in v["problems"][0]


def test_weak_regions_warn_between_the_thresholds():
    from bodystudio.rig import plausibility as rp

    V, F = _scan()
    v = rp.rig_plausibility(_fit({"head": 0.6, "foot_l": 0.5, "hand_r": 0.4, "leg_r": 0.7}), V, F)
    assert v["ok"] is True and v["problems"] == []
    assert v["warnings"] == ["the scan covers little of the fitted body's hand_r (0.40), foot_l (0.50): holes or a "
                             "part cut off there"]
    v = rp.rig_plausibility(_fit({"foot_l": 0.5}, p90=7.0), V, F)
    assert len(v["warnings"]) == 2 and v["warnings"][0].startswith("the fit error's 90th percentile is 7.0 mm")
    assert v["warnings"][1].startswith("the scan covers little of the fitted body's foot_l (0.50)")


def test_part_names():
    from bodystudio.rig.plausibility import _part_name

    assert [_part_name(r) for r in REGIONS] == ["head", "hands", "hands", "feet", "feet", "arms", "arms", "legs",
                                                "legs", "trunk"]


def test_check_rig_raises_unless_accepted():
    from bodystudio.errors import ImplausibleResultError
    from bodystudio.rig import plausibility as rp

    V, F = _scan()
    bad = _fit({"head": 0.0})
    with pytest.raises(ImplausibleResultError) as e:
        rp.check_rig(bad, V, F, "nohead.ply")
    msg = str(e.value)
    assert msg.startswith("nohead.ply: avatar not written, nohead.ply has no head: ")
    assert msg.endswith("; or pass --accept-implausible") and "\n" not in msg
    v = rp.check_rig(bad, V, F, "nohead.ply", accept_implausible=True)
    assert v["ok"] is False and v["problems"][0].startswith("nohead.ply has no head")
    v = rp.check_rig(_fit({"foot_l": 0.5}), V, F, "scan.ply")
    assert v["ok"] is True and len(v["warnings"]) == 1
    assert rp.COVERED_MM == 10.0
