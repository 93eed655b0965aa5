"""Arm-muscle capture (issue 11, eighth pass): what the depth can tell about the subject's rest shape, poses known.

The capture's error mixes the rest shape (Eq. 6-9's regression), the poses and the placement. Here the truth's joint
angles are held (``gt/arm_pose``), the rest arm is placed at the truth's shoulder, and the figure is the per-vertex
median (mm, arm vertices, every ``--stride``-th frame of a 200-frame session) against the truth's posed rest shape
(its own body parameters in ``model.body_shape_space``, posed by Eq. 12 with the capture's pose term and norm limit:
the seventh pass's floor, 0.10-0.16 mm from the truth) for:

* ``regression``: the model's rest mesh for the measured shape, projected into the body space (its joints
  MakeHuman's), placement as the truth's;
* ``placement``: the same with the shared placement fitted to the depth (``fit_body_rest_shape`` with a prior that
  holds the shape);
* ``body pw=W``: the body parameters fitted to the depth too (``refine.fit_body_rest_shape``, prior weight W per
  frame, centred on the projection), placement with them.

    python -m benchmarks.muscle_rest_ceiling --work W --session 504:0 --prior-weight 100 --prior-weight 1000

Sessions as ``benchmarks.muscle_sequences`` (``W/seq_SUBJECT_sNOISE_200``, made when missing), the benchmark's model
``W/model.npz``. docs/muscle.md "eighth pass".
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def ceiling(work: Path, subject_seed: int, noise_seed: int, stride: int, prior_weights: list[float]) -> dict:
    from scipy.spatial import cKDTree

    from benchmarks import bench_muscle as bm
    from benchmarks.muscle_energy import work_model
    from benchmarks.muscle_sequences import session_of
    from bodystudio.muscle.arm import ArmPose
    from bodystudio.muscle.capture import CaptureOptions
    from bodystudio.muscle.depth import clean_depth, depth_point_cloud
    from bodystudio.muscle.model import (
        body_parameters_of,
        body_shape_space,
        model_joints,
        model_rest_vertices,
        project_to_body_space,
    )
    from bodystudio.muscle.nicp import vertex_neighbourhoods
    from bodystudio.muscle.refine import DepthFrame, fit_body_rest_shape, skeleton_model_mesh

    template = bm._template()
    model = work_model(work, template)
    subject, session = session_of(work, subject_seed, noise_seed, 200)
    truth, shape = bm.truth_template(subject), bm.shape_of(subject)
    space = body_shape_space(template)
    o = CaptureOptions()
    F = np.asarray(template.faces, np.int64)
    adjacency = vertex_neighbourhoods(F, len(template.vertices), rings=2)
    camera = session.kinect.depth
    frames, poses = [], []
    for fid in session.frame_ids[::stride]:
        fr = session.frame(fid)
        P, N = depth_point_cloud(clean_depth(fr.kinect_depth_m, o.depth), camera)
        frames.append(DepthFrame(P, N, cKDTree(P), camera.center, template.arm_mask, adjacency, o.nicp.filters, F))
        poses.append(ArmPose.from_dict(fr.gt_arm_pose))
    shoulder = truth.joints[0]
    rest_t, J_t = space.rest_and_joints(body_parameters_of(subject.phenotype, subject.local, space), shoulder)
    truths = [skeleton_model_mesh(model, p, rest_t, J_t, o.norm_limit) for p in poses]

    def median_mm(x, shift):
        rest, J = space.rest_and_joints(x, shoulder)
        d = []
        for p, G in zip(poses, truths, strict=True):
            root = p.root.copy()
            root[:3, 3] += shift
            d.append(np.linalg.norm(skeleton_model_mesh(model, ArmPose(root, p.angles), rest, J, o.norm_limit) - G,
                                    axis=1)[model.arm_mask])
        return 1000.0 * float(np.median(d))

    mean, sigma = space.prior(shape)
    x_reg = project_to_body_space(space, model_rest_vertices(model, shape), model_joints(model, shape), mean, sigma)
    row = {"subject": subject_seed, "noise_seed": noise_seed, "frames": len(poses),
           "regression": median_mm(x_reg, np.zeros(3))}
    args = (o.norm_limit, o.sequence_huber_m, 3, True)
    row["placement"] = median_mm(*fit_body_rest_shape(space, model, poses, frames, x_reg, shoulder, x_reg, sigma,
                                                      1e7, *args))
    for w in prior_weights:
        row[f"body pw={w:g}"] = median_mm(*fit_body_rest_shape(space, model, poses, frames, x_reg, shoulder, x_reg,
                                                               sigma, w, *args))
    return row


def main(argv: list[str] | None = None) -> None:
    from benchmarks.muscle_sequences import parse_session

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--session", action="append", default=[], help="SUBJECT:NOISE_SEED (repeatable)")
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--prior-weight", type=float, action="append", default=[])
    args = parser.parse_args(argv)
    try:
        sessions = [parse_session(s) for s in (args.session or ["501:0"])]
    except ValueError as exc:
        parser.error(str(exc))
    for s, n in sessions:
        row = ceiling(args.work, s, n, args.stride, args.prior_weight or [100.0])
        print(" ".join(f"{k}={v:.2f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()), flush=True)


if __name__ == "__main__":
    main()
