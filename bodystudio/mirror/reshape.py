"""Shape deformation, §5.1 of Real-time Reshaping of Humans: the target body from semantic edits (Eq. 4).

The user's edits ``lambda_i`` (taller, heavier, more muscular, chest, waist, hip girth) move the source
body's coefficients along the statistical model's semantic directions, ``M^T = M^S + sum_i lambda_i w_i``
(Eq. 4; :meth:`bodystudio.body.statistical.StatisticalBodyModel.edit`, which then corrects with a few
Newton steps so the *measured* stature, mass and girths change by exactly the amounts asked, the
others held). Edits are validated against ranges an installation can show without breaking the body
model. "A gradual and continuous change of shape variations" (§5.1) is :func:`ramp_edits`, which moves
the shown edits toward the wanted ones by a bounded step per frame. The pose found for the source
skeleton is transferred to the target (same local rotations and root translation, the target's own
skeleton from Eq. 3), :func:`posed_source_and_target`.
"""

from __future__ import annotations

import math

import numpy as np

from bodystudio.body.pose import Pose, transfer_pose
from bodystudio.body.skeleton import Skeleton
from bodystudio.body.statistical import StatisticalBodyModel
from bodystudio.errors import InputError
from bodystudio.mirror.init import SourceBody, refit_skeleton_from_vertices
from bodystudio.mirror.track import skin_source_and_target, skin_vertices

EDIT_NAMES = ("taller", "heavier", "muscular", "chest", "waist", "hips")
#: The statistical model attribute each edit changes (units: metres, kg, the model's muscularity 0-1).
EDIT_ATTRIBUTES = {"taller": "stature_m", "heavier": "mass_kg", "muscular": "muscularity", "chest": "chest_m",
                   "waist": "waist_m", "hips": "hip_m"}
#: Allowed range of each edit (symmetric): beyond it the PCA model leaves the population it was learnt on.
EDIT_RANGES = {"taller": 0.30, "heavier": 40.0, "muscular": 0.5, "chest": 0.30, "waist": 0.30, "hips": 0.30}
EDIT_UNITS = {"taller": "m", "heavier": "kg", "muscular": "", "chest": "m", "waist": "m", "hips": "m"}
#: Where the target skeleton's root goes when its joints come from the model's regressor (:func:`target_skeleton`):
#: "model", moved by the regressor's change like every other joint (the ground truth's Eq. 4 target), or "source",
#: the source's rest root kept (before MIR12s).
TARGET_ROOT = "model"
#: Default largest change of each edit per frame in :func:`ramp_edits` (about 1 s for +-0.15 m or +-15 kg at 30 fps).
RAMP_STEP_PER_FRAME = {"taller": 0.005, "heavier": 0.5, "muscular": 0.02, "chest": 0.005, "waist": 0.005,
                       "hips": 0.005}


def check_edits(edits: dict[str, float] | None) -> dict[str, float]:
    """Validated edits: names in :data:`EDIT_NAMES`, finite, within :data:`EDIT_RANGES` (else a one-line InputError)."""
    out = {}
    for name, value in (edits or {}).items():
        if name not in EDIT_NAMES:
            raise InputError(f"unknown edit {name!r}; valid edits: {', '.join(EDIT_NAMES)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"edit {name} must be a number, got {value!r}") from None
        limit = EDIT_RANGES[name]
        if not math.isfinite(v) or abs(v) > limit:
            unit = f" {EDIT_UNITS[name]}" if EDIT_UNITS[name] else ""
            raise InputError(f"edit {name}={value} is out of range: use -{limit} to +{limit}{unit}")
        out[name] = v
    return out


def target_coeffs(model: StatisticalBodyModel, source_coeffs, edits: dict[str, float],
                  refine: bool = True) -> np.ndarray:
    """Eq. 4: the target body's coefficients, the source's moved along the semantic directions by ``edits``.

    With ``refine`` (default) the measured attributes change by exactly the edits, every other measured
    attribute held (``model.edit``, a few Newton steps, tens of ms); without it only the linear step
    ``c + sum_i lambda_i w_i`` of Eq. 4 (microseconds, for per-frame ramps).
    """
    edits = check_edits(edits)
    c = np.asarray(source_coeffs, dtype=np.float64)
    deltas = {EDIT_ATTRIBUTES[n]: v for n, v in edits.items() if v != 0.0}
    if not deltas:
        return c.copy()
    if refine:
        return model.edit(c, deltas)
    step = np.array([deltas.get(n, 0.0) for n in model.attribute_names])
    return c + step @ model.semantic_directions


def ramp_edits(current: dict[str, float], wanted: dict[str, float], max_step=None) -> dict[str, float]:
    """One frame of the gradual change of §5.1: each edit moves toward ``wanted`` by at most ``max_step``.

    ``max_step`` is a dict of per-frame limits (default :data:`RAMP_STEP_PER_FRAME`) or one number used
    for every edit in its own unit. Edits missing from ``wanted`` ramp back to 0.
    """
    wanted = check_edits(wanted)
    current = check_edits(current)
    if max_step is None:
        steps = RAMP_STEP_PER_FRAME
    elif isinstance(max_step, dict):
        steps = {**RAMP_STEP_PER_FRAME, **{k: float(v) for k, v in max_step.items()}}
    else:
        steps = dict.fromkeys(EDIT_NAMES, float(max_step))
    if any(not (s > 0) for s in steps.values()):
        raise InputError("ramp max_step must be positive")
    out = {}
    for name in EDIT_NAMES:
        now, goal = current.get(name, 0.0), wanted.get(name, 0.0)
        if name in current or name in wanted:
            out[name] = now + float(np.clip(goal - now, -steps[name], steps[name]))
    return out


def target_skeleton(source: SourceBody, target_vertices_rest, model: StatisticalBodyModel | None = None,
                    target_coeffs=None, keep_root: bool | None = None) -> Skeleton:
    """The target body's skeleton: with ``model`` and ``target_coeffs``, the source's joints moved by the change
    of the statistical model's own joints (its joint regressor, ``model.skeleton(c_T) - model.skeleton(c_S)``,
    exact for a target built as ``V_S + B(c_T) - B(c_S)``); else by Eq. 3 (joints move with their neighbouring
    vertices).

    The root bone is not a joint of the body but its anchor on the floor (the game_engine rig's ``Root``
    lies on the floor between the feet, where the pose's translation puts it). Eq. 3 would move it with the
    nearest vertices (the feet of a bigger body: +2 cm up and +4 cm forward for +17 cm / +15 kg), and since
    the root's head offset ``d`` enters the posed body untouched by the root's rotation (the posed target
    moves by ``(I - R_root) d``), the target then slid 4 cm along the world z axis whichever way the person
    faced (warp_iou 0.75 -> 0.86 on a MIR-SYNTH session with a side-on walk-in, docs/mirror.md): with Eq. 3
    the root keeps the source's rest head and tail. The model's regressor moves it by a few millimetres
    (-3 to +6 mm forward for +-10 cm with -+15 kg), and the Eq. 4 target of the ground truth
    (``synthetic.target_rest_body``) moves it so: with ``model`` the root follows the regressor too unless
    ``keep_root`` (default :data:`TARGET_ROOT` == "source"), which cost a person side-on ~4 mm (0.7 px) of
    the displacement (MIR12s).
    """
    regressed = model is not None and target_coeffs is not None
    if regressed:
        sk_s, sk_t = model.skeleton(source.coeffs), model.skeleton(target_coeffs)
        src = source.skeleton
        skeleton = Skeleton(src.bone_names, src.parents, src.heads + sk_t.heads - sk_s.heads,
                            src.tails + sk_t.tails - sk_s.tails, src.rolls)
        if not (TARGET_ROOT == "source" if keep_root is None else keep_root):
            return skeleton
    else:
        skeleton = refit_skeleton_from_vertices(source.vertices, source.skeleton, target_vertices_rest,
                                                source.joint_neighbourhoods)
    heads, tails = skeleton.heads.copy(), skeleton.tails.copy()
    roots = np.flatnonzero(np.asarray(skeleton.parents) < 0)
    heads[roots], tails[roots] = source.skeleton.heads[roots], source.skeleton.tails[roots]
    return Skeleton(skeleton.bone_names, skeleton.parents, heads, tails, skeleton.rolls)


def posed_source_and_target(source: SourceBody, target_vertices_rest, pose: Pose, target_rig=None,
                            subset=None) -> tuple[np.ndarray, np.ndarray]:
    """Source and target vertices posed by ``pose`` (the pose transfer of §5.2), ``(n, 3)`` each.

    The target is posed on its own skeleton (``target_rig``, else Eq. 3 from the source's) with every bone
    turned by the same world rotation as the source's (:func:`bodystudio.body.pose.transfer_pose`; copying
    the local rotations would tip the target over where a reshape turns a short bone's rest frame) and the
    same root translation; ``subset`` poses only those vertex rows.
    """
    if source.weights is None:
        raise InputError("the source body has no skin weights: load it with load_source_body(path, model)")
    Vt = np.asarray(target_vertices_rest, dtype=np.float64)
    if Vt.shape != source.vertices.shape:
        raise InputError(f"target vertices {Vt.shape} do not match the source body's {source.vertices.shape}")
    skel_t = target_skeleton(source, Vt) if target_rig is None else target_rig
    if subset is None:  # both bodies in one pass (the same values to ~1e-15 m)
        return skin_source_and_target(source.vertices, Vt, source.weights, source.skeleton, skel_t, pose)
    Vs = skin_vertices(source.vertices, source.weights, source.skeleton, pose, subset=subset)
    return Vs, skin_vertices(Vt, source.weights, skel_t, transfer_pose(pose, source.skeleton, skel_t), subset=subset)
