"""Where ``mirror init`` puts the trunk joints against the truth's, and whether they follow the fitted surface (MIR12r).

Usage: PYTHONPATH=. python benchmarks/mirror_trunk_joints.py [--source NAME.npz] SESSION [SESSION ...]

Per synthetic mirror session (``gt/mirror/actors.npz``; player 1) and trunk joint, in the rest pose, relative to the
pelvis head (the SDK's SpineBase, the IK root's anchor), mm along the body's forward axis (z) and up (y):

* ``fitted``: the source body's joint (``model.skeleton(coeffs)``, ``SourceBody.skeleton``) minus the truth's;
* ``regressor``: the statistical model's joint regressor on the *true* coefficients (``gt``'s projection of the
  actor) minus the truth's: what the skeleton would be with a perfect shape fit;
* ``surface``: the mean rest offset (fitted minus true vertex) of the vertices whose strongest skin weight is the
  joint's bone and that face forward (normal z > 0.5), minus the same for the pelvis: where the fitted *surface*
  sits there. ``fitted - surface`` is the skeleton's error against its own surface.

The SDK joints of the synthetic tracker are the true skeleton's (``capture.kinect.simulate_tracker_joints``), so a
joint refit to them can only move the fitted skeleton towards ``fitted = 0``; ``fitted ~ surface`` says the fitted
joints already sit where the fitted surface around them puts them (the error is the shape's, not the skeleton's).
Prints one table per axis and the mean |value| over the sessions.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: (label, bone, end): the joints the IK's trunk segments use (Kinect names where the SDK reports one).
TRUNK_JOINTS = (("SpineMid", "spine_02", "head"), ("spine_03 head", "spine_03", "head"),
                ("SpineShoulder", "spine_03", "tail"), ("Neck", "neck_01", "head"), ("head", "head", "head"),
                ("clavicle", "clavicle_l", "head"), ("Shoulder", "upperarm_l", "head"))


def trunk_rows(path: Path, model, source: str = "source_body.npz") -> dict[str, np.ndarray]:
    """(joints, 3, 3) per session: [fitted, regressor, surface] x (x, y, z) mm, relative to the pelvis."""
    from bodystudio.geometry.mesh import vertex_normals

    names = list(model.bone_names)
    actors = np.load(path / "gt" / "mirror" / "actors.npz")
    fitted = np.load(path / "mirror" / source)
    true_h, true_t = actors["source_heads"][0], actors["source_tails"][0]
    reg = model.skeleton(actors["source_coeffs"][0])
    W = model.weights.toarray() if hasattr(model.weights, "toarray") else np.asarray(model.weights)
    strongest = W.argmax(1)
    front = vertex_normals(model.mean, model.faces)[:, 2] > 0.5
    D = fitted["vertices"] - actors["source_rest_vertices"][0]
    pelvis = names.index("pelvis")

    def at(heads, tails, bone, end):
        i = names.index(bone)
        return (heads[i] if end == "head" else tails[i]) - heads[pelvis]

    def surface(bone):
        return D[(strongest == names.index(bone)) & front].mean(0)

    out = np.zeros((len(TRUNK_JOINTS), 3, 3))
    for r, (_, bone, end) in enumerate(TRUNK_JOINTS):
        truth = at(true_h, true_t, bone, end)
        out[r, 0] = at(fitted["heads"], fitted["tails"], bone, end) - truth
        out[r, 1] = at(reg.heads, reg.tails, bone, end) - truth
        out[r, 2] = surface(bone) - surface("pelvis")
    return 1e3 * out


def main() -> None:
    from bodystudio.body.statistical import load_statistical_model

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sessions", nargs="+", type=Path)
    parser.add_argument("--source", default="source_body.npz", help="source body .npz inside SESSION/mirror/")
    args = parser.parse_args()
    model = load_statistical_model("6k", progress=False)
    rows = {p.name: trunk_rows(p, model, args.source) for p in args.sessions}
    for axis, label in ((2, "z (forward)"), (1, "y (up)")):
        print(f"\n{label}, mm relative to the pelvis head: fitted / regressor on the true coefficients / front surface")
        print("| session | " + " | ".join(j for j, _, _ in TRUNK_JOINTS) + " |")
        print("|---|" + "---|" * len(TRUNK_JOINTS))
        for name, r in rows.items():
            print(f"| {name} | " + " | ".join(f"{r[j, 0, axis]:+.1f} / {r[j, 1, axis]:+.1f} / {r[j, 2, axis]:+.1f}"
                                              for j in range(len(TRUNK_JOINTS))) + " |")
        R = np.array(list(rows.values()))
        print("| mean abs | " + " | ".join(
            f"{np.abs(R[:, j, 0, axis]).mean():.1f} / {np.abs(R[:, j, 1, axis]).mean():.1f} / "
            f"{np.abs(R[:, j, 2, axis]).mean():.1f}" for j in range(len(TRUNK_JOINTS))) + " |")
        print("| mean abs (fitted - surface) | " + " | ".join(
            f"{np.abs(R[:, j, 0, axis] - R[:, j, 2, axis]).mean():.1f}" for j in range(len(TRUNK_JOINTS))) + " |")


if __name__ == "__main__":
    main()
