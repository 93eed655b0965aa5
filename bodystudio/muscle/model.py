"""The statistical arm deformation model (§6.1 and Eq. 5-12 of Arm-Muscle Capture; issue 11 §2, §4).

``v = skinning(v_base + d_l + d_theta + d_rho)`` (Eq. 12):

* ``v_base``: the mean arm of a population of bodies in the base pose (the paper's Hasler average);
* ``d_l`` (Eq. 8-9): length displacements, a combination of the population's PCA eigenvectors whose
  weights are regressed (Tikhonov) on the arm length over the population - the paper's Hasler
  dataset, ours ``bodystudio.body.population``;
* ``d_theta`` (Eq. 6-7): shape displacements, per-vertex linear regression on BMI, muscularity,
  height, arm length (standardised, Tikhonov-regularised) and sex (a female indicator, ``1 - sex``;
  the paper's Table 1 lists every subject's sex) of the training subjects' base-pose meshes minus
  ``v_base + d_l`` (optionally with the women's own slopes, the interaction ``(1 - sex) z``:
  ``sex_slopes``). The paper's training set is all male, so the female column is zero there and its
  coefficient stays zero until women are added (dataset extension); a subject of unknown sex is
  taken as male, which is what the original model describes;
* ``d_rho`` (Eq. 10): pose displacements, per-vertex linear regression on the 9 joint-angle
  coordinates (shoulder, elbow, wrist rotation vectors) plus an intercept, of every training mesh
  brought back to the base pose by inverting the four-part skinning, minus its subject's base mesh;
* the rest joints are regressed on the four shape parameters over the population and the subjects
  whose joints are known;
* ``skinning``: :func:`bodystudio.muscle.arm.pose_arm`.

The 90 % displacement-norm limit (§8.2, Fig. 13): "0 % = unlimited, 100 % = simple skinning", the
percentage of the pose's maximum displacement norm that is cut off: with limit ``p`` every pose
displacement longer than ``(1 - p) * max_i |d_rho_i|`` is shortened to that length.

Dataset extension (issue §4): the model keeps its training statistics (per-row shape residuals, the
normal equations of the pose regression), so :func:`extend_arm_model` adds captured subjects and
re-solves without the original meshes. The sex column has its own, weaker Tikhonov weight
(``sex_regularization``): it is learned from the few added women alone, and the common weight
(1, against a column sum of squares of 2 for two women with one base-pose mesh each) shrank it by a
third (docs/muscle.md, "Dataset extension"). A captured subject's shape row can be its rest mesh's nearest
arm of the body model's shape space (:func:`body_space_rest_mesh`: where the shoulder sits in the skin and how the
vertices lie along it, which a depth capture does not see; seventh extension pass).

The shape term has two forms (``shape_form``, :data:`SHAPE_FORMS`): ``"linear"``, Eq. 6-7 as above (one linear map from
the five shape numbers to the vertex displacements; the paper's), and ``"body"`` (eighth extension pass): each shape
row's parameters in the body model's shape space (:func:`shape_row_parameters`) are regressed on the numbers, each
parameter on the numbers that describe it (:data:`BODY_FORM_INPUTS`: the gender macro on sex, the weight macro on BMI,
muscularity and height, ...), the rest mesh is the body model's arm at the regressed parameters (MakeHuman's blend of
its targets: non-linear in the numbers, so a subject outside the rows' range is reached through the body model's
own targets for that range) plus Eq. 6-7's linear regression of what that arm leaves of each row
(:func:`fit_body_form`). Saved as a versioned ``.npz`` with the subjects it was learned from and the template key
(version 3: the form, and for the body form the rows' parameters and their regression); loading it for another
template is refused.
"""

from __future__ import annotations

import json
import logging
import os
import zipfile
from dataclasses import dataclass, field, fields, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from bodystudio.body import build_body
from bodystudio.body.measure import measure_body
from bodystudio.body.population import sample_subject
from bodystudio.errors import FileFormatError, InputError
from bodystudio.fileio import atomic_write
from bodystudio.muscle.arm import ArmPose, ArmTemplate, arm_template, part_transforms, pose_arm
from bodystudio.muscle.normal_equations import normal_matrix, normal_rhs, spd_solve

log = logging.getLogger(__name__)

MODEL_FORMAT = "bodystudio-arm-model"
MODEL_VERSION = 3  # 2: sex in the shape regression (version 1 files are read as all-male models); 3: the shape
# term's form (``shape_form``) and, for the body form, the body-space parameters of each shape row and their regression
# (version 2 files are read as the linear form they are)
# A training mesh is in the base pose when no joint is rotated more than this (the paper compares angles).
BASE_POSE_TOL_RAD = np.deg2rad(8.0)
N_LENGTH_COMPONENTS = 8
SHAPE_NAMES = ("bmi", "muscularity", "height_m", "arm_length_m")
# Regressors of the shape term: BMI, muscularity, height (Eq. 6) and arm length (issue 11 §2 lists it with
# the shape parameters; it lets added subjects correct the population length term at the extremes).
SHAPE_REGRESSORS = 4
# The shape term's last regressor: female indicator 1 - sex (sex 1 = male, 0 = female).
SEX_NAMES = {"male": 1.0, "m": 1.0, "female": 0.0, "f": 0.0}
# Tikhonov weight of the sex column: measured on ground-truth extensions (docs/muscle.md), 1.0 -> 0.1
# takes the held-out out-of-range change from -23 % to -29 %.
SEX_REGULARIZATION = 0.1
# The women's own slopes (``ArmModel.sex_slopes``, ``muscle model build --sex-slopes``): the shape term's interaction
# ``(1 - sex) z`` (one column per shape number, Tikhonov weight ``regularization`` as the shared slopes'), so a woman's
# arm follows her BMI, muscularity, height and arm length with slopes of its own rather than the men's. Off by default
# (docs/muscle.md, "Women's own slopes").
SEX_SLOPES = False
# Where a captured subject's shape row comes from (dataset extension): "mesh", its captured rest mesh as it is; "body",
# that mesh's nearest arm of the body model's shape space (:func:`body_space_rest_mesh`), which puts the subject's
# shoulder where the body model's joint regressor puts it in that skin and the vertices where the body model lays
# them along it (neither is seen by a depth camera; docs/muscle.md, "Dataset extension, seventh pass").
CAPTURED_REST_CHOICES = ("mesh", "body")
# Prior weight of that fit (per vertex, on the standardised body parameters, in (1 mm)^2): chosen on a third seed
# set of held-out subjects (641-664, 621-625), 3 / 10 / 30 -> -19.2 / -18.6 / -17.3 % (docs/muscle.md).
CAPTURED_REST_PRIOR_WEIGHT = 3.0
# The extension's own prior weights of that fit (``extend_arm_model``'s defaults): every parameter but the weight
# macro, and the weight macro's (the prior takes nothing from the BMI, so a strong one pulls a heavy subject's weight
# to the population's). 30 / 3 since the twelfth pass (docs/muscle.md, "Dataset extension, twelfth pass"): on
# held-out set C (641-664), a grid of 12 pairs, with two sets of added captures, 3 / 3 -> 30 / 3 -23.4 / -19.4 ->
# -24.9 / -23.5 % (6.29 / 6.45 -> 5.83 / 5.55 mm); on set D (711-754, seen by no choice) -26.4 / -24.5 -> -32.5 /
# -30.5 % (7.85 / 7.94 -> 6.96 / 6.91 mm). 100 / 3 is C's best (-27.3 / -25.1 %) but misses set A's goal with one
# added set (-28.1 %) and costs C's in-range men 0.41 mm. Before: 3 / 3 (:data:`CAPTURED_REST_PRIOR_WEIGHT`).
EXTENSION_ROW_PRIOR_WEIGHT = 30.0
EXTENSION_ROW_WEIGHT_PRIOR_WEIGHT = 3.0
# The shape term's form (Eq. 6-7): "linear", one Tikhonov regression of the rows' vertex displacements on the five shape
# numbers (the paper's); "body", a regression of the rows' body-space parameters on the five numbers, the rest mesh
# made through the body model's own blend of its targets, plus the linear regression of what the body space does not
# express (:func:`body_form_rest_vertices`; docs/muscle.md, "Dataset extension, eighth pass").
SHAPE_FORMS = ("linear", "body")
# Prior weight of the projection of a shape row into the body space (:func:`body_space_rest_mesh`, per vertex, on the
# standardised parameters, in (1 mm)^2): a ground-truth row lies in the space, the prior only breaks its ties.
SHAPE_ROW_PRIOR_WEIGHT = 0.01
# Which of the five shape numbers each body-space parameter of the body form is regressed on (the others, the age, the
# ethnic mix and the local targets, are the rows' mean: individual, not predicted by the numbers). Regressing every
# parameter on every number overfits the ten training men (in-range subject 620 6.28 -> 9.86 mm); chosen on the third
# held-out set C against all numbers / the six first macros on all numbers / these plus the local targets on all
# numbers; the weight macro's BMI x muscularity product (MakeHuman's BMI is not linear in its weight and muscle
# macros: a heavy man of muscularity 0 got 0.95 for his 0.81) on set C, -34.8 -> -36.8 % (docs/muscle.md, "Dataset
# extension, eighth pass"). Names: the columns of :func:`body_form_design`.
BODY_FORM_INPUTS = {"gender": ("sex",), "muscle": ("muscularity",),
                    "weight": ("bmi", "muscularity", "height_m", "bmi*muscularity"),
                    "height": ("height_m", "sex"), "proportions": ("height_m", "arm_length_m", "sex")}
# Tikhonov weight of those regressions' four continuous inputs, times the model's ``regularization`` (the sex column
# keeps ``sex_regularization``): chosen on set C, x1 / x3 -> extended with ground-truth meshes 6.45 / 6.07 mm mean
# (in range 3.97 / 3.82 mm); the macros of ten training men are a noisy function of the numbers (docs/muscle.md).
BODY_FORM_REGULARIZATION_SCALE = 3.0
# The body form's weight macro: "regressed", on ``BODY_FORM_INPUTS["weight"]`` (the eighth pass's); "bmi", solved per
# query from the subject's BMI through the body model's own measurement (:func:`body_weight_for_bmi`: the 6k body's
# mass from its volume over its stature squared, as the subjects are measured) at its other regressed parameters.
# MakeHuman's BMI is not linear in its weight and muscle macros. Measured on set C (docs/muscle.md, "Dataset extension,
# ninth pass"): the solution alone against an offset regressed on it (intercept / the weight's four inputs).
BODY_WEIGHT_CHOICES = ("regressed", "bmi")
BODY_FORM_WEIGHT = "bmi"
# How many shape rows an added subject has in Eq. 7 (and in the body form's regressions): "own", the rows it brings;
# "training", at least as many as one of the model's training subjects (its rows repeated;
# :func:`training_rows_per_subject`). A training subject of the benchmark has 3 base-pose meshes, a captured subject 1
# row (its frames' mean, sixth pass) and a ground-truth one 1 base-pose mesh, so an added subject weighs a third of a
# training one. Measured (docs/muscle.md, "Dataset extension, tenth pass"), own -> training, from the benchmark's
# captures of 601-604: held-out set C -21.0 -> -22.2 %, mean 6.37 -> 6.08 mm, C's in-range men 3.60 -> 3.48 mm; but from
# another four captured subjects (671-674): A -20.6 -> -11.3 %, C 6.84 -> 6.82 mm, C's in-range men 3.73 -> 4.05 mm:
# a single out-of-range subject weighed up teaches its own residual. Off by default.
SUBJECT_ROWS_CHOICES = ("own", "training")
SUBJECT_ROWS = "own"


def parse_sex(value, source: str = "sex") -> float:
    """Sex as the model's number: 1 male, 0 female (``male``/``m``/``female``/``f`` or a value in [0, 1])."""
    if isinstance(value, str):
        key = value.strip().lower()
        if key in SEX_NAMES:
            return SEX_NAMES[key]
        try:
            value = float(key)
        except ValueError:
            raise InputError(f"{source}: sex {value!r} is not male, female or a number in [0, 1] "
                             "(1 = male, 0 = female)") from None
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{source}: sex {value!r} is not male, female or a number in [0, 1]") from None
    if not 0.0 <= x <= 1.0:
        raise InputError(f"{source}: sex {value!r} is not male, female or a number in [0, 1] (1 = male, 0 = female)")
    return x


@dataclass(frozen=True)
class ArmShapeParams:
    """The paper's shape parameters: BMI, muscularity (0..1), height and arm length (metres), and sex.

    ``sex`` (1 male, 0 female; the paper's Table 1) is not part of :meth:`as_vector` (the continuous
    parameters a shape fit varies); it defaults to male, the original training set's.
    """

    bmi: float
    muscularity: float
    height_m: float
    arm_length_m: float
    sex: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "sex", parse_sex(self.sex))

    def as_vector(self) -> np.ndarray:
        return np.array([self.bmi, self.muscularity, self.height_m, self.arm_length_m], dtype=np.float64)

    def as_row(self) -> np.ndarray:
        """The four parameters of :meth:`as_vector` and the sex: a row of the model's ``shape_rows``."""
        return np.r_[self.as_vector(), self.sex]

    @classmethod
    def from_vector(cls, x, sex: float = 1.0) -> ArmShapeParams:
        return cls(*(float(v) for v in np.asarray(x, dtype=np.float64).reshape(4)), sex=sex)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict, source: str = "shape parameters") -> ArmShapeParams:
        """From ``{bmi, muscularity, height_m, arm_length_m[, sex]}``; without ``sex`` a synthetic subject's
        ``gender`` (MakeHuman's, 1 male) is taken, else male."""
        try:
            values = [float(d[n]) for n in SHAPE_NAMES]
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: needs {', '.join(SHAPE_NAMES)} ({exc})") from None
        sex = d.get("sex", d.get("gender", 1.0))
        return cls(*values, sex=parse_sex(sex, source))


def measure_arm_shape(phenotype, local: dict | None = None, side: str = "left") -> ArmShapeParams:
    """Shape parameters of a body: BMI (mass from the 6k body's volume), muscle, stature, arm chain length."""
    body = build_body(phenotype, local or {}, resolution="6k")
    m = measure_body(body)
    s = "_l" if side == "left" else "_r"
    names = body.skeleton.bone_names
    h = body.skeleton.heads[[names.index(f"{b}{s}") for b in ("upperarm", "lowerarm", "hand")]]
    arm = float(np.linalg.norm(h[1] - h[0]) + np.linalg.norm(h[2] - h[1]))
    return ArmShapeParams(m["mass_kg"] / m["stature_m"] ** 2, float(phenotype.muscle), m["stature_m"], arm,
                          sex=min(max(float(phenotype.gender), 0.0), 1.0))


@dataclass(frozen=True, eq=False)
class ArmSample:
    """One training mesh: a subject's arm ``vertices`` (n, 3) in ``pose``, in the template topology.

    ``joints`` are the subject's rest joint centres when known (ground truth); None uses the model's
    joint regression from ``shape``.

    ``rest_origin`` (3,): the point of the unposed mesh that the model's shoulder-centred frame puts at
    the origin; None: its shoulder, ``joints[0]`` (a ground-truth mesh). A capture's rest mesh sits at
    the capturing model's *regressed* shoulder, whatever skeleton it was posed about
    (``refine.skeleton_model_mesh``), so :func:`capture_samples` sets it there.
    """

    subject: str
    shape: ArmShapeParams
    vertices: np.ndarray
    pose: ArmPose
    joints: np.ndarray | None = None
    rest_origin: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ArmModel:
    """A learned arm deformation model (all arrays float64; ``3n`` = flattened vertex coordinates)."""

    template_key: str
    faces: np.ndarray  # (m, 3)
    part_weights: np.ndarray  # (n, 4)
    arm_mask: np.ndarray  # (n,) bool
    base_vertices: np.ndarray  # (n, 3) population mean arm (v_base), shoulder joint at the origin
    length_basis: np.ndarray  # (k, 3n) PCA eigenvectors e_j of the population arms
    length_coeffs: np.ndarray  # (2, k) PCA weights = [1, z(arm length)] @ length_coeffs
    joint_coeffs: np.ndarray  # (5, 9) rest joints = [1, z(shape)] @ joint_coeffs
    shape_coeffs: np.ndarray  # (6, 3n) d_theta = [1, z(SHAPE_NAMES), 1 - sex] @ shape_coeffs ((10, 3n) with
    # ``sex_slopes``: the design row continued by (1 - sex) z(SHAPE_NAMES))
    pose_coeffs: np.ndarray  # (10, 3n) d_rho = [1, 9 joint-angle coordinates] @ pose_coeffs
    param_center: np.ndarray  # (4,) z(x) = (x - center) / scale, order SHAPE_NAMES
    param_scale: np.ndarray  # (4,)
    regularization: float
    # Training statistics kept for dataset extension.
    shape_rows: np.ndarray  # (R, 5) shape parameters and sex of each base-pose training mesh
    shape_residuals: np.ndarray  # (R, 3n) its displacement from v_base + d_l
    pose_xtx: np.ndarray  # (10, 10) normal equations of Eq. 10
    pose_xtd: np.ndarray  # (10, 3n)
    joint_xtx: np.ndarray  # (5, 5) normal equations of the joint regression (population + subjects)
    joint_xty: np.ndarray  # (5, 9)
    subjects: list = field(default_factory=list)  # [{"name", "shape": {...}, "n_meshes", "source"}]
    version: int = MODEL_VERSION
    sex_regularization: float = SEX_REGULARIZATION  # Tikhonov weight of the shape term's sex column
    # The shape term's form (:data:`SHAPE_FORMS`). "body": ``shape_params`` (R, P) each shape row's body-space
    # parameters (:func:`body_space_rest_mesh`), ``body_coeffs`` (7, P) their regression on :func:`body_form_design` in
    # units of the population prior's spread, ``shape_coeffs`` the linear regression of what is left of the rows.
    shape_form: str = "linear"
    shape_params: np.ndarray | None = None
    body_coeffs: np.ndarray | None = None
    # The body form's weight macro (:data:`BODY_WEIGHT_CHOICES`): "bmi", solved from the BMI (``body_coeffs``' weight
    # column zero); "regressed", Eq. 7 on its inputs.
    body_weight: str = "regressed"
    # The women's own slopes (:data:`SEX_SLOPES`): the shape term's design continued by ``(1 - sex) z``.
    sex_slopes: bool = SEX_SLOPES

    @property
    def n_vertices(self) -> int:
        return len(self.base_vertices)

    def shape_range(self) -> dict[str, tuple[float, float]]:
        """Range of each shape parameter over the training subjects."""
        S = np.array([[s["shape"][n] for n in SHAPE_NAMES] for s in self.subjects])
        return {n: (float(S[:, i].min()), float(S[:, i].max())) for i, n in enumerate(SHAPE_NAMES)}


# --- the population ("Hasler's dataset") -----------------------------------------------------------------

@lru_cache(maxsize=4)
def population_arms(resolution: str, side: str = "left", n_subjects: int = 40, seed: int = 114):
    """Rest arms (N, n, 3), rest joints (N, 3, 3) and shape parameters (N, 4) of a seeded population."""
    rng = np.random.default_rng(seed)
    V, J, P = [], [], []
    for _ in range(n_subjects):
        phenotype, local = sample_subject(rng)
        body = build_body(phenotype, local, resolution=resolution)
        T = arm_template(body, side)
        V.append(T.vertices)
        J.append(T.joints)
        P.append(measure_arm_shape(phenotype, local, side).as_vector())
    return np.stack(V), np.stack(J), np.stack(P)


def _design(Z: np.ndarray) -> np.ndarray:
    return np.c_[np.ones(len(Z)), Z]


def tikhonov_least_squares(X: np.ndarray, Y: np.ndarray, q: float) -> np.ndarray:
    """``argmin_W |X W - Y|^2 + q^2 |W[1:]|^2`` (Eq. 7 and 9; the intercept row is not regularised)."""
    return tikhonov_from_normal_equations(X.T @ X, X.T @ Y, q)


def tikhonov_from_normal_equations(xtx: np.ndarray, xty: np.ndarray, q: float,
                                   column_weights: np.ndarray | None = None) -> np.ndarray:
    """The Tikhonov solution from ``X^T X`` and ``X^T Y``; ``column_weights`` (one per column) replace ``q``."""
    q2 = np.full(len(xtx), float(q) ** 2) if column_weights is None else np.asarray(column_weights, float) ** 2
    reg = np.diag(q2)
    reg[0, 0] = 0.0
    return np.linalg.solve(xtx + reg, xty)


def _sex_design(model: ArmModel, rows: np.ndarray) -> np.ndarray:
    """Eq. 6's design rows ``[1, z(bmi, muscularity, height, arm length), 1 - sex]`` (R, 6) for ``rows`` (R, 5)."""
    rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
    return np.c_[np.ones(len(rows)), _z(model, rows[:, :4]), 1.0 - rows[:, 4]]


def shape_design(model: ArmModel, rows: np.ndarray) -> np.ndarray:
    """Design rows of Eq. 6 for ``rows`` (R, 5): ``[1, z(bmi, muscularity, height, arm length), 1 - sex]``, continued
    with ``model.sex_slopes`` by the women's own slopes ``(1 - sex) z`` (R, 10): a man's row (sex 1) is unchanged."""
    X = _sex_design(model, rows)
    if not model.sex_slopes:
        return X
    return np.c_[X, X[:, 5:6] * X[:, 1:5]]


def shape_column_weights(model: ArmModel) -> np.ndarray:
    """Eq. 7's Tikhonov weight of each :func:`shape_design` column after the intercept's: ``regularization`` for the
    four slopes, ``sex_regularization`` for the female column, ``regularization`` for the women's own slopes."""
    q = np.r_[np.full(SHAPE_REGRESSORS, model.regularization), model.sex_regularization]
    return np.r_[q, np.full(SHAPE_REGRESSORS, model.regularization)] if model.sex_slopes else q


def fit_shape_coefficients(model: ArmModel, rows: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """Eq. 7: Tikhonov regression of the base-pose residuals on :func:`shape_design` (sex column weighted apart)."""
    X = shape_design(model, rows)
    q = np.r_[0.0, shape_column_weights(model)]
    return tikhonov_from_normal_equations(X.T @ X, X.T @ residuals, 0.0, column_weights=q)


def fit_body_form(model: ArmModel, rows: np.ndarray, residuals: np.ndarray,
                  params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The body form's two regressions on :func:`shape_design` (Tikhonov weights as Eq. 7's, the first's continuous
    inputs times :data:`BODY_FORM_REGULARIZATION_SCALE`): the rows' body-space
    parameters ``params`` (R, P; standardised by the population prior), each on its own inputs
    (:func:`body_form_columns`) -> ``body_coeffs``, then Eq. 7 on what the
    body model's arm at the *regressed* parameters leaves of each row (``v_base + d_l + residual`` minus it) ->
    ``shape_coeffs``. Returns ``(body_coeffs, shape_coeffs)``.

    With ``model.body_weight == "bmi"`` the weight macro is not regressed (its column is zero): the regressed
    parameters take the weight that gives the row's BMI at their other parameters (:func:`body_weight_for_bmi`)."""
    space = body_space_for_model(model)
    mean, sigma = space.prior()
    X = body_form_design(model, rows)
    q = model.regularization * BODY_FORM_REGULARIZATION_SCALE
    q2 = np.r_[0.0, q, q, q, q, model.sex_regularization, q] ** 2
    U = (np.asarray(params) - mean) / sigma
    A = np.zeros((X.shape[1], U.shape[1]))
    for p in range(U.shape[1]):
        cols = body_form_columns(p, model.body_weight)
        if not cols:
            continue
        A[cols, p] = np.linalg.solve(X[:, cols].T @ X[:, cols] + np.diag(q2[cols]), X[:, cols].T @ U[:, p])
    left = np.empty_like(residuals)
    for i, (row, r) in enumerate(zip(rows, residuals, strict=True)):
        shape = ArmShapeParams.from_vector(row[:4], sex=row[4])
        rest = model.base_vertices + length_displacements(model, shape) + r.reshape(-1, 3)
        x = _body_parameters(space, model.body_weight, X[i] @ A, shape.bmi)
        left[i] = (rest - space.rest_and_joints(x)[0]).ravel()
    return A, fit_shape_coefficients(model, rows, left)


def _body_parameters(space: BodyShapeSpace, body_weight: str, u: np.ndarray, bmi: float) -> np.ndarray:
    """Body-space parameters from the regressed standardised ones ``u`` (P,); "bmi": the weight macro solved."""
    mean, sigma = space.prior()
    x = mean + sigma * u
    if body_weight == "bmi":
        w = BODY_MACRO_NAMES.index("weight")
        x[w] = body_weight_for_bmi(space, x, bmi)
    return x


def body_form_design(model: ArmModel, rows: np.ndarray) -> np.ndarray:
    """Design rows (R, 7) of the body form's parameter regression: Eq. 6's six columns, ``z(bmi) z(muscularity)`` (the
    women's own slopes, ``sex_slopes``, enter the body form's linear residual term only)."""
    X = _sex_design(model, rows)
    return np.c_[X, X[:, 1] * X[:, 2]]


def body_form_columns(p: int, body_weight: str = "regressed") -> list[int]:
    """The columns of :func:`body_form_design` that body-space parameter ``p`` is regressed on
    (:data:`BODY_FORM_INPUTS`; the intercept alone for a parameter not listed there; none for the weight macro with
    ``body_weight == "bmi"``, which :func:`body_weight_for_bmi` solves)."""
    names = (*SHAPE_NAMES, "sex", "bmi*muscularity")
    inputs = BODY_FORM_INPUTS.get(BODY_MACRO_NAMES[p], ()) if p < len(BODY_MACRO_NAMES) else ()
    if body_weight == "bmi" and p < len(BODY_MACRO_NAMES) and BODY_MACRO_NAMES[p] == "weight":
        return []
    return [0, *(1 + names.index(n) for n in inputs)]


def shape_row_parameters(model: ArmModel, rows: np.ndarray, residuals: np.ndarray,
                         prior_weight: float = SHAPE_ROW_PRIOR_WEIGHT) -> np.ndarray:
    """Each shape row's body-space parameters (R, P): its rest mesh ``v_base + d_l + residual`` projected into the
    body model's shape space (:func:`body_space_rest_mesh`, free translation, ``prior_weight``)."""
    space = body_space_for_model(model)
    out = np.empty((len(rows), space.n_parameters))
    for i, (row, r) in enumerate(zip(rows, residuals, strict=True)):
        same = [j for j in range(i) if np.array_equal(rows[j], row) and np.array_equal(residuals[j], r)]
        if same:  # a subject's repeated base-pose meshes: one projection
            out[i] = out[same[0]]
            continue
        shape = ArmShapeParams.from_vector(row[:4], sex=row[4])
        rest = model.base_vertices + length_displacements(model, shape) + r.reshape(-1, 3)
        out[i] = body_space_rest_mesh(space, rest, shape, prior_weight)[1]
    return out


# --- evaluation of the model ---------------------------------------------------------------------------

def _z(model: ArmModel, x: np.ndarray) -> np.ndarray:
    return (np.asarray(x, dtype=np.float64) - model.param_center) / model.param_scale


def length_displacements(model: ArmModel, shape: ArmShapeParams) -> np.ndarray:
    """``d_l`` (n, 3): PCA eigenvectors weighted by the regression on arm length (Eq. 8)."""
    z = _z(model, shape.as_vector())[3]
    w = np.array([1.0, z]) @ model.length_coeffs
    return (w @ model.length_basis).reshape(-1, 3)


def shape_displacements(model: ArmModel, shape: ArmShapeParams) -> np.ndarray:
    """``d_theta`` (n, 3) = w0 + w1 BMI + w2 muscularity + w3 height + w4 arm length + w5 (1 - sex) (Eq. 6).

    In the body form (``model.shape_form == "body"``) the term is the body model's arm at the regressed parameters
    minus ``v_base + d_l``, plus Eq. 6's linear term of what the body space does not express
    (:func:`body_form_rest_vertices`)."""
    d = (shape_design(model, shape.as_row())[0] @ model.shape_coeffs).reshape(-1, 3)
    if model.shape_form == "body":
        d = d + body_form_rest_vertices(model, shape) - model.base_vertices - length_displacements(model, shape)
    return d


def regressed_body_parameters(model: ArmModel, shape: ArmShapeParams) -> np.ndarray:
    """The body-space parameters (P,) the body form regresses from the five shape numbers: Eq. 6's design row times
    ``model.body_coeffs``, in units of the population prior's spread about its mean (:meth:`BodyShapeSpace.prior`);
    with ``model.body_weight == "bmi"`` the weight macro is :func:`body_weight_for_bmi` at the other regressed
    parameters plus the regressed offset."""
    space = body_space_for_model(model)
    return _body_parameters(space, model.body_weight, body_form_design(model, shape.as_row())[0] @ model.body_coeffs,
                            shape.bmi)


def body_form_rest_vertices(model: ArmModel, shape: ArmShapeParams) -> np.ndarray:
    """The body form's rest arm (n, 3) before its linear residual term: the body model's arm (its own blend of the
    macro and local targets, non-linear in the shape numbers) at :func:`regressed_body_parameters`, relative to the
    shoulder MakeHuman's joint regressor puts in it."""
    return body_space_for_model(model).rest_and_joints(regressed_body_parameters(model, shape))[0]


def pose_displacements(model: ArmModel, angles: np.ndarray) -> np.ndarray:
    """``d_rho`` (n, 3) from the 9 joint-angle coordinates plus intercept (Eq. 10)."""
    a = np.asarray(angles, dtype=np.float64).reshape(9)
    return (np.r_[1.0, a] @ model.pose_coeffs).reshape(-1, 3)


def model_rest_vertices(model: ArmModel, shape: ArmShapeParams, joints: np.ndarray | None = None) -> np.ndarray:
    """``v_base + d_l + d_theta`` (n, 3): the subject's arm in the base pose, placed at its shoulder.

    The terms live in a frame centred on the shoulder joint (arm shape, not where the torso puts the
    shoulder); ``joints`` (the subject's, else the regressed ones) place it.
    """
    J = model_joints(model, shape) if joints is None else np.asarray(joints, dtype=np.float64).reshape(3, 3)
    return model.base_vertices + length_displacements(model, shape) + shape_displacements(model, shape) + J[0]


def model_joints(model: ArmModel, shape: ArmShapeParams) -> np.ndarray:
    """Rest shoulder, elbow and wrist centres (3, 3) regressed from the shape parameters."""
    return (np.r_[1.0, _z(model, shape.as_vector())] @ model.joint_coeffs).reshape(3, 3)


def limit_displacement_norms(d: np.ndarray, norm_limit: float) -> np.ndarray:
    """§8.2's displacement-norm limit: cut every norm above ``(1 - norm_limit) * max norm`` (0 = unlimited)."""
    if not 0.0 <= norm_limit <= 1.0:
        raise InputError(f"norm_limit={norm_limit} must be in [0, 1] (0 = unlimited, 1 = plain skinning)")
    norms = np.linalg.norm(d, axis=1)
    cap = (1.0 - norm_limit) * norms.max(initial=0.0)
    scale = np.where(norms > cap, cap / np.maximum(norms, 1e-300), 1.0)
    return d * scale[:, None]


def model_mesh(model: ArmModel, shape: ArmShapeParams, arm_pose: ArmPose, norm_limit: float = 0.9,
               joints: np.ndarray | None = None) -> np.ndarray:
    """Eq. 12: ``skinning(v_base + d_l + d_theta + d_rho)`` with the §8.2 norm limit on ``d_rho`` (n, 3).

    ``joints`` overrides the regressed rest joints (e.g. joints measured on the subject).
    """
    d_rho = limit_displacement_norms(pose_displacements(model, arm_pose.angles), norm_limit)
    J = model_joints(model, shape) if joints is None else np.asarray(joints, dtype=np.float64).reshape(3, 3)
    return pose_arm(model_rest_vertices(model, shape, J) + d_rho, model.part_weights, J, arm_pose)


def unpose_arm(vertices: np.ndarray, part_weights: np.ndarray, joints: np.ndarray, pose: ArmPose) -> np.ndarray:
    """Inverse of :func:`~bodystudio.muscle.arm.pose_arm`: posed vertices back to the base pose (per-vertex)."""
    T = part_transforms(joints, pose)
    M = np.einsum("np,pij->nij", part_weights, T)
    Vh = np.c_[vertices, np.ones(len(vertices))]
    return np.linalg.solve(M, Vh[:, :, None])[:, :3, 0]


def model_error_mm(model: ArmModel, samples: list[ArmSample], norm_limit: float = 0.0,
                   use_sample_joints: bool = False, fit_translation: bool = False) -> dict:
    """Model-only error of ``samples`` (true shape parameters and poses): arm-vertex distances in mm.

    ``use_sample_joints`` places the model on each sample's own rest joints; ``fit_translation`` removes
    the best translation per mesh (what a capture's root fit absorbs: where the torso puts the shoulder).
    """
    errs = []
    for s in samples:
        V = model_mesh(model, s.shape, s.pose, norm_limit, joints=s.joints if use_sample_joints else None)
        D = (V - s.vertices)[model.arm_mask]
        if fit_translation:
            D = D - D.mean(axis=0)
        errs.append(np.linalg.norm(D, axis=1))
    e = 1000 * np.concatenate(errs)
    return {"mean_mm": float(e.mean()), "median_mm": float(np.median(e)), "p90_mm": float(np.percentile(e, 90)),
            "n_meshes": len(samples)}


# --- learning -----------------------------------------------------------------------------------------

def unposed_sample(s: ArmSample, part_weights, predict_joints) -> np.ndarray:
    """A training mesh brought back to the model's shoulder-centred rest frame (n, 3), still with its pose term.

    Unposed about its skeleton (``joints``, else the regression), centred on ``rest_origin`` (else its
    shoulder ``joints[0]``).
    """
    J = s.joints if s.joints is not None else predict_joints(s.shape)
    origin = J[0] if s.rest_origin is None else np.asarray(s.rest_origin, dtype=np.float64).reshape(3)
    return unpose_arm(s.vertices, part_weights, J, s.pose) - origin


def body_space_rest_mesh(space: BodyShapeSpace, rest: np.ndarray, shape: ArmShapeParams,
                         prior_weight: float = CAPTURED_REST_PRIOR_WEIGHT, iterations: int = 8,
                         weight_prior_weight: float | None = None):
    """A rest mesh (n, 3) as its nearest arm of the body model's shape space (dataset extension of captures).

    Gauss-Newton over the body parameters ``x`` (macro values, local target weights) and a free translation ``t``:
    ``min |B(x) + t - rest|^2 + prior``, ``B(x)`` the space's rest arm relative to its own shoulder (MakeHuman's joint
    regressor), the prior the population's (:meth:`BodyShapeSpace.prior`: gender and muscle at the subject's sex and
    muscularity, nothing from its BMI or height) with ``prior_weight`` per vertex on the standardised parameters in
    (1 mm)^2, started at its mean. Returns ``(B(x), x, t)``: the arm relative to the shoulder the body model puts
    in this skin (``rest - t`` is the given mesh so centred), the parameters, the shoulder's place in ``rest``'s frame.
    ``weight_prior_weight``: the weight macro's own prior weight (None: ``prior_weight``); the prior takes nothing from
    the BMI, so a strong prior pulls a heavy subject's weight to the population's (the extension's defaults, 30 and
    3: :data:`EXTENSION_ROW_PRIOR_WEIGHT`; docs/muscle.md, "Dataset extension, twelfth pass").

    Why: a depth capture sees the skin, not where the shoulder joint sits in it nor how the vertices lie along it;
    as a shape row, a captured rest mesh carried 0.02-0.6 of its subject's departure from the model, while its body
    space fit carries 0.4-0.9 (docs/muscle.md, seventh pass).
    """
    rest = np.asarray(rest, dtype=np.float64)
    if rest.shape != (space.n_vertices, 3) or not np.isfinite(rest).all():
        raise InputError(f"rest mesh of shape {rest.shape}: the body space's arm template has ({space.n_vertices}, 3)")
    _check_prior_weights(prior_weight, weight_prior_weight)
    mean, sigma = space.prior(shape)
    x, t = mean.copy(), np.zeros(3)
    n, P = len(rest), len(mean)
    weights = np.full(P, float(prior_weight))
    if weight_prior_weight is not None:
        weights[BODY_MACRO_NAMES.index("weight")] = weight_prior_weight
    lam = np.r_[weights * n * 1e-6 / sigma ** 2, np.zeros(3)]
    translation = np.tile(np.eye(3), (n, 1))
    for _ in range(iterations):
        R = space.shaped_rows(x)
        r = (R[:-3] - R[-3] + t - rest).ravel()
        G = np.c_[space.jacobian(x)[:, :-3].reshape(P, -1).T, translation]
        step = np.linalg.solve(G.T @ G + np.diag(lam), -(G.T @ r) - lam * np.r_[x - mean, np.zeros(3)])
        x, t = x + step[:P], t + step[P:]
        x[:len(BODY_MACRO_NAMES)] = np.clip(x[:len(BODY_MACRO_NAMES)], 0.0, 1.0)
    R = space.shaped_rows(x)
    return R[:-3] - R[-3], x, t


def _check_prior_weights(prior_weight: float, weight_prior_weight: float | None) -> None:
    if not (np.isfinite(prior_weight) and prior_weight > 0):
        raise InputError(f"prior_weight={prior_weight} must be > 0")
    if weight_prior_weight is not None and not (np.isfinite(weight_prior_weight) and weight_prior_weight > 0):
        raise InputError(f"weight_prior_weight={weight_prior_weight} must be > 0 (or None: prior_weight's)")


def body_space_for_model(model: ArmModel) -> BodyShapeSpace:
    """The body model's shape space on ``model``'s arm template (resolution and side from its template key)."""
    resolution, side = model.template_key.split("-")[:2]
    space = _body_shape_space(resolution, side)
    if space.n_vertices != model.n_vertices:
        raise InputError(f"arm model template {model.template_key}: the body model's {resolution} {side} arm has "
                         f"{space.n_vertices} vertices, not {model.n_vertices}; rebuild the model")
    return space


def _subject_rows(samples: list[ArmSample], part_weights, predict_joints, prior: ArmModel | None,
                  body_space: BodyShapeSpace | None = None, prior_weight: float = CAPTURED_REST_PRIOR_WEIGHT,
                  weight_prior_weight: float | None = None):
    """Unposed meshes of one subject -> (base-pose rows, subject base mesh, pose rows (angles, d)).

    ``body_space``: a captured subject's shape row is its rest mesh's nearest body-space arm
    (:func:`body_space_rest_mesh`); the pose rows stay relative to the captured rest mesh."""
    unposed, angles = [], []
    for s in samples:
        unposed.append(unposed_sample(s, part_weights, predict_joints))
        angles.append(s.pose.angles.reshape(9))
    unposed, angles = np.stack(unposed), np.stack(angles)
    in_base = np.abs(angles.reshape(-1, 3, 3)).max(axis=(1, 2)) <= BASE_POSE_TOL_RAD
    if in_base.any():
        base_rows = unposed[in_base]
    elif prior is not None:
        # No base-pose mesh (a captured sequence): remove the prior's pose term from every frame; the frames'
        # mean is the subject's one shape row. Every frame shows the same rest shape (the frames' rows of a
        # capture differ by ~1 mm against 4-23 mm of residual), so a row per frame weighed a captured subject by
        # its frame count against a training subject's 1-3 base-pose meshes. Measured (docs/muscle.md, sixth
        # pass), held-out sets A / B: a row per frame -11.7 / -11.7 %, one row -12.3 / -14.1 %.
        base_rows = np.mean([u - pose_displacements(prior, a) for u, a in zip(unposed, angles, strict=True)],
                            axis=0)[None]
        if body_space is not None:
            base = base_rows[0]
            row = body_space_rest_mesh(body_space, base, samples[0].shape, prior_weight,
                                       weight_prior_weight=weight_prior_weight)[0]
            return row[None], base, angles, unposed - base
    else:
        raise InputError(f"subject {samples[0].subject!r} has no mesh in the base pose (all joint angles "
                         f"< {np.degrees(BASE_POSE_TOL_RAD):.0f} deg); add one or extend an existing model")
    base = base_rows.mean(axis=0)
    return base_rows, base, angles, unposed - base


def _group(samples: list[ArmSample]) -> dict[str, list[ArmSample]]:
    groups: dict[str, list[ArmSample]] = {}
    for s in samples:
        groups.setdefault(s.subject, []).append(s)
    return groups


def _check_samples(samples: list[ArmSample], n: int) -> None:
    if not samples:
        raise InputError("no training meshes given; the arm model needs at least one subject")
    for s in samples:
        if np.shape(s.vertices) != (n, 3) or not np.isfinite(s.vertices).all():
            raise InputError(f"subject {s.subject!r}: mesh has shape {np.shape(s.vertices)}, the arm template "
                             f"needs ({n}, 3) finite vertices; use the same template (resolution, side)")


def learn_arm_model(samples: list[ArmSample], template: ArmTemplate, regularization: float = 1.0,
                    population_size: int = 40, population_seed: int = 114, source: str = "training",
                    sex_regularization: float = SEX_REGULARIZATION, sex_slopes: bool = SEX_SLOPES) -> ArmModel:
    """Learn the model of Eq. 6-10 from training meshes (several subjects, base pose + other poses); ``sex_slopes``:
    the shape term with the women's own slopes (:func:`shape_design`)."""
    _check_samples(samples, template.n_vertices)
    if regularization < 0:
        raise InputError(f"regularization={regularization} must be >= 0")
    if sex_slopes and not regularization > 0:  # the women's slopes of a set without women: q = 0 leaves them singular
        raise InputError(f"regularization={regularization}: the women's own slopes (sex_slopes) need a regularization "
                         "> 0")
    if not sex_regularization > 0:  # the sex column of an all-male set is zero: q = 0 leaves it singular
        raise InputError(f"sex_regularization={sex_regularization} must be > 0")
    popV, popJ, popP = population_arms(template.resolution, template.side, population_size, population_seed)
    N = len(popV)
    X = (popV - popJ[:, :1]).reshape(N, -1)  # shoulder-centred
    base = X.mean(axis=0)
    _, _, Vt = np.linalg.svd(X - base, full_matrices=False)
    k = min(N_LENGTH_COMPONENTS, N - 1)
    E = Vt[:k]
    coeffs = (X - base) @ E.T
    center, scale = popP.mean(axis=0), popP.std(axis=0) + 1e-12
    Zp = (popP - center) / scale
    length_coeffs = tikhonov_least_squares(_design(Zp[:, 3:4]), coeffs, regularization)
    Xj = _design(Zp)
    joint_xtx, joint_xty = Xj.T @ Xj, Xj.T @ popJ.reshape(N, 9)
    joint_coeffs = tikhonov_from_normal_equations(joint_xtx, joint_xty, regularization)
    model = ArmModel(template.key, template.faces.copy(), template.part_weights.copy(), template.arm_mask.copy(),
                     base.reshape(-1, 3), E, length_coeffs, joint_coeffs,
                     np.zeros((2 + SHAPE_REGRESSORS * (2 if sex_slopes else 1), X.shape[1])),
                     np.zeros((10, X.shape[1])), center, scale, float(regularization),
                     np.zeros((0, 5)), np.zeros((0, X.shape[1])), np.zeros((10, 10)), np.zeros((10, X.shape[1])),
                     joint_xtx, joint_xty, sex_regularization=float(sex_regularization), sex_slopes=bool(sex_slopes))
    return _add_subjects(model, samples, prior=None, source=source)


def training_rows_per_subject(model: ArmModel) -> int:
    """Shape rows (base-pose meshes) of one of ``model``'s training subjects (``source == "training"``): the median
    over them of the stored rows with their shape parameters and sex; 1 without training subjects (or none whose
    shape is recorded)."""
    counts = []
    for s in model.subjects:
        if s.get("source") != "training" or not all(n in (s.get("shape") or {}) for n in SHAPE_NAMES):
            continue
        row = ArmShapeParams.from_dict(s["shape"]).as_row()
        counts.append(int(np.all(np.abs(model.shape_rows - row) <= 1e-12, axis=1).sum()))
    return max(1, int(round(float(np.median(counts))))) if counts else 1


def _add_subjects(model: ArmModel, samples: list[ArmSample], prior: ArmModel | None, source: str,
                  body_space: BodyShapeSpace | None = None,
                  prior_weight: float = CAPTURED_REST_PRIOR_WEIGHT, subject_rows: str = "own",
                  weight_prior_weight: float | None = None) -> ArmModel:
    """``subject_rows`` (:data:`SUBJECT_ROWS_CHOICES`): "training" repeats each added subject's base-pose rows up to
    :func:`training_rows_per_subject` of ``model`` (a subject counts as much as a training subject in Eq. 7)."""
    groups = _group(samples)
    rows_each = training_rows_per_subject(model) if subject_rows == "training" else 1
    taken = {s["name"] for s in model.subjects}
    clash = sorted(set(groups) & taken)
    if clash:
        raise InputError(f"subject(s) {', '.join(clash)} are already in the model; give the new captures other names")
    shape_rows, residuals = [model.shape_rows], [model.shape_residuals]
    xtx, xtd = model.pose_xtx.copy(), model.pose_xtd.copy()
    jtx, jty = model.joint_xtx.copy(), model.joint_xty.copy()
    subjects = list(model.subjects)
    for name, group in groups.items():
        shape = group[0].shape
        base_rows, _, angles, d = _subject_rows(group, model.part_weights, lambda s: model_joints(model, s), prior,
                                                body_space, prior_weight, weight_prior_weight)
        if len(base_rows) < rows_each:
            base_rows = base_rows[np.arange(rows_each) % len(base_rows)]
        expected = model.base_vertices + length_displacements(model, shape)
        shape_rows.append(np.tile(shape.as_row(), (len(base_rows), 1)))
        residuals.append((base_rows - expected).reshape(len(base_rows), -1))
        Xp = _design(angles)
        xtx += Xp.T @ Xp
        xtd += Xp.T @ d.reshape(len(d), -1)
        known = [s.joints for s in group if s.joints is not None]
        if known:  # subjects with measured joints refine the joint regression (as population rows do)
            xj = np.r_[1.0, _z(model, shape.as_vector())]
            jtx += np.outer(xj, xj)
            jty += np.outer(xj, np.mean(known, axis=0).reshape(9))
        entry = {"name": name, "shape": shape.to_dict(), "n_meshes": len(group), "source": source}
        in_base = [np.abs(s.pose.angles).max() <= BASE_POSE_TOL_RAD for s in group]
        if body_space is not None and prior is not None and not any(in_base):  # _subject_rows' body-space row
            entry["rest"] = f"body space (prior weight {prior_weight:g})" if weight_prior_weight is None else \
                f"body space (prior weight {prior_weight:g}, weight macro {weight_prior_weight:g})"
        subjects.append(entry)
    rows, R = np.concatenate(shape_rows), np.concatenate(residuals)
    q = model.regularization
    params = body_coeffs = None
    if model.shape_form == "body":
        known = model.shape_params if model.shape_params is not None else np.zeros((0, 0))
        n_known = len(known) if len(known) == len(model.shape_rows) else 0  # a linear model's rows: projected here
        new = shape_row_parameters(model, rows[n_known:], R[n_known:])
        params = np.concatenate([known[:n_known].reshape(n_known, new.shape[1]), new])
        body_coeffs, shape_coeffs = fit_body_form(model, rows, R, params)
    else:
        shape_coeffs = fit_shape_coefficients(model, rows, R)
    pose_coeffs = tikhonov_from_normal_equations(xtx, xtd, q)
    joint_coeffs = tikhonov_from_normal_equations(jtx, jty, q)
    return replace(model, shape_coeffs=shape_coeffs, pose_coeffs=pose_coeffs, joint_coeffs=joint_coeffs,
                   shape_rows=rows, shape_residuals=R, pose_xtx=xtx, pose_xtd=xtd, joint_xtx=jtx, joint_xty=jty,
                   subjects=subjects, shape_params=params, body_coeffs=body_coeffs)


def extend_arm_model(model: ArmModel, captures: list[ArmSample], source: str = "capture",
                     captured_rest: str = "mesh", prior_weight: float = EXTENSION_ROW_PRIOR_WEIGHT,
                     shape_form: str | None = None, subject_rows: str = SUBJECT_ROWS,
                     weight_prior_weight: float | None = EXTENSION_ROW_WEIGHT_PRIOR_WEIGHT) -> ArmModel:
    """Dataset extension (§1 contribution 2, issue §4): add captured subjects and re-learn Eq. 6-10.

    Subjects without a base-pose mesh (captured sequences) get their base mesh from every frame minus
    the current model's pose term, averaged over the frames into one shape row (a subject counts once
    in Eq. 7, however many frames were captured). The population terms (v_base, d_l, joints) are kept.
    ``captured_rest``: that row as captured (``"mesh"``) or its nearest arm of the body model's shape space
    (``"body"``, :func:`body_space_rest_mesh` with ``prior_weight`` and ``weight_prior_weight``; the benchmark's and
    ``muscle model extend``'s default). Subjects with a base-pose mesh (ground truth) are added as they are either way.
    ``shape_form``: the extended model's shape term (:data:`SHAPE_FORMS`; None keeps ``model``'s); "body" on a linear
    model projects its stored rows into the body space first (the pose and joint terms are unchanged).
    ``subject_rows``: "own" (default, :data:`SUBJECT_ROWS`) keeps the rows an added subject brings; "training" repeats
    them up to the rows a training subject of ``model`` has, so that it weighs as much in Eq. 7 (measured, not kept:
    docs/muscle.md, "Dataset extension, tenth pass").
    ``weight_prior_weight``: the weight macro's prior weight in a captured row's body-space fit (None:
    ``prior_weight``'s; :func:`body_space_rest_mesh`). The defaults ``prior_weight=30, weight_prior_weight=3`` (3 and
    3 before) lower the held-out sets C and D's error with two sets of added subjects (docs/muscle.md, "Dataset
    extension, twelfth pass").
    """
    _check_samples(captures, model.n_vertices)
    if captured_rest == "body":
        _check_prior_weights(prior_weight, weight_prior_weight)
    if subject_rows not in SUBJECT_ROWS_CHOICES:
        raise InputError(f"subject_rows={subject_rows!r} must be one of {', '.join(SUBJECT_ROWS_CHOICES)}")
    if captured_rest not in CAPTURED_REST_CHOICES:
        raise InputError(f"captured_rest={captured_rest!r} must be one of {', '.join(CAPTURED_REST_CHOICES)}")
    if shape_form is not None and shape_form not in SHAPE_FORMS:
        raise InputError(f"shape_form={shape_form!r} must be one of {', '.join(SHAPE_FORMS)}")
    space = body_space_for_model(model) if captured_rest == "body" or shape_form == "body" else None
    target = with_shape_form(model, shape_form or model.shape_form)
    return _add_subjects(target, captures, prior=model, source=source,
                         body_space=space if captured_rest == "body" else None, prior_weight=prior_weight,
                         subject_rows=subject_rows, weight_prior_weight=weight_prior_weight)


def with_shape_form(model: ArmModel, shape_form: str, body_weight: str | None = None) -> ArmModel:
    """``model`` with its shape term in ``shape_form`` (:data:`SHAPE_FORMS`), learned from its own stored rows (a
    linear model's rows are projected into the body space for the body form; the other terms are unchanged).
    ``body_weight``: the body form's weight macro (:data:`BODY_WEIGHT_CHOICES`; None: a body-form model's own, else
    :data:`BODY_FORM_WEIGHT`)."""
    if shape_form not in SHAPE_FORMS:
        raise InputError(f"shape_form={shape_form!r} must be one of {', '.join(SHAPE_FORMS)}")
    if body_weight is not None and body_weight not in BODY_WEIGHT_CHOICES:
        raise InputError(f"body_weight={body_weight!r} must be one of {', '.join(BODY_WEIGHT_CHOICES)}")
    if shape_form == model.shape_form and (shape_form == "linear" or body_weight in (None, model.body_weight)):
        return model
    if shape_form == "linear":
        return replace(model, shape_form="linear", shape_params=None, body_coeffs=None, body_weight="regressed",
                       shape_coeffs=fit_shape_coefficients(model, model.shape_rows, model.shape_residuals))
    if model.shape_form == "body":
        params = model.shape_params
    else:
        params = shape_row_parameters(model, model.shape_rows, model.shape_residuals)
    converted = replace(model, shape_form="body", shape_params=params, body_weight=body_weight or BODY_FORM_WEIGHT)
    body_coeffs, shape_coeffs = fit_body_form(converted, model.shape_rows, model.shape_residuals, params)
    return replace(converted, body_coeffs=body_coeffs, shape_coeffs=shape_coeffs)


# --- files ----------------------------------------------------------------------------------------------

_ARRAYS = ("faces", "part_weights", "arm_mask", "base_vertices", "length_basis", "length_coeffs", "joint_coeffs",
           "shape_coeffs", "pose_coeffs", "param_center", "param_scale", "shape_rows", "shape_residuals",
           "pose_xtx", "pose_xtd", "joint_xtx", "joint_xty")


def save_arm_model(path: str | os.PathLike, model: ArmModel) -> None:
    """Write the model as a versioned ``.npz`` (atomic): arrays + JSON header (format, version, key, subjects)."""
    header = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "template_key": model.template_key,
              "regularization": model.regularization, "sex_regularization": model.sex_regularization,
              "subjects": model.subjects, "shape_form": model.shape_form}
    if model.sex_slopes:  # written only when on: the files of models without them stay as they were
        header["sex_slopes"] = True
    body = {}
    if model.shape_form == "body":
        body = {"shape_params": model.shape_params, "body_coeffs": model.body_coeffs}
        header["body_space"] = {"local_targets": list(body_space_for_model(model).local_names)}
        header["body_weight"] = model.body_weight
    with atomic_write(path, "wb") as f:
        np.savez_compressed(f, header=np.array(json.dumps(header)), **{k: getattr(model, k) for k in _ARRAYS}, **body)


def load_arm_model(path: str | os.PathLike, template: ArmTemplate | None = None) -> ArmModel:
    """Read a model written by :func:`save_arm_model`; refuse junk, other versions and other templates."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such arm model file; build one with `bodystudio muscle model build`")
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(str(z["header"]))
            arrays = {k: np.array(z[k]) for k in _ARRAYS}
            body = {k: np.array(z[k]) for k in ("shape_params", "body_coeffs") if k in z.files}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, EOFError) as exc:
        raise FileFormatError(f"{path}: not a bodystudio arm model ({type(exc).__name__}: {exc}); "
                              "rebuild it with `bodystudio muscle model build`") from None
    if not isinstance(header, dict) or header.get("format") != MODEL_FORMAT:
        raise FileFormatError(f"{path}: not a bodystudio arm model (format {header.get('format')!r})"
                              if isinstance(header, dict) else f"{path}: not a bodystudio arm model")
    version = header.get("version")
    if version not in (1, 2, MODEL_VERSION) or isinstance(version, bool):
        raise FileFormatError(f"{path}: arm model version {version!r} is not supported (this "
                              f"bodystudio reads versions 1-{MODEL_VERSION}); rebuild it with "
                              "`bodystudio muscle model build`")
    if not isinstance(header.get("template_key"), str) or not isinstance(header.get("regularization"), (int, float)) \
            or not isinstance(header.get("subjects", []), list):
        raise FileFormatError(f"{path}: arm model header lacks template_key / regularization / subjects; "
                              "rebuild it with `bodystudio muscle model build`")
    n = len(arrays["base_vertices"])
    if version == 1:
        arrays = _upgrade_version_1(path, arrays)
    sex_q = header.get("sex_regularization", SEX_REGULARIZATION)
    if isinstance(sex_q, bool) or not isinstance(sex_q, (int, float)) or not 0 < sex_q < np.inf:
        raise FileFormatError(f"{path}: arm model sex_regularization {sex_q!r} is not a positive number; "
                              "rebuild the model")
    sex_slopes = header.get("sex_slopes", False)
    if not isinstance(sex_slopes, bool):
        raise FileFormatError(f"{path}: arm model sex_slopes {sex_slopes!r} is not true or false; rebuild the model")
    if arrays["shape_coeffs"].shape[0] != 2 + SHAPE_REGRESSORS * (2 if sex_slopes else 1) \
            or arrays["shape_rows"].shape[1:] != (5,) \
            or len(arrays["shape_rows"]) != len(arrays["shape_residuals"]):
        raise FileFormatError(f"{path}: arm model shape arrays are inconsistent; rebuild the model")
    if arrays["pose_coeffs"].shape != (10, 3 * n) or arrays["shape_coeffs"].shape[1:] != (3 * n,) \
            or not all(np.isfinite(arrays[k]).all() for k in ("base_vertices", "pose_coeffs", "shape_coeffs")):
        raise FileFormatError(f"{path}: arm model arrays are inconsistent or not finite; rebuild the model")
    form = header.get("shape_form", "linear")  # version 1-2 files: the linear form
    if form not in SHAPE_FORMS:
        raise FileFormatError(f"{path}: arm model shape_form {form!r} is not one of {', '.join(SHAPE_FORMS)}; "
                              "rebuild the model")
    if form == "body":
        params, coeffs = body.get("shape_params"), body.get("body_coeffs")
        if params is None or coeffs is None or params.ndim != 2 or len(params) != len(arrays["shape_rows"]) \
                or coeffs.shape != (3 + SHAPE_REGRESSORS, params.shape[1]) or not np.isfinite(coeffs).all():
            raise FileFormatError(f"{path}: arm model of the body form lacks consistent shape_params / body_coeffs; "
                                  "rebuild the model")
        weight = header.get("body_weight", "regressed")  # files before the ninth pass: the regressed weight
        if weight not in BODY_WEIGHT_CHOICES:
            raise FileFormatError(f"{path}: arm model body_weight {weight!r} is not one of "
                                  f"{', '.join(BODY_WEIGHT_CHOICES)}; rebuild the model")
        body = {"shape_params": params, "body_coeffs": coeffs, "body_weight": weight}
    else:
        body = {}
    model = ArmModel(header["template_key"], **{k: arrays[k] for k in _ARRAYS if k != "arm_mask"},
                     arm_mask=arrays["arm_mask"].astype(bool), regularization=float(header["regularization"]),
                     subjects=list(header.get("subjects", [])), version=MODEL_VERSION,
                     sex_regularization=float(sex_q), shape_form=form, sex_slopes=sex_slopes, **body)
    if form == "body":
        saved = (header.get("body_space") or {}).get("local_targets")
        space = body_space_for_model(model)
        if saved != list(space.local_names) or space.n_parameters != body["body_coeffs"].shape[1]:
            raise FileFormatError(f"{path}: arm model of the body form was learned on another body shape space "
                                  f"({len(saved or [])} local targets, this body model's {len(space.local_names)}); "
                                  "re-extend it with `bodystudio muscle model extend --shape-form body`")
    if template is not None and template.key != model.template_key:
        raise InputError(f"{path}: model was built for arm template {model.template_key}, not {template.key}; "
                         "use the same --resolution and --side as the model or rebuild it for this template")
    return model


def _upgrade_version_1(path: Path, arrays: dict) -> dict:
    """A version-1 model (no sex input) as version 2: its subjects male, the sex term zero (same meshes)."""
    rows, coeffs = arrays["shape_rows"], arrays["shape_coeffs"]
    if rows.ndim != 2 or rows.shape[1] != 4 or coeffs.ndim != 2 or len(coeffs) != 1 + SHAPE_REGRESSORS:
        raise FileFormatError(f"{path}: version-1 arm model arrays are inconsistent; rebuild the model")
    log.warning("%s: arm model version 1 (no sex input) read as version %d with every subject male; "
                "`bodystudio muscle model extend` writes the new version", path, MODEL_VERSION)
    return {**arrays, "shape_rows": np.c_[rows, np.ones(len(rows))],
            "shape_coeffs": np.r_[coeffs, np.zeros((1, coeffs.shape[1]))]}


def capture_samples(capture, name: str, shape: ArmShapeParams | None = None, stride: int = 1,
                    model: ArmModel | None = None, centre: str = "fitted") -> list[ArmSample]:
    """Captured frames as training meshes for :func:`extend_arm_model` (issue §4).

    ``capture`` is a ``bodystudio.muscle.capture.ArmCapture``: each ``stride``-th frame with a pose is
    brought back to template space (inverse of its §5.1 similarity ``(s, R, t)``: ``x = R^T (y - t) / s``)
    and paired with that pose and ``shape`` (default: the capture's fitted shape). The joints are the
    capture's fitted skeleton (``capture.joints``, the rest joints its poses turn about) when it has one,
    else left to the model's regression, as the capture's model fit used them.

    ``centre``: where the unposed mesh is centred in the model's shoulder frame. ``"fitted"``: on the
    fitted shoulder ``joints[0]`` (as a ground-truth mesh on its own skeleton). ``"regressed"``: on the
    shoulder that ``model`` (the model the capture was made with) regresses from the capture's shape -
    where the capture's rest mesh sits (``refine.skeleton_model_mesh`` holds the rest mesh and moves the
    joints inside it), so a fitted shoulder's error is not copied into the residual as a translation.
    ``"sex"``: the fitted shoulder for a woman, the regressed one for a man (the joint regression has no
    sex input - a population of both sexes plus the all-male training subjects - so a woman's regressed
    shoulder is a sex-averaged one: her fitted one carries what the regression lacks, while a man's fit
    mostly adds its placement error; docs/muscle.md, fifth pass).
    With the regressed skeleton (no skeleton fit) all three are the same.
    """
    if stride < 1:
        raise InputError(f"stride={stride} must be >= 1")
    if centre not in ("fitted", "regressed", "sex"):
        raise InputError(f"centre={centre!r} must be 'fitted', 'regressed' or 'sex'")
    shape = shape if shape is not None else capture.shape
    if shape is None:
        raise InputError(f"capture {name!r} has no shape parameters (a no-model capture); give them with "
                         "--shape bmi=..,muscularity=..,height_m=..,arm_length_m=..")
    origin, centre_arg = None, centre
    if centre == "sex":
        centre = "fitted" if shape.sex < 0.5 else "regressed"
    if centre == "regressed":
        if model is None and getattr(capture, "regressed_joints", None) is None:
            raise InputError(f"capture {name!r}: centre={centre_arg!r} needs the model the capture was made with "
                             "(model=...) for its regressed shoulder")
        recorded = getattr(capture, "regressed_joints", None)
        if recorded is not None:  # the capture's own model's shoulder, whichever model is extended
            origin = np.asarray(recorded, dtype=np.float64)[0]
        else:  # a capture written before it was recorded: MODEL is taken as the capture's model
            origin = model_joints(model, capture.shape if isinstance(capture.shape, ArmShapeParams) else shape)[0]
    s, R, t = capture.similarity
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    out = []
    for k in range(0, len(capture.vertices), stride):
        if capture.poses[k] is None:
            continue
        V = ((np.asarray(capture.vertices[k], dtype=np.float64) - t) @ R) / float(s)
        out.append(ArmSample(name, shape, V, capture.poses[k], getattr(capture, "joints", None), origin))
    if not out:
        raise InputError(f"capture {name!r} has no frames with joint angles (a no-model capture); "
                         "capture it with the model to extend the dataset")
    return out


# --- the body model's own shape space (replaces Eq. 6-9 per subject; issue 11, eighth pass) ---------------------

#: macro parameters of the body model fitted per subject (MakeHuman's; :class:`bodystudio.body.Phenotype`)
BODY_MACRO_NAMES = ("gender", "age", "muscle", "weight", "height", "proportions", "african", "asian", "caucasian")
#: population mean and spread of each macro parameter (``bodystudio.body.population``'s distribution: gender a
#: coin mixed to the middle, age U(0.5, 0.875), weight 0.15 + 0.8 Beta(3, 3), height ~0.5 +- 0.07, proportions
#: U(0.3, 0.8), ethnic Dirichlet(1, 1, 1)); gender and muscle are centred on the measured sex / muscularity instead
BODY_MACRO_PRIOR = {"gender": (0.5, 0.05), "age": (0.6875, 0.108), "muscle": (0.5, 0.05), "weight": (0.55, 0.15),
                    "height": (0.5, 0.07), "proportions": (0.55, 0.144), "african": (1 / 3, 0.24),
                    "asian": (1 / 3, 0.24), "caucasian": (1 / 3, 0.24)}
#: spread of a local target's weight in the prior (MakeHuman's local modifiers, [-1, 1]; the population samples
#: its few at sigma 0.15-0.25)
BODY_LOCAL_PRIOR_SIGMA = 0.25
#: a local target enters the space when it moves a vertex of the arm region or one of its joints at least this far
BODY_LOCAL_MIN_EFFECT_M = 0.002


@dataclass(frozen=True, eq=False)
class BodyShapeSpace:
    """The body model's shape space restricted to an arm template: rest arm and joints as functions of the macro
    parameters (:data:`BODY_MACRO_NAMES`) and of the weights of the local targets that move the region.

    ``rows`` are the template's vertices followed by the shoulder, elbow and wrist heads (each a linear function of
    the full body's vertices: :func:`bodystudio.body.skeleton.skeleton_from_vertices`); ``base`` (r, 3) their
    unshaped positions, ``macro_deltas`` (M, r, 3) / ``local_deltas`` (L, r, 3) the targets restricted to them.
    A parameter vector ``x`` is the macro values then the local target weights."""

    base: np.ndarray
    macro_names: list
    macro_deltas: np.ndarray
    local_names: list
    local_deltas: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.base) - 3

    @property
    def n_parameters(self) -> int:
        return len(BODY_MACRO_NAMES) + len(self.local_names)

    def macro_weights(self, x: np.ndarray) -> np.ndarray:
        """Weights (M,) of the macro targets for the macro values ``x[:9]`` (MakeHuman's blend)."""
        from bodystudio.body.phenotype import Phenotype, macro_target_weights

        v = np.clip(np.asarray(x[:len(BODY_MACRO_NAMES)], np.float64), 0.0, 1.0)
        v[6:] = np.maximum(v[6:], 1e-3)  # the ethnic weights are normalised by their sum
        w = macro_target_weights(Phenotype(**dict(zip(BODY_MACRO_NAMES, v.tolist(), strict=True))), self.macro_names)
        return np.array([w.get(n, 0.0) for n in self.macro_names])

    def shaped_rows(self, x: np.ndarray) -> np.ndarray:
        """The rows (r, 3) for parameters ``x``: the region's vertices and the three joints."""
        x = np.asarray(x, np.float64)
        return (self.base + np.einsum("m,mrd->rd", self.macro_weights(x), self.macro_deltas)
                + np.einsum("l,lrd->rd", x[len(BODY_MACRO_NAMES):], self.local_deltas))

    def rest_and_joints(self, x: np.ndarray, shoulder: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Rest arm (n, 3) and rest shoulder, elbow, wrist (3, 3), moved so the shoulder is at ``shoulder``
        (default the origin: the model's shoulder-centred frame)."""
        R = self.shaped_rows(x)
        R = R - R[-3] + (np.zeros(3) if shoulder is None else np.asarray(shoulder, np.float64))
        return R[:-3], R[-3:]

    def jacobian(self, x: np.ndarray, step: float = 1e-4) -> np.ndarray:
        """d rows / d x (P, r, 3), shoulder-relative (the shoulder row's derivative subtracted): the macro columns by
        one-sided differences into the unit interval (MakeHuman's blend is piecewise multilinear), the local ones
        exact."""
        x = np.asarray(x, np.float64)
        m = len(BODY_MACRO_NAMES)
        w0 = self.macro_weights(x)
        cols = []
        for k in range(m):
            h = step if x[k] + step <= 1.0 else -step
            xk = x.copy()
            xk[k] += h
            cols.append(np.einsum("m,mrd->rd", (self.macro_weights(xk) - w0) / h, self.macro_deltas))
        D = np.concatenate([np.stack(cols), self.local_deltas]) if cols else self.local_deltas
        return D - D[:, -3:-2]

    def prior(self, shape=None, local_sigma: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Prior mean and spread (P,) of the parameters: the population's, gender and muscle at the measured sex and
        muscularity of ``shape`` (an ArmShapeParams) when given, local weights 0, each with spread
        :data:`BODY_LOCAL_PRIOR_SIGMA` or ``local_sigma`` (L,) (e.g. :func:`population_local_sigma`)."""
        mean = np.array([BODY_MACRO_PRIOR[n][0] for n in BODY_MACRO_NAMES])
        sigma = np.array([BODY_MACRO_PRIOR[n][1] for n in BODY_MACRO_NAMES])
        if shape is not None:
            mean[0] = 0.05 + 0.9 * float(shape.sex) if shape.sex in (0.0, 1.0) else float(shape.sex)
            mean[2] = float(shape.muscularity)
        L = len(self.local_names)
        local = np.full(L, BODY_LOCAL_PRIOR_SIGMA) if local_sigma is None else np.asarray(local_sigma, np.float64)
        if local.shape != (L,) or not (local > 0).all():
            raise InputError(f"local_sigma must be {L} spreads > 0 (one per local target of the space), got shape "
                             f"{local.shape}")
        return np.r_[mean, np.zeros(L)], np.r_[sigma, local]


def population_local_sigma(space: BodyShapeSpace, other_sigma: float, scale: float = 1.0) -> np.ndarray:
    """Prior spread (L,) of the space's local target weights as the body population varies them
    (``bodystudio.body.population.LOCAL_SPREAD``: each sampled modifier's spread times ``scale`` on both of its
    targets, both sides), ``other_sigma`` on every target the population holds at 0 (the neck's, the torso's
    measurements, the forearm's scale ...).

    The macro prior (:data:`BODY_MACRO_PRIOR`) is the population's already; with every local target at
    :data:`BODY_LOCAL_PRIOR_SIGMA` the rest-shape fit explains the seen front with targets no subject of the
    population carries (507 / 504: the neck moved down, the forearm narrowed, the torso's depth shrunk), and the side no
    depth frame sees follows them (docs/muscle.md, fifteenth pass)."""
    from bodystudio.body.makehuman import load_base, load_targets
    from bodystudio.body.phenotype import local_target_weights
    from bodystudio.body.population import LOCAL_SPREAD

    if not (other_sigma > 0 and scale > 0):
        raise InputError(f"other_sigma and scale must be > 0, got {other_sigma} and {scale}")
    base = load_base()
    names = load_targets(len(base.vertices)).names
    sigma = np.full(len(space.local_names), float(other_sigma))
    index = {n: i for i, n in enumerate(space.local_names)}
    for modifier, spread in LOCAL_SPREAD.items():
        for value in (-1.0, 1.0):
            for target in local_target_weights({modifier: value}, base.data_dir, names):
                if target in index:
                    sigma[index[target]] = spread * scale
    return sigma


@lru_cache(maxsize=4)
def _body_shape_space(resolution: str, side: str) -> BodyShapeSpace:
    from bodystudio.body.makehuman import load_base, load_targets
    from bodystudio.body.model import rig_definition, template_topology
    from bodystudio.body.phenotype import local_modifiers
    from bodystudio.muscle.arm import _region, _side_suffix

    base = load_base()
    lib = load_targets(len(base.vertices))
    ids, _ = template_topology(resolution)
    arm_ids, _ = _region(resolution, side)
    full_ids = arm_ids if ids is None else np.asarray(ids)[arm_ids]
    rig = rig_definition()
    s = _side_suffix(side)
    heads = rig.head_regressor[[rig.bone_names.index(f"{b}{s}") for b in ("upperarm", "lowerarm", "hand")]]
    n_all = len(base.vertices)

    def restrict(V):  # (n_all, 3) -> rows (r, 3)
        return np.concatenate([V[full_ids], heads @ V])

    def target_rows(name):
        idx, d = lib.delta(name)
        D = np.zeros((n_all, 3))
        D[idx] = d
        return restrict(D)

    macro_names = [n for n in lib.names if n.startswith("macrodetails/")]
    other = "r-" if side == "left" else "l-"
    local_names = []
    for mod, pair in sorted(local_modifiers(base.data_dir).items()):
        if mod.startswith(other):
            continue
        for t in pair:
            full = next((n for n in lib.names if not n.startswith("macrodetails") and n.rsplit("/", 1)[-1] == t), None)
            if t and full is not None and full not in local_names:
                local_names.append(full)
    local = [(n, target_rows(n)) for n in local_names]
    local = [(n, D) for n, D in local if np.abs(D - D[-3]).max() >= BODY_LOCAL_MIN_EFFECT_M]
    return BodyShapeSpace(restrict(np.asarray(base.vertices, np.float64)), macro_names,
                          np.stack([target_rows(n) for n in macro_names]), [n for n, _ in local],
                          np.stack([D for _, D in local]) if local else np.zeros((0, len(full_ids) + 3, 3)))


def body_shape_space(template: ArmTemplate) -> BodyShapeSpace:
    """The body model's shape space on ``template``'s region (cached per resolution and side; needs the body
    assets): what a subject's rest arm can be in the model the synthetic and real subjects are shaped by, far
    richer than Eq. 6-9's five measurements (age, proportions, ethnic mix, MakeHuman's local arm, shoulder and
    torso targets)."""
    return _body_shape_space(template.resolution, template.side)


def body_parameters_of(phenotype, local: dict, space: BodyShapeSpace) -> np.ndarray:
    """The parameter vector of a body (its phenotype and local modifier values) in ``space`` (local targets outside
    the space are dropped): for tests and for the truth's own point in the space."""
    from bodystudio.body.makehuman import load_base, load_targets
    from bodystudio.body.phenotype import local_target_weights

    base = load_base()
    lib = load_targets(len(base.vertices))
    w = local_target_weights(local or {}, base.data_dir, lib.names)
    macro = [float(getattr(phenotype, n)) for n in BODY_MACRO_NAMES]
    return np.r_[macro, [w.get(n, 0.0) for n in space.local_names]]


def project_to_body_space(space: BodyShapeSpace, rest: np.ndarray, joints: np.ndarray, prior_mean: np.ndarray,
                          prior_sigma: np.ndarray, prior_weight: float = 1e-3, iterations: int = 6) -> np.ndarray:
    """The parameters whose rest arm and joints are nearest ``rest`` (n, 3) and ``joints`` (3, 3), both relative to
    their shoulder (Gauss-Newton on the vertex distances, a Tikhonov prior ``prior_weight`` per vertex on the
    standardised parameters, in (1 mm)^2): the point of the body space a regressed rest mesh (Eq. 6-9) stands for."""
    target = np.concatenate([np.asarray(rest, np.float64) - joints[0], np.asarray(joints, np.float64) - joints[0]])
    x = np.asarray(prior_mean, np.float64).copy()
    lam = prior_weight * len(target) * 1e-6 / np.asarray(prior_sigma, np.float64) ** 2
    for _ in range(iterations):
        R = space.shaped_rows(x)
        r = (R - R[-3] - target).ravel()
        G = space.jacobian(x).reshape(len(x), -1).T
        x += spd_solve(normal_matrix(G) + np.diag(lam), -normal_rhs(G, r) - lam * (x - prior_mean))
        x[:len(BODY_MACRO_NAMES)] = np.clip(x[:len(BODY_MACRO_NAMES)], 0.0, 1.0)
    return x


@lru_cache(maxsize=4)
def _body_measure(local_names: tuple) -> tuple:
    """What :func:`body_space_bmi` needs of the 6k body (the resolution :func:`measure_arm_shape` measures): its rest
    vertices (n, 3), the targets' deltas on them (3n, K) (the macro targets, then each local target of the space with
    its other-side twin: a local modifier moves both sides), the columns of the local twins, the faces closed over its
    boundary loops and those loops."""
    import igl
    import scipy.sparse as sp

    from bodystudio.body.makehuman import load_base, load_targets
    from bodystudio.body.measure import close_boundary_loops
    from bodystudio.body.model import template_topology

    base = load_base()
    lib = load_targets(len(base.vertices))
    ids, faces = template_topology("6k")
    ids = np.asarray(ids)
    macro = [n for n in lib.names if n.startswith("macrodetails/")]
    names, local_cols = list(macro), []
    for n in local_names:
        head, _, tail = n.rpartition("/")
        twin = {"l-": "r-", "r-": "l-"}.get(tail[:2])
        twin = f"{head}/{twin}{tail[2:]}" if twin else None
        cols = [len(names)]
        names.append(n)
        if twin is not None and twin in lib._row:
            cols.append(len(names))
            names.append(twin)
        local_cols.append(cols)
    rows = (3 * ids[:, None] + np.arange(3)).ravel()
    D = sp.csr_matrix(lib.matrix(names))[rows]
    V0 = np.asarray(base.vertices, np.float64)[ids]
    F = np.ascontiguousarray(faces, dtype=np.int64)
    loops = [np.asarray(loop, dtype=np.int64) for loop in igl.boundary_loop_all(F) if len(loop) >= 3]
    Fc = close_boundary_loops(V0, F)[1]
    return V0, D, macro, local_cols, Fc, loops


def body_space_bmi(space: BodyShapeSpace, x: np.ndarray) -> tuple[float, float]:
    """(BMI, stature m) of the body at body-space parameters ``x``, measured as :func:`measure_arm_shape` measures a
    subject (the 6k body's mass from its enclosed volume, its stature): the body model's own measurement. Local
    targets outside the space are zero."""
    from bodystudio.body.measure import BODY_DENSITY_KG_M3, enclosed_volume

    V0, D, macro, local_cols, Fc, loops = _body_measure(tuple(space.local_names))
    x = np.asarray(x, np.float64)
    w = np.zeros(D.shape[1])
    w[:len(macro)] = space.macro_weights(x)  # the space's macro targets are the same list (:func:`_body_shape_space`)
    for cols, v in zip(local_cols, x[len(BODY_MACRO_NAMES):], strict=True):
        w[cols] = v
    V = V0 + (D @ w).reshape(-1, 3)
    stature = float(V[:, 1].max() - V[:, 1].min())
    Vc = np.vstack([V, *(V[loop].mean(0, keepdims=True) for loop in loops)])
    return enclosed_volume(Vc, Fc) * BODY_DENSITY_KG_M3 / stature ** 2, stature


def body_weight_for_bmi(space: BodyShapeSpace, x: np.ndarray, bmi: float) -> float:
    """The weight macro in [0, 1] whose body, at the other parameters of ``x``, has BMI ``bmi`` through
    :func:`body_space_bmi` (Brent's method; 0 or 1 where the BMI is out of the body model's reach there): the weight
    a subject of that BMI has in the body model, as MakeHuman's weight and muscle macros make BMI non-linearly."""
    return _body_weight_for_bmi(space, np.asarray(x, np.float64).tobytes(), round(float(bmi), 9))


@lru_cache(maxsize=4096)
def _body_weight_for_bmi(space: BodyShapeSpace, key: bytes, bmi: float) -> float:
    from scipy.optimize import brentq

    x = np.frombuffer(key, dtype=np.float64).copy()
    w = BODY_MACRO_NAMES.index("weight")

    def excess(v):
        x[w] = v
        return body_space_bmi(space, x)[0] - bmi

    lo, hi = excess(0.0), excess(1.0)
    if lo >= 0.0:
        return 0.0
    if hi <= 0.0:
        return 1.0
    return float(brentq(excess, 0.0, 1.0, xtol=1e-4, rtol=1e-6, maxiter=30))
