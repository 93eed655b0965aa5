"""Named settings of :func:`bodystudio.reconstruct.sequence.reconstruct_session` (issue 15).

``ACCURATE_SETTINGS`` is rec15g's ``cand`` + smoothing guard (docs/reconstruct.md, "Depth in the pose refinement,
a hold against the drift, and the default", 5.): the tracker, the joints smoothed over 2 frames either side with
its silhouette guard 0.05, the statistical body model's shape prior per frame (3 re-matchings from it, fitted after
2), the whole body's Kinect depth in the pose refinement (weight 3) with its silhouette guard 0.05, and
``ACCURATE_PARAMS``: the torso held to the frame's first iterate (``RapidSkinParams.surface_hold_k`` 1.0). It met
all 12 accuracy goals (silhouettes + depth) on the three 30 fps sessions it was tuned on, against the default's 9;
on held-out sessions: docs/reconstruct.md, "The accurate setting on held-out sessions (rec15h)". It needs the
sequential path (tracking and smoothing use the neighbouring frames) and was measured with depth constraints. Its
tracker keeps the head's Eq. 11 stretch (``TrackParams(unstretch_head=False)``; docs/reconstruct.md, rec15m).
"""

from __future__ import annotations

from dataclasses import replace

from bodystudio.reconstruct.rapid_skin import RapidSkinParams
from bodystudio.reconstruct.tracking import TrackParams

#: keywords of :func:`reconstruct_session` that ``bodystudio reconstruct --accurate`` sets
ACCURATE_SETTINGS: dict = {
    "tracking": True,
    "joint_smoothing": 2,
    "smoothing_guard": 0.05,
    "shape_prior": "frame",
    "shape_prior_outer": 3,
    "shape_prior_first_outer": 2,
    "refine_depth": 3.0,
    "refine_depth_bones": "all",
    "refine_depth_guard": 0.05,
    # rec15m: the tracked default's unstretched head costs this setting p90 on 5 of 7 sessions (it refines the head
    # as its own segment); it keeps the head as before
    "track_params": TrackParams(unstretch_head=False),
}

#: :class:`RapidSkinParams` fields the accurate setting sets over the caller's
ACCURATE_PARAMS: dict = {"surface_hold_k": 1.0, "surface_hold_region": "torso"}


def accurate_keywords(params: RapidSkinParams | None = None) -> dict:
    """The keywords of :func:`reconstruct_session` for the accurate setting: ``ACCURATE_SETTINGS`` and ``params``
    (default ``RapidSkinParams()``) with ``ACCURATE_PARAMS`` over it."""
    return {**ACCURATE_SETTINGS, "params": replace(params or RapidSkinParams(), **ACCURATE_PARAMS)}
