"""Issue 15's worst regions, side by side: where the Hausdorff maximum and the worst region p90 sit, per mode.

Usage: PYTHONPATH=. python benchmarks/reconstruct_worst_ab.py ROOT [--variants 'NAME=k:v,k:v;...']
       [--constraints sil|sil,depth|both] [--modes per-frame|tracking|both] [--sessions walk31,turn3,arm_flex12]
       [--where]

ROOT holds the benchmark's 30 fps hidden-subject sessions (``synth_session(ROOT / "walk31", n_cameras=10,
n_frames=6, motion="walk", subject_seed=31, template="full", fps=30)``, likewise turn 3 and arm_flex 12; made
when missing). Each variant is a set of :class:`RapidSkinParams` fields (``t_NAME``: :class:`TrackParams`) over
the defaults (``default`` = none; ``r_NAME``: a keyword of :func:`reconstruct_session`, e.g.
``r_joint_smoothing:2``);
every (session, constraints, mode) runs all variants back to back, so the rows compare on the same
frames.
Printed per row: median / p90 (visible) / Hausdorff mm and the region p90s (mean over frames), as the
benchmark's tracker table; with ``--where`` also each frame's Hausdorff maximum: its direction (reconstruction
-> truth or back), signed distance (> 0 outside the other surface), region / dominant bone, normal in the body
frame, height and whether a camera sees it, and the torso's worst 10 %.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

REGIONS = ("head", "torso", "crotch", "arms", "hands", "legs", "feet")
SESSIONS = {"walk31": ("walk", 31), "turn3": ("turn", 3), "arm_flex12": ("arm_flex", 12)}
# rec15h's held-out sessions (subjects and motion seeds no setting was tuned on): MOTION SUBJECT s SEED
HELD_OUT = ("walk58s1", "turn66s2", "arm_flex71s3", "arms_raise79s4")


def session_spec(name: str) -> tuple[str, int, int]:
    """``walk31`` -> ("walk", 31, 0); ``turn66s2`` -> ("turn", 66, 2) (motion, subject, motion seed)."""
    import re

    from bodystudio.capture.motion import MOTIONS

    motions = "|".join(sorted(MOTIONS, key=len, reverse=True))
    m = re.fullmatch(rf"({motions})(\d+)(?:s(\d+))?", name.split("_copy")[0])
    if m is None:
        raise SystemExit(f"--sessions {name!r}: name a session MOTION SUBJECT[sSEED], e.g. walk31 or turn66s2")
    return m.group(1), int(m.group(2)), int(m.group(3) or 0)


def parse_value(v: str):
    """``True`` / ``False``, an int, a float or the string itself."""
    if v in ("True", "False"):
        return v == "True"
    for kind in (int, float):
        try:
            return kind(v)
        except ValueError:
            pass
    return v


def parse_variants(text: str) -> list[tuple[str, dict]]:
    """``NAME=k:v,k:v;NAME2=...`` -> [(NAME, {k: v})]. Keys ``m_NAME`` are fields of the tracked frames'
    :class:`MatchSchedule` (issue 15's frame time, e.g. ``m_cheap_iterations:2,m_keep_outline:True``): they
    become one ``t_matching``, over the exact ``MatchSchedule()`` (not the tracker's default: name every field).
    ``NAME=@accurate`` is :data:`bodystudio.reconstruct.presets.ACCURATE_SETTINGS` and ``ACCURATE_PARAMS`` (the
    CLI's ``--accurate``; its tracking comes from ``--modes``: run it with ``--modes tracking``);
    ``NAME=@accurate,k:v,...`` the preset with more keys over it (e.g. ``t_outer_iterations:3``).
    """
    from bodystudio.reconstruct.presets import ACCURATE_PARAMS, ACCURATE_SETTINGS
    from bodystudio.reconstruct.silhouette import MatchSchedule

    out = []
    for part in text.split(";"):
        name, _, kv = part.partition("=")
        if kv.strip().split(",")[0] == "@accurate":  # ``@accurate,k:v,...``: the preset and more keys over it
            out.append((name.strip(), {**{f"r_{k}": v for k, v in ACCURATE_SETTINGS.items() if k != "tracking"},
                                       **ACCURATE_PARAMS,
                                       **{k: parse_value(v) for k, _, v in (item.partition(":") for item in
                                                                            filter(None, kv.split(",")[1:]))}}))
            continue
        kw = {k: parse_value(v) for k, _, v in (item.partition(":") for item in filter(None, kv.split(",")))}
        match_kw = {k[2:]: kw.pop(k) for k in [k for k in kw if k.startswith("m_")]}
        if match_kw:
            kw["t_matching"] = MatchSchedule(**match_kw)
        out.append((name.strip(), kw))
    return out


def where_lines(path: Path, body, regions, bones) -> list[str]:
    from benchmarks.reconstruct_worst_regions import body_axes, signed_distance_mm
    from bodystudio.capture.session import open_session
    from bodystudio.geometry.mesh import load_mesh, vertex_normals
    from bodystudio.reconstruct.evaluate import visible_vertices

    session = open_session(path)
    cams = list(session.cameras)
    F = body.faces
    lines = []
    for fid in session.frame_ids:
        gt = session.frame(fid).gt_mesh
        V = load_mesh(path / "reconstruct" / "meshes" / f"{fid:05d}.ply").vertices
        right, forward = body_axes(gt.vertices, body)
        N, N_gt = vertex_normals(V, F), vertex_normals(gt.vertices, gt.faces)
        seen = visible_vertices(gt.vertices, gt.faces, cams)
        to_gt = signed_distance_mm(V, N, gt.vertices, gt.faces)
        from_gt = -signed_distance_mm(gt.vertices, N_gt, V, F)
        i, j = int(np.argmax(np.abs(to_gt))), int(np.argmax(np.abs(from_gt)))
        if abs(to_gt[i]) >= abs(from_gt[j]):
            tag, k, d, P, NP = "rec->gt", i, to_gt[i], V, N
        else:
            tag, k, d, P, NP = "gt->rec", j, from_gt[j], gt.vertices, N_gt
        big = np.abs(to_gt) > 0.6 * abs(d)
        top = ", ".join(f"{b} {n}" for b, n in sorted(zip(*np.unique(bones[big], return_counts=True), strict=True),
                                                      key=lambda t: -t[1])[:4])
        torso = regions == "torso"
        a = np.abs(to_gt)
        p90 = np.percentile(a[torso], 90)
        worst = torso & (a >= p90)
        nf = N[worst] @ forward
        lines.append(f"   f{fid} {tag} {d:+.1f} mm {regions[k]}/{bones[k]} y={P[k, 1]:.2f} "
                     f"n fwd {NP[k] @ forward:+.2f} right {NP[k] @ right:+.2f} up {NP[k, 1]:+.2f} "
                     f"seen {bool(seen[k]) if tag == 'gt->rec' else '-'}"
                     f" | >60%: {top} | torso p90 {p90:.1f}: out {np.mean(to_gt[worst] > 0):.2f} "
                     f"fwd {np.mean(nf > 0.5):.2f} back {np.mean(nf < -0.5):.2f} "
                     f"down {np.mean(N[worst, 1] < -0.3):.2f}")
    return lines


def main() -> None:
    from dataclasses import replace

    import numba
    from threadpoolctl import threadpool_limits

    from bodystudio.body import build_body
    from bodystudio.capture.synth import synth_session
    from bodystudio.reconstruct.evaluate import vertex_regions
    from bodystudio.reconstruct.rapid_skin import RapidSkinParams
    from bodystudio.reconstruct.sequence import reconstruct_session
    from bodystudio.reconstruct.tracking import TrackParams

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path)
    ap.add_argument("--variants", default="default=")
    ap.add_argument("--constraints", default="both")
    ap.add_argument("--modes", default="both")
    ap.add_argument("--sessions", default=",".join(SESSIONS))
    ap.add_argument("--where", action="store_true")
    args = ap.parse_args()
    numba.set_num_threads(1)
    cons_list = {"sil": [("silhouette",)], "sil,depth": [("silhouette", "depth")],
                 "both": [("silhouette",), ("silhouette", "depth")]}[args.constraints]
    modes = {"per-frame": [False], "tracking": [True], "both": [False, True]}[args.modes]
    body = build_body(resolution="full")
    regions = vertex_regions(body)
    names = body.skeleton.bone_names
    bones = np.array([names[b] for b in np.argmax(body.weights, axis=1)], dtype=object)
    for sname in args.sessions.split(","):
        path = args.root / sname
        if not path.exists():
            motion, subject, seed = session_spec(sname)
            synth_session(path, n_cameras=10, n_frames=6, motion=motion, subject_seed=subject, template="full",
                          fps=30.0, seed=seed)
        for cons in cons_list:
            for tracking in modes:
                for vname, kw in parse_variants(args.variants):
                    track_kw = {k[2:]: v for k, v in kw.items() if k.startswith("t_")}
                    run_kw = {k[2:]: v for k, v in kw.items() if k.startswith("r_")}
                    params = RapidSkinParams(constraints=cons,
                                             **{k: v for k, v in kw.items() if not k.startswith(("t_", "r_"))})
                    # a preset may bring its own tracker settings (@accurate: rec15m); t_ fields go over them
                    track = replace(run_kw.pop("track_params", None) or TrackParams(), **track_kw)
                    with threadpool_limits(1):
                        s = reconstruct_session(path, template="13k", constraints=cons, tracking=tracking,
                                                params=params, track_params=track, **run_kw)
                    fr = json.loads((path / "reconstruct" / "frames.json").read_text())["frames"]
                    reg = [np.mean([f["metrics"]["regions"][r]["p90_mm"] for f in fr]) for r in REGIONS]
                    haus = [f["metrics"]["hausdorff_mm"] for f in fr]
                    print(f"{sname:10s} {'+'.join(c[:3] for c in cons):7s} {'track' if tracking else 'frame'} "
                          f"{vname:14s} {s['median_mm']:.3f} / {s['p90_mm']:.3f} / {s['hausdorff_mm']:.1f} | "
                          + " ".join(f"{r[:2]} {v:.1f}" for r, v in zip(REGIONS, reg, strict=True))
                          + " | H/frame " + " ".join(f"{h:.0f}" for h in haus), flush=True)
                    if args.where:
                        print("\n".join(where_lines(path, body, regions, bones)), flush=True)


if __name__ == "__main__":
    main()
