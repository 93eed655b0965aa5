"""CPU cost of Algorithm 1's visual-hull gate, compiled vs the two implicit-hull passes it replaced (issue 15).

Usage: PYTHONPATH=. python benchmarks/reconstruct_gate_ab.py [--cache DIR] [--repeats 6]

The frame of the benchmark's per-step CPU table (walk s31 frame 1 at 30 fps, 10 cameras 640x480, 13K
template, pose from the distance-field fit); numba and BLAS on one thread, ``time.process_time``. The
deformation runs with the compiled gate (:meth:`SilhouetteFields.hull_gate`), the reference gate
(:func:`hull_gate_reference`) and no gate, interleaved in one process so machine load hits all three alike;
prints the median CPU ms of each and the largest vertex difference between the two gates (0 expected).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def step_table_frame(cache: Path | None):
    """The frame of the per-step CPU table, posed by the distance-field fit: ``(P, body, cams, masks, fields,
    rest)`` (posed 13K vertices, the body, cameras, masks, their :class:`SilhouetteFields`, rest cotangent
    weights); the walk s31 session is made in ``cache`` (or a temporary folder) when missing."""
    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.capture.synth import synth_session
    from bodystudio.geometry.laplacian import cotangent_weights
    from bodystudio.reconstruct.articulated_fit import refine_bone_transforms
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template
    from bodystudio.reconstruct.sequence import frame_joints
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, silhouette_data_term

    path = cache or Path(tempfile.mkdtemp()) / "walk31"
    if not (path / "session.json").exists():
        synth_session(path, n_cameras=10, n_frames=3, motion="walk", subject_seed=31, template="full", fps=30.0)
    session = open_session(path)
    cams = list(session.cameras)
    body, fit_body = build_body(resolution="full"), build_body(resolution="2k")
    frame = session.frame(session.frame_ids[1])
    masks = {n: np.asarray(frame.masks[n]) for n in frame.masks}
    J = frame_joints(session, frame, "tracker", None)
    fields = SilhouetteFields(cams, masks)
    T = refine_bone_transforms(fit_body, initialise_pose(fit_body, J).bone_transforms, None,
                               data_term=silhouette_data_term(fields, TrackParams()))
    P = pose_template(body, T, initialise_pose(body, J).global_scale).vertices
    return P, body, cams, masks, fields, cotangent_weights(body.vertices, body.faces)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=None, help="session folder to reuse (made when missing)")
    ap.add_argument("--repeats", type=int, default=6)
    args = ap.parse_args()
    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.reconstruct.rapid_skin import RapidSkinParams, deform_to_observations, hull_gate_reference
    from bodystudio.reconstruct.solver import SilhouetteConstraints
    from bodystudio.reconstruct.tracking import SilhouetteFields

    numba.set_num_threads(1)
    P, body, cams, masks, fields, rest = step_table_frame(args.cache)
    compiled = SilhouetteFields.hull_gate

    def reference(self, V, vertex, origin, direction, gate_m):
        return hull_gate_reference(V, SilhouetteConstraints(vertex, origin, direction, np.ones(len(vertex))), self,
                                   gate_m)

    ms: dict[str, list] = {"reference gate": [], "compiled gate": [], "no gate": []}
    out = {}
    try:
        with threadpool_limits(1):
            for rep in range(args.repeats + 1):  # the first run compiles
                for name in ms:
                    SilhouetteFields.hull_gate = reference if name == "reference gate" else compiled
                    gate = 0.0 if name == "no gate" else RapidSkinParams().hull_gate_m
                    t = time.process_time()
                    r = deform_to_observations(P, body.faces, cams, masks, RapidSkinParams(hull_gate_m=gate),
                                               delta=rest, fields=fields)
                    dt = 1000 * (time.process_time() - t)
                    if rep:
                        ms[name].append((dt, dt * r.matching_s / (r.matching_s + r.solver_s)))
                    out[name] = r.vertices
    finally:
        SilhouetteFields.hull_gate = compiled
    for name, v in ms.items():
        print(f"{name}: deformation {statistics.median(x[0] for x in v):.1f} ms CPU, "
              f"of which matching {statistics.median(x[1] for x in v):.1f} ms")
    print("max |dV| compiled vs reference gate:", float(np.abs(out["compiled gate"] - out["reference gate"]).max()))


if __name__ == "__main__":
    main()
