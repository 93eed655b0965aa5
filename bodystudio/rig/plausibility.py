"""Self-check of a rig from its own data (no ground truth): does the fitted body explain the scan, and the scan
the fitted body?

The fit (eq. 5 of Avatar Reshaping, §4) pulls the model onto the scan, and its error is measured one way: scan
points to the fitted model (``fit_err_mm_*``). A scan with the person cut off (feet or head outside the
scanner's volume) is explained well that way, since every scan point has model skin nearby, while the model
invents the missing part: the skeleton transfer (eq. 4, 6) then places ankles or a head where the scan has
nothing, and the rig used to be written with exit 0. We measure the other direction too:

* per body region (head, each hand, each foot, arms, legs, torso; the model's skin weights), the share of the
  fitted model's vertices with scan surface within :data:`COVERED_MM` (a region the scan does not contain has
  a share near 0, one the scan holds ~1; synthetic scans' sole holes and random patches lower the feet a
  little, figures in docs/plausibility.md);
* the one-way fit error itself (median and 90th percentile) against what a human scan reaches.

:func:`rig_plausibility` returns the figures and a verdict (``warnings``, ``problems``, ``ok``); ``rig``
refuses a scan with a problem unless ``--accept-implausible`` and writes the verdict to the rig JSON.
"""

from __future__ import annotations

import numpy as np

#: A fitted-model vertex with scan surface within this distance (mm) counts as covered by the scan.
COVERED_MM = 10.0

#: Body regions by bone name (a vertex belongs to the region of its largest skin weight).
REGIONS = {
    "head": ("head", "neck_01"),
    "hand_l": ("hand_l",), "hand_r": ("hand_r",),
    "foot_l": ("foot_l", "ball_l"), "foot_r": ("foot_r", "ball_r"),
    "arm_l": ("upperarm_l", "lowerarm_l"), "arm_r": ("upperarm_r", "lowerarm_r"),
    "leg_l": ("thigh_l", "calf_l"), "leg_r": ("thigh_r", "calf_r"),
}


def region_of_vertices(weights: np.ndarray, bone_names) -> dict[str, np.ndarray]:
    """Per region of :data:`REGIONS` (fingers join their hand; everything else is ``torso``), the vertices
    (boolean mask) whose largest skin weight is on one of its bones."""
    names = list(bone_names)
    owner = np.argmax(np.asarray(weights), axis=1)
    bone_region = np.full(len(names), "torso", dtype=object)
    for region, bones in REGIONS.items():
        for b in bones:
            if b in names:
                bone_region[names.index(b)] = region
    for k, b in enumerate(names):  # fingers: index_01_l, thumb_03_r, ...
        if b.split("_")[0] in ("index", "middle", "pinky", "ring", "thumb"):
            bone_region[k] = f"hand_{b[-1]}"
    vertex_region = bone_region[owner]
    return {r: vertex_region == r for r in (*REGIONS, "torso")}


def region_coverage(model_vertices: np.ndarray, regions: dict[str, np.ndarray], scan_vertices: np.ndarray,
                    scan_faces: np.ndarray) -> dict[str, float]:
    """Per region, the share of the fitted model's vertices with scan surface within :data:`COVERED_MM` (the
    model-to-scan direction of eq. 5's data term, which the fit itself does not measure)."""
    import igl

    d2 = igl.point_mesh_squared_distance(np.ascontiguousarray(model_vertices, np.float64),
                                         np.ascontiguousarray(scan_vertices, np.float64),
                                         np.ascontiguousarray(scan_faces, np.int64))[0]
    covered = 1000.0 * np.sqrt(d2) <= COVERED_MM
    return {r: float(np.mean(covered[m])) if m.any() else float("nan") for r, m in regions.items()}


# Thresholds, from 6000-vertex synthetic scans (benchmarks/rig_plausibility.py; docs/plausibility.md, "rig"):
# clean = subjects 11, 12, 101-103 in the A-pose (and 11 in the T-pose), 1 mm noise, sole holes and patches.
#: Fit error's 90th percentile (mm, scan to model) above which the rig is refused: clean 2.1-2.4 mm, a pose 3x the
#: random scans' spread 5.5; feet cut off 14.5-23.9, head cut off 19.7, a pose the fit missed 38.3.
FIT_P90_REFUSE_MM = 10.0
#: ... and above which it warns (the pipeline's own "good fit" bound, :data:`bodystudio.rig.pipeline.GOOD_FIT_P90_MM`).
FIT_P90_WARN_MM = 6.0
#: A region whose share of fitted-model vertices with scan surface within COVERED_MM is below this is named
#: missing from the scan, and the rig refused: clean >= 0.72 (a foot's sole hole), feet cut off: 0.00-0.24,
#: head cut off: 0.37.
REGION_MISSING = 0.4
#: ... below this a region is named in a warning.
REGION_WARN = 0.6


def rig_plausibility(fit, scan_vertices: np.ndarray, scan_faces: np.ndarray, source: str = "the scan") -> dict:
    """The rig's self-check: ``coverage`` per region (:func:`region_coverage`), the fit error, ``warnings``,
    ``problems`` (one sentence each, naming the scan and the fix) and ``ok``."""
    regions = region_of_vertices(fit.weights, fit.skeleton.bone_names)
    coverage = region_coverage(fit.vertices, regions, scan_vertices, scan_faces)
    p90, median = float(fit.fit_err_mm_p90), float(fit.fit_err_mm_median)
    missing = sorted((r for r, c in coverage.items() if np.isfinite(c) and c < REGION_MISSING), key=coverage.get)
    weak = sorted((r for r, c in coverage.items() if np.isfinite(c) and REGION_MISSING <= c < REGION_WARN),
                  key=coverage.get)
    warnings, problems = [], []
    listing = ", ".join(f"{r} {coverage[r]:.2f}" for r in missing)
    if missing:
        parts = sorted({_part_name(r) for r in missing})
        problems.append(f"{source} has no {' and no '.join(parts)}: the fitted body's {listing} of its skin has no "
                        f"scan surface within {COVERED_MM:g} mm (a whole scan: >= 0.72), so the skeleton there is "
                        f"invented (fit error p90 {p90:.1f} mm); rescan the whole person (cut off by the scanner's "
                        "volume or floor?)")
    elif p90 > FIT_P90_REFUSE_MM:
        problems.append(f"the body model does not fit {source} (fit error {median:.1f} mm median, {p90:.1f} mm at the "
                        f"90th percentile; a whole person standing in an A or T pose: <= 2.5 mm): the person is in "
                        "another pose than the fit can find (arms above the head, sitting, crossed limbs) or part "
                        "of the scan is not the person; scan them standing in an A or T pose")
    else:
        if p90 > FIT_P90_WARN_MM:
            warnings.append(f"the fit error's 90th percentile is {p90:.1f} mm (a whole person in an A or T pose: "
                            "<= 2.5 mm): a limb may sit in the wrong place; check the avatar")
        if weak:
            warnings.append(f"the scan covers little of the fitted body's "
                            f"{', '.join(f'{r} ({coverage[r]:.2f})' for r in weak)}: holes or a part cut off there")
    return {"thresholds": {"covered_mm": COVERED_MM, "fit_p90_refuse_mm": FIT_P90_REFUSE_MM,
                           "fit_p90_warn_mm": FIT_P90_WARN_MM, "region_missing": REGION_MISSING,
                           "region_warn": REGION_WARN},
            "coverage": {r: (None if not np.isfinite(c) else c) for r, c in coverage.items()},
            "fit_err_mm_median": median, "fit_err_mm_p90": p90,
            "warnings": warnings, "problems": problems, "ok": not problems}


def _part_name(region: str) -> str:
    return {"foot_l": "feet", "foot_r": "feet", "hand_l": "hands", "hand_r": "hands", "head": "head",
            "leg_l": "legs", "leg_r": "legs", "arm_l": "arms", "arm_r": "arms"}.get(region, "trunk")


def check_rig(fit, scan_vertices: np.ndarray, scan_faces: np.ndarray, source: str,
              accept_implausible: bool = False) -> dict:
    """:func:`rig_plausibility`, raising ImplausibleResultError (one line) on a problem unless
    ``accept_implausible``."""
    from bodystudio.errors import ImplausibleResultError

    verdict = rig_plausibility(fit, scan_vertices, scan_faces, source)
    if verdict["problems"] and not accept_implausible:
        raise ImplausibleResultError(f"{source}: avatar not written, {verdict['problems'][0]}; or pass "
                                     "--accept-implausible")
    return verdict
