"""Analytic tests of the muscle deformation ground truth (bodystudio.muscle.synthetic; issue 17).

The arm is a hand-made bent tube (no body model): the upper arm runs along +x from the shoulder (0, 1.4, 0) to
the elbow (0.3, 1.4, 0), radius 4 cm, rings every 2.5 cm (``t`` = 0, 1/12, ..., 1 along it); the forearm leaves
the elbow 30 deg towards +z, so the anterior direction ``a`` (the forearm made orthogonal to the upper arm) is +z
and the lateral direction is +y. A vertex at ring angle ``theta`` sits at (x, 1.4 + r cos, r sin): its radial
direction ``r`` has ``r.a = sin(theta)`` and ``r.lateral = cos(theta)``. With a chosen ``MuscleVariation`` each
term of the model in the module docstring (Gaussian belly along ``t``, ``max(0, r.a)^2`` profile, smoothstep
activation, amplitude from muscularity and BMI, skin slide, forearm counter-twist) has a closed form at single
vertices, which the tests compare to 1e-12 m.
"""

from functools import lru_cache

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bodystudio.body import Phenotype
from bodystudio.errors import InputError
from bodystudio.geometry.mesh import Mesh
from bodystudio.muscle import synthetic as syn
from bodystudio.muscle.arm import ArmPose, ArmTemplate

N_RING, RADIUS, STEP, L_U = 16, 0.04, 0.025, 0.3
S, E = np.array([0.0, 1.4, 0.0]), np.array([0.3, 1.4, 0.0])
F_DIR = np.array([np.cos(np.radians(30.0)), 0.0, np.sin(np.radians(30.0))])
W = E + 0.25 * F_DIR
TH = 2 * np.pi * np.arange(N_RING) / N_RING


@lru_cache(maxsize=2)
def _arm(side="left"):
    """Rings 0..12 on the upper arm (x = 0..0.3), rings 13..22 on the forearm (s = 0.1..1 of elbow-wrist)."""
    ring_pts = []
    for x in STEP * np.arange(13):
        ring_pts.append(np.c_[np.full(N_RING, x), 1.4 + RADIUS * np.cos(TH), RADIUS * np.sin(TH)])
    e2 = np.cross(F_DIR, [0.0, 1.0, 0.0])  # forearm ring frame: (0, 1, 0) and F x y
    for s in np.linspace(0.1, 1.0, 10):
        c = E + 0.25 * s * F_DIR
        ring_pts.append(c + RADIUS * (np.outer(np.cos(TH), [0.0, 1.0, 0.0]) - np.outer(np.sin(TH), e2)))
    V = np.concatenate(ring_pts)
    joints = np.stack([S, E, W])
    if side == "right":  # the mirror image in x = 0
        V, joints = V * [-1.0, 1.0, 1.0], joints * [-1.0, 1.0, 1.0]
    n_len = len(ring_pts)
    F = []
    for i in range(n_len - 1):
        for j in range(N_RING):
            a, b = i * N_RING + j, i * N_RING + (j + 1) % N_RING
            F += [[a, a + N_RING, b], [b, a + N_RING, b + N_RING]]
    F = np.array(F, np.int64)
    ring = np.repeat(np.arange(n_len), N_RING)
    part = np.where(ring == 0, 0, np.where(ring <= 12, 1, 2))
    T = ArmTemplate(np.arange(len(V)), F, V, np.eye(4)[part], joints, part > 0, side, "2k")
    N = Mesh(V, F).vertex_normals
    if np.einsum("kd,kd->k", N[ring == 6], V[ring == 6] - 0.5 * (joints[0] + joints[1])).mean() < 0:
        F = F[:, ::-1].copy()
        T = ArmTemplate(T.vertex_ids, F, V, T.part_weights, T.joints, T.arm_mask, side, "2k")
    return T


def _vid(ring, j):
    return ring * N_RING + j


def _subject(muscularity=1.0, bmi=21.0, seed=0):
    return syn.ArmSubject(seed, 1.0, Phenotype(), {}, bmi=bmi, muscularity=muscularity)


def _variation(**kw):
    base = dict(biceps_center=0.5 + 0.06, triceps_center=0.5, deltoid_center=0.25, width_scale=1.0,
                amplitudes=(1.0, 1.0, 1.0), thresholds_deg=(35.0, 0.0, 100.0), exponents=(1.7, 1.7, 1.7),
                anterior_twist_rad=0.0, slide=1.0)
    return syn.MuscleVariation(**{**base, **kw})


def _normals(T):
    return Mesh(T.vertices, T.faces).vertex_normals


U = np.array([1.0, 0.0, 0.0])
MIRROR = np.array([-1.0, 1.0, 1.0])


def _axes(side):
    """(u, f, elbow) of the left tube or of its mirror image."""
    return (U, F_DIR, E) if side == "left" else (U * MIRROR, F_DIR * MIRROR, E * MIRROR)


# ------------------------------------------------------------------------------------------- the angles

def test_rest_axes_and_angles_of_the_bent_tube():
    T = _arm()
    u, f, a = syn._rest_axes(T)
    np.testing.assert_allclose(u, U, atol=1e-15)
    np.testing.assert_allclose(f, F_DIR, atol=1e-15)
    np.testing.assert_allclose(a, [0.0, 0.0, 1.0], atol=1e-15)
    rest = syn.anatomical_angles(T, ArmPose.rest())
    # flexion 30 (the forearm's bend), elevation 90 (the upper arm is horizontal), no twist
    assert (rest.flexion_deg, rest.elevation_deg, rest.pronation_deg) == pytest.approx((30.0, 90.0, 0.0), abs=1e-9)


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize("flex, elev, pron, fwd", [(140.0, 45.0, 0.0, 0.0), (20.0, 95.0, -25.0, 10.0),
                                                    (90.0, 30.0, 60.0, 0.0), (90.0, 60.0, 170.0, 0.0),
                                                    (90.0, 60.0, -170.0, 0.0)])
def test_anatomical_angles_read_back_the_angles_a_pose_was_made_from(side, flex, elev, pron, fwd):
    T = _arm(side)
    ap = syn.arm_pose_from_angles(T, flex, elev, pron, fwd)
    got = syn.anatomical_angles(T, ap)
    assert got.flexion_deg == pytest.approx(flex, abs=1e-6)
    assert got.pronation_deg == pytest.approx(pron, abs=1e-6)
    if fwd == 0.0:
        assert got.elevation_deg == pytest.approx(elev, abs=1e-6)
    # the elbow turns about u x f by flex - 30 deg (then twists about f): the forearm axis ends at flex from u
    R_e = Rotation.from_rotvec(ap.angles[1])
    u, f, _ = _axes(side)
    assert np.degrees(np.arccos(u @ R_e.apply(f))) == pytest.approx(flex, abs=1e-6)
    assert np.all(ap.angles[2] == 0.0) and np.array_equal(ap.root, np.eye(4))


def test_shoulder_elevation_is_abduction_about_z_and_forward_flexion_about_minus_x():
    T = _arm()
    R = Rotation.from_rotvec(syn._shoulder_rotvec(T, 50.0)).as_matrix()
    # rest elevation 90: 50 deg lowers the arm by 40 deg about +z (left side)
    np.testing.assert_allclose(R, Rotation.from_rotvec([0.0, 0.0, np.radians(-40.0)]).as_matrix(), atol=1e-12)
    R = Rotation.from_rotvec(syn._shoulder_rotvec(T, 90.0, 20.0)).as_matrix()
    np.testing.assert_allclose(R, Rotation.from_rotvec([np.radians(-20.0), 0.0, 0.0]).as_matrix(), atol=1e-12)
    R = Rotation.from_rotvec(syn._shoulder_rotvec(_arm("right"), 50.0)).as_matrix()
    np.testing.assert_allclose(R, Rotation.from_rotvec([0.0, 0.0, np.radians(40.0)]).as_matrix(), atol=1e-12)
    root = np.eye(4)
    root[:3, 3] = [0.1, 0.2, 0.3]
    np.testing.assert_array_equal(syn.arm_pose_from_angles(T, 90.0, 90.0, root=root).root, root)


def test_elbow_rotation_flexes_about_u_cross_f_then_twists_about_f():
    T = _arm()
    axis = np.cross(U, F_DIR) / np.linalg.norm(np.cross(U, F_DIR))
    want = Rotation.from_rotvec(axis * np.radians(50.0)) * Rotation.from_rotvec(F_DIR * np.radians(20.0))
    np.testing.assert_allclose(syn._elbow_rotvec(T, 80.0, 20.0), want.as_rotvec(), atol=1e-12)
    u_r, f_r, _ = _axes("right")
    axis_r = np.cross(u_r, f_r) / np.linalg.norm(np.cross(u_r, f_r))
    want_r = Rotation.from_rotvec(axis_r * np.radians(50.0)) * Rotation.from_rotvec(f_r * np.radians(-20.0))
    np.testing.assert_allclose(syn._elbow_rotvec(_arm("right"), 80.0, 20.0), want_r.as_rotvec(), atol=1e-12)


# ------------------------------------------------------------------------------------- activation, amplitude

def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def test_activations_are_smoothsteps_past_each_onset_with_the_persons_exponent():
    var = _variation(thresholds_deg=(35.0, 60.0, 40.0), exponents=(1.7, 3.4, 0.85))
    act = syn.muscle_activations(syn.ArmAngles(35.0 + 0.25 * 105.0, 40.0 + 0.5 * 60.0, 0.0), var)
    np.testing.assert_allclose(act, [_smoothstep(0.25), 0.0, _smoothstep(0.5) ** 0.5], atol=1e-15)
    act = syn.muscle_activations(syn.ArmAngles(60.0 - 0.75 * 60.0, 20.0, 0.0), var)
    np.testing.assert_allclose(act, [0.0, _smoothstep(0.75) ** 2, 0.0], atol=1e-15)
    # saturation: past the end of the range the activation stays 1
    np.testing.assert_allclose(syn.muscle_activations(syn.ArmAngles(175.0, 130.0, 0.0), var), [1, 0, 1], atol=0)
    np.testing.assert_allclose(syn.muscle_activations(syn.ArmAngles(-30.0, 20.0, 0.0), var), [0, 1, 0], atol=0)
    assert _smoothstep(0.25) == pytest.approx(0.15625)


@pytest.mark.parametrize("m, bmi, want", [(1.0, 21.0, 1.0), (0.0, 21.0, 0.2), (1.0, 28.0, 0.5), (1.0, 18.0, 1.0),
                                          (0.5, 24.5, (0.2 + 0.8 * 0.5 ** 1.3) / 1.5)])
def test_amplitude_rises_with_muscularity_and_fat_damps_it(m, bmi, want):
    assert syn.muscle_amplitude_m(_subject(m, bmi)) == pytest.approx(want, abs=1e-15)


# ------------------------------------------------------------------------------------------- the bulges

def _flexed(T, flex, elev=90.0, pron=0.0):
    return syn.arm_pose_from_angles(T, flex, elev, pron)


def test_biceps_bulge_is_the_full_amplitude_on_the_anterior_line_at_the_belly():
    """Full flexion (activation 1): the belly moved 0.06 towards the shoulder (t = 0.5, ring 6); on the anterior
    line (theta 90) the displacement is 2 cm along the normal, at 45 deg half of it (max(0, r.a)^2), behind 0."""
    T = _arm()
    N = _normals(T)
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 140.0), _variation())
    np.testing.assert_allclose(d[_vid(6, 4)], 0.02 * N[_vid(6, 4)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(6, 2)], 0.01 * N[_vid(6, 2)], atol=1e-12)
    np.testing.assert_array_equal(d[_vid(6, 12)], 0.0)
    np.testing.assert_array_equal(d[_vid(6, 0)], 0.0)  # lateral (theta 0): r.a = 0
    assert np.abs(d).max() == pytest.approx(0.02, abs=2e-3)


def test_biceps_belly_is_a_gaussian_along_the_arm_and_the_skin_slides_towards_it():
    """Two rings from the belly (t - c_b = 1/6 = 0.22 w with w = 0.7576): exp(-1) of the bulge along the normal,
    and the skin slides towards the belly: - SKIN_SLIDE * slide * act * (t - c_b) * L_u * exp(-((t-c_b)/0.4)^2) u."""
    w = (1.0 / 6.0) / 0.22
    T = _arm()
    N = _normals(T)
    var = _variation(width_scale=w, slide=0.7)
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 140.0), var)
    for ring, dt in ((8, 1.0 / 6.0), (4, -1.0 / 6.0)):
        k = _vid(ring, 4)
        slide = -syn.SKIN_SLIDE * 0.7 * dt * L_U * np.exp(-(dt / 0.4) ** 2) * U
        np.testing.assert_allclose(d[k], 0.02 * np.exp(-1.0) * N[k] + slide, atol=1e-12)
    assert abs(d[_vid(8, 4)] @ U) > 1e-3  # the slide is millimetres


def test_half_flexion_bulges_by_the_smoothstep_and_the_belly_moves_half_as_far():
    """Flexion 35 + 52.5 deg: activation smoothstep(0.5) ** (2.2 / 1.7); the belly 0.03 towards the shoulder, so
    on ring 6 (t = 0.5, c_b = 0.53) the bulge is exp(-(0.03 / 0.22)^2) of the peak and the skin slides by
    - SKIN_SLIDE * act * (-0.03) * L_u * exp(-(0.03 / 0.4)^2)."""
    T = _arm()
    N = _normals(T)
    var = _variation(exponents=(2.2, 1.7, 1.7))
    act = _smoothstep(0.5) ** (2.2 / 1.7)
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 35.0 + 52.5), var)
    dt = 0.5 - (0.56 - 0.06 * act)
    k = _vid(6, 4)
    want = (0.02 * act * np.exp(-(dt / 0.22) ** 2) * N[k]
            - syn.SKIN_SLIDE * act * dt * L_U * np.exp(-(dt / 0.4) ** 2) * U)
    np.testing.assert_allclose(d[k], want, atol=1e-12)


def test_no_muscle_is_active_below_its_onset_and_the_arm_then_does_not_move():
    T = _arm()
    var = _variation(thresholds_deg=(35.0, 30.0, 100.0))
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 32.0), var)
    np.testing.assert_array_equal(d, 0.0)


def test_bulge_scales_with_the_amplitude_factors_and_is_damped_and_widened_by_fat():
    T = _arm()
    N = _normals(T)
    k = _vid(6, 4)
    d = syn.muscle_displacement(T, _subject(muscularity=0.0), _flexed(T, 140.0), _variation(amplitudes=(0.9, 1, 1)))
    np.testing.assert_allclose(d[k], 0.2 * 0.9 * 0.02 * N[k], atol=1e-12)
    # BMI 28: amplitude / 2, width * (1 + 0.3 * 0.7): two rings off the belly the Gaussian is wider
    w = 1.0 + 0.3 * 0.7
    d = syn.muscle_displacement(T, _subject(bmi=28.0), _flexed(T, 140.0), _variation())
    np.testing.assert_allclose(d[k], 0.5 * 0.02 * N[k], atol=1e-12)
    dt = 1.0 / 6.0
    k2 = _vid(8, 4)
    slide = -syn.SKIN_SLIDE * dt * L_U * np.exp(-(dt / 0.4) ** 2) * 0.5 * U
    np.testing.assert_allclose(d[k2], 0.5 * 0.02 * np.exp(-(dt / (0.22 * w)) ** 2) * N[k2] + slide, atol=1e-12)


def test_the_anterior_direction_turns_with_the_persons_twist():
    """A twist of 22.5 deg about u moves the biceps line from theta 90 to theta 112.5 (ring index 5)."""
    T = _arm()
    N = _normals(T)
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 140.0), _variation(anterior_twist_rad=np.radians(22.5)))
    np.testing.assert_allclose(d[_vid(6, 5)], 0.02 * N[_vid(6, 5)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(6, 4)], 0.02 * np.cos(np.radians(22.5)) ** 2 * N[_vid(6, 4)], atol=1e-12)


def test_triceps_bulges_behind_at_extension():
    """Flexion 0 with the triceps onset at 60: activation 1; behind (theta 270) on its belly ring: 1.2 cm."""
    T = _arm()
    N = _normals(T)
    var = _variation(thresholds_deg=(200.0, 60.0, 100.0), triceps_center=0.5, width_scale=(1 / 6) / 0.25,
                     amplitudes=(1.0, 0.8, 0.7))
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 0.0), var)
    np.testing.assert_allclose(d[_vid(6, 12)], 0.8 * 0.012 * N[_vid(6, 12)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(6, 10)], 0.8 * 0.006 * N[_vid(6, 10)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(8, 12)], 0.8 * 0.012 * np.exp(-1.0) * N[_vid(8, 12)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(7, 12)], 0.8 * 0.012 * np.exp(-0.25) * N[_vid(7, 12)], atol=1e-12)
    np.testing.assert_array_equal(d[_vid(6, 4)], 0.0)


def test_deltoid_caps_the_lateral_side_near_the_shoulder():
    """Elevation 90 with the onset at 30: activation 1; on the lateral line (theta 0, r.lateral = 1) at its centre
    (t = 0.25, ring 3) 9 mm, at 45 deg cos(45)^1.5 of it, below the arm nothing; hand-weighted skin is spared."""
    T = _arm()
    N = _normals(T)
    var = _variation(thresholds_deg=(200.0, -10.0, 30.0), deltoid_center=0.25, width_scale=(1 / 6) / 0.2,
                     amplitudes=(1.0, 1.0, 0.7))
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 30.0), var)
    np.testing.assert_allclose(d[_vid(3, 0)], 0.7 * 0.009 * N[_vid(3, 0)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(3, 2)], 0.7 * 0.009 * np.cos(np.pi / 4) ** 1.5 * N[_vid(3, 2)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(5, 0)], 0.7 * 0.009 * np.exp(-1.0) * N[_vid(5, 0)], atol=1e-12)
    np.testing.assert_allclose(d[_vid(4, 0)], 0.7 * 0.009 * np.exp(-0.25) * N[_vid(4, 0)], atol=1e-12)
    var = _variation(thresholds_deg=(200.0, -10.0, 30.0), deltoid_center=0.25, width_scale=(1 / 6) / 0.2)
    np.testing.assert_array_equal(d[_vid(3, 8)], 0.0)
    W4 = T.part_weights.copy()
    W4[_vid(3, 0)] = [0.0, 0.75, 0.0, 0.25]
    T2 = ArmTemplate(T.vertex_ids, T.faces, T.vertices, W4, T.joints, T.arm_mask, "left", "2k")
    d2 = syn.muscle_displacement(T2, _subject(), _flexed(T2, 30.0), var)
    np.testing.assert_allclose(d2[_vid(3, 0)], 0.75 * 0.009 * N[_vid(3, 0)], atol=1e-12)


def _tilted(side, down_deg, forward_deg=0.0):
    """The tube turned about the shoulder: down by ``down_deg`` (about z), forward by ``forward_deg`` (about y);
    the right arm's turn is the mirror image of the left's."""
    T0 = _arm(side)
    m = 1.0 if side == "left" else -1.0
    R = Rotation.from_rotvec([0.0, 0.0, -m * np.radians(down_deg)]) * Rotation.from_rotvec(
        [0.0, -m * np.radians(forward_deg), 0.0])
    S0 = T0.joints[0]
    V, J = R.apply(T0.vertices - S0) + S0, R.apply(T0.joints - S0) + S0
    return ArmTemplate(T0.vertex_ids, T0.faces, V, T0.part_weights, J, T0.arm_mask, side, "2k")


@pytest.mark.parametrize("side", ["left", "right"])
def test_the_deltoid_follows_the_lateral_upward_direction_of_a_tilted_arm(side):
    """The tube turned down 40 deg and forward 30 deg: the lateral direction is (sign, 1, 0) made orthogonal to u
    (sign +1 left, -1 right), and the deltoid's profile is max(0, r.lateral)^1.5."""
    T = _tilted(side, 40.0, 30.0)
    V, J = T.vertices, T.joints
    u = (J[1] - J[0]) / np.linalg.norm(J[1] - J[0])
    assert abs(u[2]) > 0.3
    sign = 1.0 if side == "left" else -1.0
    lat = np.array([sign, 1.0, 0.0]) - (np.array([sign, 1.0, 0.0]) @ u) * u
    lat /= np.linalg.norm(lat)
    N = _normals(T)
    var = _variation(thresholds_deg=(200.0, -10.0, 0.0), deltoid_center=0.25)
    act = syn.muscle_activations(syn.anatomical_angles(T, ArmPose.rest()), var)
    assert act[0] == 0.0 and act[1] == 0.0 and act[2] > 0.0
    d = syn.muscle_displacement(T, _subject(), ArmPose.rest(), var)
    for j in range(N_RING):
        k = _vid(3, j)
        rel = V[k] - J[0]
        r = rel - (rel @ u) * u
        r /= np.linalg.norm(r)
        want = 0.009 * act[2] * max(0.0, r @ lat) ** 1.5 * N[k]
        np.testing.assert_allclose(d[k], want, atol=1e-12)
    assert np.abs(d).max() > 1e-3


@pytest.mark.parametrize("side", ["left", "right"])
def test_elevation_is_measured_from_hanging_on_a_lowered_arm(side):
    """The tube lowered by 40 deg rests at elevation 50 (from hanging, -y); a pose made for 60 / 20 reads back."""
    T = _tilted(side, 40.0)
    assert syn.anatomical_angles(T, ArmPose.rest()).elevation_deg == pytest.approx(50.0, abs=1e-9)
    for elev in (60.0, 20.0):
        got = syn.anatomical_angles(T, syn.arm_pose_from_angles(T, 90.0, elev))
        assert got.elevation_deg == pytest.approx(elev, abs=1e-6)


def test_the_biceps_is_scaled_by_the_limb_weight():
    T = _arm()
    N = _normals(T)
    W4 = T.part_weights.copy()
    W4[_vid(6, 4)] = [0.4, 0.6, 0.0, 0.0]
    W4[_vid(6, 3)] = [0.0, 0.6, 0.3, 0.1]  # upper arm + forearm = 0.9 of the limb
    T2 = ArmTemplate(T.vertex_ids, T.faces, T.vertices, W4, T.joints, T.arm_mask, "left", "2k")
    d = syn.muscle_displacement(T2, _subject(), _flexed(T2, 140.0), _variation())
    np.testing.assert_allclose(d[_vid(6, 4)], 0.6 * 0.02 * N[_vid(6, 4)], atol=1e-12)
    prof = np.sin(np.radians(22.5 * 3)) ** 2
    np.testing.assert_allclose(d[_vid(6, 3)], 0.9 * prof * 0.02 * N[_vid(6, 3)], atol=1e-12)


def test_default_variation_is_the_subjects_seeded_one():
    T = _arm()
    ap = _flexed(T, 120.0, 60.0)
    subj = _subject(seed=7)
    np.testing.assert_array_equal(syn.muscle_displacement(T, subj, ap),
                                  syn.muscle_displacement(T, subj, ap, syn.MuscleVariation.from_seed(7)))
    a, b = syn.MuscleVariation.from_seed(7), syn.MuscleVariation.from_seed(8)
    assert a == syn.MuscleVariation.from_seed(7) and a != b


def test_the_per_person_variation_has_the_documented_spread():
    """Over 40 seeds each drawn value has its documented mean (within 4 standard errors) and spread (sample std
    0.6-1.5 of the documented one), and lies in its range: belly centres 0.6 / 0.45 / 0.1 +- 0.04 / 0.04 / 0.03,
    widths and amplitudes U(0.85, 1.15), onsets 35 / 60 / 40 +- 6 deg each on its own, exponents U(1.3, 2.2),
    the anterior twist N(0, 8 deg), the slide U(0.5, 1)."""
    vs = [syn.MuscleVariation.from_seed(s) for s in range(40)]
    n = len(vs)

    def check(x, mean, sd):
        x = np.asarray(x, float)
        assert abs(x.mean() - mean) < 4 * sd / np.sqrt(n), (x.mean(), mean)
        assert 0.6 * sd < x.std(ddof=1) < 1.5 * sd, (x.std(ddof=1), sd)

    check([v.biceps_center for v in vs], 0.6, 0.04)
    check([v.triceps_center for v in vs], 0.45, 0.04)
    check([v.deltoid_center for v in vs], 0.1, 0.03)
    u_sd = 0.3 / np.sqrt(12)
    check([v.width_scale for v in vs], 1.0, u_sd)
    A = np.array([v.amplitudes for v in vs])
    assert A.shape == (n, 3) and A.min() >= 0.85 and A.max() <= 1.15
    for c in range(3):
        check(A[:, c], 1.0, u_sd)
    T = np.array([v.thresholds_deg for v in vs])
    assert T.shape == (n, 3)
    for c, m in enumerate((35.0, 60.0, 40.0)):
        check(T[:, c], m, 6.0)
    assert np.std(T[:, 0] - T[:, 1]) > 4.0  # drawn per muscle, not one shift for all
    X = np.array([v.exponents for v in vs])
    assert X.shape == (n, 3) and X.min() >= 1.3 and X.max() <= 2.2
    check(X[:, 0], 1.75, 0.9 / np.sqrt(12))
    check([v.anterior_twist_rad for v in vs], 0.0, np.radians(8.0))
    sl = [v.slide for v in vs]
    assert min(sl) >= 0.5 and max(sl) <= 1.0
    check(sl, 0.75, 0.5 / np.sqrt(12))


# ---------------------------------------------------------------------------------------- forearm twist

@pytest.mark.parametrize("side", ["left", "right"])
def test_pronation_counter_twists_the_forearm_by_the_unreached_fraction(side):
    """A forearm vertex at s (0 elbow, 1 wrist) is turned back about f through the elbow by -(1 - s) of the
    world twist (the right arm's world twist is the mirrored one); upper-arm vertices and the wrist ring stay."""
    T = _arm(side)
    slide = syn._pronation_slide(T, 60.0)
    world = 60.0 if side == "left" else -60.0
    _, f, e = _axes(side)
    for ring, s in ((13, 0.1), (17, 0.5), (22, 1.0)):
        k = _vid(ring, 3)
        R = Rotation.from_rotvec(-np.radians(world) * (1.0 - s) * f)
        np.testing.assert_allclose(T.vertices[k] + slide[k], R.apply(T.vertices[k] - e) + e, atol=1e-12)
    np.testing.assert_allclose(slide[: 13 * N_RING], 0.0, atol=1e-15)
    np.testing.assert_array_equal(syn._pronation_slide(T, 0.0), 0.0)
    small = syn._pronation_slide(T, 1.0)[_vid(13, 3)]  # one degree is a twist, not "none"
    assert np.linalg.norm(small) > 1e-4
    # the whole displacement adds it: no muscle active, pronated
    var = _variation(thresholds_deg=(200.0, -10.0, 100.0))
    d = syn.muscle_displacement(T, _subject(), _flexed(T, 90.0, 90.0, 60.0), var)
    np.testing.assert_allclose(d, slide, atol=1e-12)


def test_the_counter_twist_fraction_is_clipped_to_the_forearm():
    """Forearm-weighted skin behind the elbow (s < 0) turns back by the whole angle, beyond the wrist (s > 1) not
    at all: with the wrist joint moved half-way, the last forearm rings (s up to 2) stay where they are."""
    T = _arm()
    W4 = T.part_weights.copy()
    k_back = _vid(11, 3)  # upper-arm ring 11 (x = 0.275): 2.5 cm before the elbow
    W4[k_back] = [0.0, 0.0, 1.0, 0.0]
    J = T.joints.copy()
    J[2] = E + 0.5 * (W - E)
    T2 = ArmTemplate(T.vertex_ids, T.faces, T.vertices, W4, J, T.arm_mask, "left", "2k")
    slide = syn._pronation_slide(T2, 60.0)
    np.testing.assert_allclose(slide[_vid(22, 3)], 0.0, atol=1e-15)  # s = 2
    np.testing.assert_allclose(slide[_vid(20, 5)], 0.0, atol=1e-15)  # s = 1.6
    R = Rotation.from_rotvec(-np.radians(60.0) * F_DIR)
    np.testing.assert_allclose(T.vertices[k_back] + slide[k_back], R.apply(T.vertices[k_back] - E) + E, atol=1e-12)


# ------------------------------------------------------------------------------------------- the motions

def test_angle_sequences_follow_their_waves():
    """elbow_flex starts straight-ish (15 deg, phase 0 of the flexion wave), the forward flexion is 10 +- 5 deg."""
    for motion in syn.ARM_MOTIONS:
        A = syn.arm_angle_sequence(motion, 120, seed=2)
        assert A.shape == (120, 4) and np.all(np.abs(A[:, 3] - 10.0) <= 5.0 + 1e-12)
        assert np.ptp(A[:, 3]) > 1.0
    flex = syn.arm_angle_sequence("elbow_flex", 120, seed=2)
    assert flex[0, 0] == pytest.approx(15.0) and flex[:, 0].min() >= 15.0 - 1e-12 and flex[:, 0].max() <= 140.0
    assert flex[:, 1].min() >= 30.0 - 1e-12 and flex[:, 1].max() <= 70.0 and np.all(flex[:, 2] == 0.0)
    assert flex[:, 0].max() > 15.0 + 0.9 * 125.0 * 0.95  # one cycle is ~100 frames: the top is reached
    ab = syn.arm_angle_sequence("abduction", 120, seed=2)
    assert ab[0, 1] == pytest.approx(20.0) and ab[:, 1].max() > 20.0 + 0.85 * 75.0 and ab[:, 1].max() <= 95.0
    assert np.all(np.abs(ab[:, 0] - 30.0) <= 5.0 + 1e-12) and np.ptp(ab[:, 0]) > 1.0 and np.all(ab[:, 2] == 0.0)
    pr = syn.arm_angle_sequence("pronation", 120, seed=2)
    assert pr[0, 2] == pytest.approx(-30.0) and pr[:, 2].max() > -30.0 + 0.85 * 105.0
    assert np.all(np.abs(pr[:, 0] - 90.0) <= 5.0 + 1e-12) and np.all(np.abs(pr[:, 1] - 40.0) <= 5.0 + 1e-12)
    assert np.ptp(pr[:, 0]) > 1.0 and np.ptp(pr[:, 1]) > 1.0
    # 30 fps: a 3.3 s (+-10 %) cycle
    top = int(np.argmax(flex[:, 0]))
    assert 0.45 * 3.3 * 0.9 * syn.FPS <= top <= 0.55 * 3.3 * 1.1 * syn.FPS
    assert not np.array_equal(syn.arm_angle_sequence("elbow_flex", 50, seed=3), syn.arm_angle_sequence(
        "elbow_flex", 50, seed=4))
    with pytest.raises(InputError, match="at least one frame"):
        syn.arm_angle_sequence("elbow_flex", 0)
    with pytest.raises(InputError, match="^unknown arm motion 'jump'; valid: elbow_flex, abduction, pronation$"):
        syn.arm_angle_sequence("jump", 10)
    one = syn.arm_angle_sequence("abduction", 1, seed=2)
    np.testing.assert_array_equal(one, ab[:1])
    np.testing.assert_array_equal(syn.arm_angle_sequence("abduction", 5), syn.arm_angle_sequence("abduction", 5, 0))


def test_arm_motion_poses_carry_the_sequence_angles():
    T = _arm()
    np.testing.assert_array_equal(syn.arm_pose_from_angles(T, 90.0, 45.0).angles,
                                  syn.arm_pose_from_angles(T, 90.0, 45.0, 0.0, 0.0).angles)
    assert not np.allclose(syn.arm_pose_from_angles(T, 90.0, 45.0, forward_deg=20.0).angles[0],
                           syn.arm_pose_from_angles(T, 90.0, 45.0).angles[0])
    default = syn.arm_motion(T, "abduction")
    assert len(default) == 200
    np.testing.assert_array_equal(default[7].angles, syn.arm_motion(T, "abduction", 8, seed=0)[7].angles)
    A = syn.arm_angle_sequence("pronation", 12, seed=1)
    poses = syn.arm_motion(T, "pronation", 12, seed=1)
    assert len(poses) == 12
    for ap, row in zip(poses, A, strict=True):
        np.testing.assert_allclose(ap.angles, syn.arm_pose_from_angles(T, *row[:3], forward_deg=row[3]).angles,
                                   atol=1e-15)
        got = syn.anatomical_angles(T, ap)
        assert got.flexion_deg == pytest.approx(row[0], abs=1e-6) and got.pronation_deg == pytest.approx(row[2],
                                                                                                         abs=1e-6)


def test_random_poses_cover_the_captured_range():
    T = _arm()
    poses = syn.random_arm_poses(T, 40, seed=5)
    ang = np.array([[a.flexion_deg, a.pronation_deg] for a in (syn.anatomical_angles(T, p) for p in poses)])
    assert ang[:, 0].min() >= 10 - 1e-6 and ang[:, 0].max() <= 145 + 1e-6 and np.ptp(ang[:, 0]) > 90
    assert ang[:, 1].min() >= -20 - 1e-6 and ang[:, 1].max() <= 60 + 1e-6 and np.ptp(ang[:, 1]) > 50
    flat = syn.random_arm_poses(T, 10, seed=5, pronation=False)
    assert all(abs(syn.anatomical_angles(T, p).pronation_deg) < 1e-6 for p in flat)
    np.testing.assert_array_equal(syn.random_arm_poses(T, 3, seed=5)[2].angles, poses[2].angles)


@pytest.mark.parametrize("motion, column, mean, amplitude, period_s", [
    ("elbow_flex", 3, 10.0, 5.0, 7.0), ("abduction", 3, 10.0, 5.0, 7.0), ("pronation", 3, 10.0, 5.0, 7.0),
    ("pronation", 0, 90.0, 5.0, 5.0), ("pronation", 1, 40.0, 5.0, 6.0)])
def test_the_side_waves_are_sines_of_their_documented_period(motion, column, mean, amplitude, period_s):
    """The small waves riding on each motion (forward flexion 10 +- 5 deg over 7 s; in the pronation motion the
    elbow 90 +- 5 over 5 s and the elevation 40 +- 5 over 6 s): a least-squares sine of that period fits exactly."""
    A = syn.arm_angle_sequence(motion, 300, seed=4)
    t = np.arange(300) / syn.FPS
    w = 2 * np.pi * t / period_s
    X = np.c_[np.ones_like(t), np.sin(w), np.cos(w)]
    coef, *_ = np.linalg.lstsq(X, A[:, column], rcond=None)
    np.testing.assert_allclose(X @ coef, A[:, column], atol=1e-9)
    assert coef[0] == pytest.approx(mean, abs=1e-9) and np.hypot(coef[1], coef[2]) == pytest.approx(amplitude, abs=1e-9)
