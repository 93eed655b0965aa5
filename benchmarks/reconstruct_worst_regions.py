"""Where Rapid Skin's worst errors are (issue 15): the Hausdorff maximum, the torso's and crotch's p90.

Usage: PYTHONPATH=. python benchmarks/reconstruct_worst_regions.py [--frames 3] [--gate 0.001]
       [--bone-lengths sequence|frame] [--cache DIR]

The benchmark's 30 fps hidden-subject sessions (walk 31, turn 3, arm_flex 12; 10 cameras 640x480, 13K
template, tracker joints, silhouettes, per-frame initialisation) with ``--frames`` frames each. Per frame:
the reconstructed vertex farthest from the ground truth and the ground-truth vertex farthest from the
reconstruction (region / dominant bone, height, normal in the body frame: forward / right / up, visible,
outside or inside the other surface); the worst 10 % of the torso and crotch vertices (share facing
forwards / backwards / downwards, outside the truth, seen by a camera); and the crotch and the torso-leg
joints before and after the pose refinement. ``--gate`` is ``RapidSkinParams.hull_gate_m`` (0: the paper's
matching); ``--bone-lengths`` as ``bodystudio reconstruct`` (``frame``: before issue 15's crotch pass).
The sessions use the reconstruction body's topology for the ground truth (``template="full"``), so regions
and per-vertex offsets apply to both meshes.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import igl
import numpy as np

SESSIONS = (("walk", 31), ("turn", 3), ("arm_flex", 12))


def body_axes(V_gt: np.ndarray, body) -> tuple[np.ndarray, np.ndarray]:
    """(right, forward) unit vectors of the posed ground truth: thighs left - right, toes ahead of the calves."""
    names = body.skeleton.bone_names
    dom = np.argmax(body.weights, axis=1)

    def centroid(*bones):
        return V_gt[np.isin(dom, [names.index(b) for b in bones])].mean(axis=0)

    right = centroid("thigh_l") - centroid("thigh_r")
    right[1] = 0.0
    right /= np.linalg.norm(right)
    forward = np.cross(right, (0.0, 1.0, 0.0))
    if np.dot(centroid("ball_l", "ball_r") - centroid("calf_l", "calf_r"), forward) < 0:
        forward = -forward
    return right, forward


def signed_distance_mm(P: np.ndarray, N_P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Distance (mm) of points ``P`` to mesh ``(V, F)``, > 0 where ``P`` lies outside it (along ``N_P``)."""
    d2, _, C = igl.point_mesh_squared_distance(P, V, F.astype(np.int64))
    side = np.sign(np.einsum("ij,ij->i", P - C, N_P))
    return 1000.0 * np.sqrt(np.maximum(d2, 0.0)) * np.where(side == 0, 1.0, side)


def describe(i, V, N, right, forward, regions, bones) -> str:
    return (f"{regions[i]}/{bones[i]} y={V[i, 1]:.2f} m, normal fwd {N[i] @ forward:+.2f} right "
            f"{N[i] @ right:+.2f} up {N[i, 1]:+.2f}")


def frame_report(V, gt, cameras, body, regions) -> list[str]:
    from bodystudio.geometry.mesh import vertex_normals
    from bodystudio.reconstruct.evaluate import visible_vertices

    F = body.faces
    names = body.skeleton.bone_names
    bones = np.array([names[b] for b in np.argmax(body.weights, axis=1)], dtype=object)
    right, forward = body_axes(gt.vertices, body)
    N, N_gt = vertex_normals(V, F), vertex_normals(gt.vertices, gt.faces)
    seen = visible_vertices(gt.vertices, gt.faces, cameras)
    to_gt = signed_distance_mm(V, N, gt.vertices, gt.faces)  # > 0: reconstruction outside the truth
    from_gt = -signed_distance_mm(gt.vertices, N_gt, V, F)  # > 0: truth inside the reconstruction
    i, j = int(np.argmax(np.abs(to_gt))), int(np.argmax(np.abs(from_gt)))
    lines = [f"  Hausdorff {max(abs(to_gt[i]), abs(from_gt[j])):.1f} mm",
             f"    reconstruction -> truth {to_gt[i]:+.1f} mm at {describe(i, V, N, right, forward, regions, bones)}",
             f"    truth -> reconstruction {from_gt[j]:+.1f} mm at "
             f"{describe(j, gt.vertices, N_gt, right, forward, regions, bones)}, seen {bool(seen[j])}"]
    d = np.abs(to_gt)
    for region in ("torso", "crotch"):
        sel = regions == region
        p90 = np.percentile(d[sel], 90)
        worst = sel & (d >= p90)
        nf = N[worst] @ forward
        top = ", ".join(f"{b} {n}" for b, n in zip(*np.unique(bones[worst], return_counts=True),
                                                                strict=True))
        lines.append(f"    {region} p90 {p90:.1f} mm ({sel.sum()} vertices); worst 10 %: outside the truth "
                     f"{np.mean(to_gt[worst] > 0):.2f}, facing forwards {np.mean(nf > 0.5):.2f} / backwards "
                     f"{np.mean(nf < -0.5):.2f} / downwards {np.mean(N[worst, 1] < -0.3):.2f}, seen "
                     f"{np.mean(seen[worst]):.2f}; bones {top}")
    return lines


def pose_report(session, frame, body, fit_body, regions, lengths=None) -> str:
    """Crotch p90, its mean offset to the ground truth and the torso-leg joint errors, before -> after refinement."""
    from bodystudio.body.kinect import kinect_joint_names
    from bodystudio.reconstruct.articulated_fit import refine_bone_transforms
    from bodystudio.reconstruct.evaluate import point_to_surface_mm
    from bodystudio.reconstruct.pose_init import initialise_pose, pose_template, with_bone_lengths
    from bodystudio.reconstruct.sequence import frame_joints, gt_kinect_joints
    from bodystudio.reconstruct.tracking import SilhouetteFields, TrackParams, silhouette_data_term

    gt = frame.gt_mesh
    cams = list(session.cameras)
    fields = SilhouetteFields(cams, {n: frame.masks[n] for n in frame.masks})
    J, J_gt = frame_joints(session, frame, "tracker", None), gt_kinect_joints(frame, None)
    if lengths is not None:  # --bone-lengths sequence, as the reconstruction
        J = with_bone_lengths(J, lengths)
    init = initialise_pose(body, J)
    T = refine_bone_transforms(fit_body, initialise_pose(fit_body, J).bone_transforms, None,
                               data_term=silhouette_data_term(fields, TrackParams()))
    refined = pose_template(body, T, init.global_scale)
    names = kinect_joint_names("v2")
    crotch = regions == "crotch"
    parts = []
    for tag, pose in (("tracker pose", init), ("refined", refined)):
        p90 = np.percentile(point_to_surface_mm(pose.vertices[crotch], gt.vertices, gt.faces), 90)
        offset = 1000 * (pose.vertices[crotch] - gt.vertices[crotch]).mean(axis=0)
        err = 1000 * np.linalg.norm(pose.joints - J_gt, axis=1)
        joints = " ".join(f"{n} {e:.0f}" for n, e in zip(names, err, strict=True)
                          if n in ("SpineBase", "HipLeft", "HipRight"))
        parts.append(f"{tag}: crotch p90 {p90:.1f} mm, offset {np.round(offset, 1)} mm, joints mm {joints}")
    return "  " + " -> ".join(parts)


def main() -> None:
    from bodystudio.body import build_body
    from bodystudio.capture.session import open_session
    from bodystudio.capture.synth import synth_session
    from bodystudio.geometry.mesh import load_mesh
    from bodystudio.reconstruct.evaluate import vertex_regions
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session, run_bone_lengths

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--gate", type=float, default=RapidSkinParams().hull_gate_m)
    ap.add_argument("--bone-lengths", default="sequence", choices=("sequence", "frame"))
    ap.add_argument("--cache", type=Path, default=None, help="keep the sessions here for the next run")
    args = ap.parse_args()
    body, fit_body = build_body(resolution="full"), build_body(resolution="2k")
    regions = vertex_regions(body)
    with tempfile.TemporaryDirectory(prefix="worst-regions-") as tmp:
        root = args.cache or Path(tmp)
        for motion, subject in SESSIONS:
            path = root / f"{motion}{subject}_{args.frames}"
            if not path.exists():
                synth_session(path, n_cameras=10, n_frames=args.frames, motion=motion, subject_seed=subject,
                              template="full", fps=30.0)
            s = reconstruct_session(path, template="13k", params=RapidSkinParams(hull_gate_m=args.gate),
                                    bone_lengths=args.bone_lengths)
            print(f"{motion} {subject} (gate {1000 * args.gate:g} mm): median {s['median_mm']:.2f} p90 "
                  f"{s['p90_mm']:.2f} Hausdorff {s['hausdorff_mm']:.1f} mm")
            session = open_session(path)
            lengths = (run_bone_lengths(session, session.frame_ids, "tracker", None)
                       if args.bone_lengths == "sequence" else None)
            for fid in session.frame_ids:
                frame = session.frame(fid)
                V = load_mesh(path / "reconstruct" / "meshes" / f"{fid:05d}.ply").vertices
                print(f" frame {fid}")
                print("\n".join(frame_report(V, frame.gt_mesh, list(session.cameras), body, regions)))
                print(pose_report(session, frame, body, fit_body, regions, lengths))


if __name__ == "__main__":
    main()
