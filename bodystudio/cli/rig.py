"""``bodystudio rig``, ``bodystudio synth scan`` and ``bodystudio eval rig`` (issue 6)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

from bodystudio.cli import eval as eval_cli
from bodystudio.cli import synth as synth_cli


def rig_to_files(scan: Path, out: Path, reshape: str | None = None, template: str = "6k", texture: bool = False,
                 weights: str = "harmonic", bvh: Path | None = None, show_progress: bool = False,
                 accept_implausible: bool = False) -> dict:
    """Load, rig, optionally reshape and export one scan; returns the rig description written beside it.

    The rig checks itself (:mod:`bodystudio.rig.plausibility`): a scan with the person cut off or in a pose the fit
    cannot find is refused (ImplausibleResultError, nothing written) unless ``accept_implausible``; the verdict
    goes to the rig JSON's ``plausibility``."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from bodystudio.errors import InputError
    from bodystudio.fileio import check_not_an_input, check_output_file
    from bodystudio.register.scan import load_scan
    from bodystudio.rig.evaluate import held_out_poses
    from bodystudio.rig.export import rig_json_path, rig_layout, write_rig
    from bodystudio.rig.pipeline import load_template_model, rig_scan
    from bodystudio.rig.reshape import parse_reshape, reshape_avatar
    from bodystudio.runfolder import RunWriter

    if out.suffix.lower() != ".glb":
        raise InputError(f"--out {out}: the avatar is written as glTF binary; give a .glb path")
    check_output_file(out, "--out")
    check_output_file(rig_json_path(out), "--out")
    check_not_an_input(out, {"the scan": scan})
    if bvh is not None:
        check_output_file(bvh, "--bvh", (".bvh",))
        check_not_an_input(bvh, {"the scan": scan, "--out": out}, "--bvh")
    deltas = parse_reshape(reshape) if reshape else None
    stages = ["load", "fit", "skeleton", "weights"] + (["reshape"] if deltas else []) + ["export"]
    t0 = time.perf_counter()
    # The lock is taken before the fit: a second `rig` onto the same avatar is refused at once, and the
    # glb, its rig.json and the BVH appear together or not at all.
    console = Console(stderr=True)
    with RunWriter(rig_layout(out), "bodystudio rig", {"scan": str(scan), "template": template,
                                                       "texture": texture}) as writer, \
            Progress(TextColumn("{task.description:<10}"), BarColumn(), TimeElapsedColumn(), console=console,
                     disable=not show_progress or not console.is_terminal, transient=True) as progress:
        tasks = {s: progress.add_task(s, total=1) for s in stages}

        def finish(name: str) -> None:
            progress.update(tasks[name], completed=1)

        mesh, report = load_scan(scan)
        model = load_template_model(template)
        finish("load")
        result = rig_scan(mesh, model, weights=weights, stage=finish)
        from bodystudio.rig.plausibility import check_rig

        # (a result without a fit, as the batch and kill tests' stand-in rig returns, has nothing to check)
        verdict = None if result.fit is None else check_rig(result.fit, mesh.vertices, mesh.faces, str(scan),
                                                            accept_implausible)
        avatar = result.avatar
        if deltas:
            avatar, _ = reshape_avatar(avatar, result.fit, model, deltas)
            finish("reshape")
        avatar.metadata["scan"] = report.as_dict()
        avatar.metadata["template"] = template
        if verdict is not None:
            avatar.metadata["plausibility"] = verdict
        avatar.metadata["seconds"] = time.perf_counter() - t0
        avatar.metadata["stage_seconds"] = result.seconds
        description = write_rig(writer, out, avatar, texture, bvh,
                                held_out_poses(avatar.bone_names) if bvh is not None else None)
        finish("export")
    description["seconds"] = time.perf_counter() - t0
    return description


def rig(scan: Path = typer.Argument(..., help="body scan: PLY, OBJ, GLB/GLTF or STL"),
        out: Path = typer.Option(..., "--out", "-o", help="avatar .glb (a .rig.json is written beside it)"),
        reshape: str = typer.Option(None, "--reshape", help="semantic edit, e.g. stature=+0.05,mass=-5 "
                                     "(within ±0.30 m stature and girths, ±40 kg mass; docs/rigging.md)"),
        template: str = typer.Option("6k", "--template", help="model template: 6k, 13k (or 2k)"),
        texture: bool = typer.Option(False, "--texture/--vertex-colors",
                                     help="bake colours into an xatlas UV texture (slow on big scans)"),
        weights: str = typer.Option("harmonic", "--weights", help="skin weight transfer: harmonic or barycentric"),
        bvh: Path = typer.Option(None, "--bvh",
                                 help="also write a BVH of sample poses on the avatar's skeleton"),
        accept_implausible: bool = typer.Option(False, "--accept-implausible", help="write the avatar even when "
                                                "its self-check finds the scan implausible (the person cut off, a "
                                                "pose the fit cannot find); the verdict goes to the rig JSON")) -> None:
    """Rig a body scan: fit the body model, transfer skeleton and skin weights, export glTF."""
    desc = rig_to_files(scan, out, reshape, template, texture, weights, bvh, show_progress=True,
                        accept_implausible=accept_implausible)
    for line in (desc.get("plausibility") or {}).get("warnings", []):
        typer.echo(f"warning: {line}", err=True)
    typer.echo(f"wrote {out} ({desc['n_vertices']} vertices, {len(desc['bones'])} bones, "
               f"fit {desc['fit_err_mm_median']:.1f} mm, {desc['seconds']:.1f} s)")


@synth_cli.app.command("scan")
def synth_scan(out: Path = typer.Argument(..., help="scan file to write (.ply, .obj, .glb, .stl)"),
               subject_seed: int = typer.Option(0, "--subject-seed", min=0, help="population subject"),
               pose: str = typer.Option("a", "--pose", help="a, t or random"),
               vertices: int = typer.Option(100_000, "--vertices", help="scan vertex count (about)"),
               noise_mm: float = typer.Option(1.0, "--noise-mm", help="normal-direction noise, mm"),
               holes: bool = typer.Option(True, "--holes/--no-holes", help="unscanned soles and patches")) -> None:
    """A synthetic body scan with ground truth in OUT.gt/."""
    from bodystudio.fileio import check_output_file, check_output_folder
    from bodystudio.register.synthetic import ground_truth_dir, save_synthetic_scan, synthetic_scan

    check_output_file(out, "synth scan", (".ply", ".obj", ".glb", ".stl"))
    check_output_folder(ground_truth_dir(out), "synth scan ground truth")
    scan, gt = synthetic_scan(subject_seed, pose, vertices, noise_mm, holes)
    gt_dir = save_synthetic_scan(out, scan, gt)
    typer.echo(f"wrote {out} ({scan.n_vertices} vertices) and {gt_dir}/")


@eval_cli.app.command("rig")
def eval_rig(avatar: Path = typer.Argument(..., help="avatar .glb written by bodystudio rig"),
             gt: Path = typer.Option(..., "--gt", help="ground-truth folder OUT.gt/ of the synthetic scan")) -> None:
    """Score a rigged avatar against its synthetic scan's ground truth; prints JSON."""
    from bodystudio.register.synthetic import load_ground_truth
    from bodystudio.rig.evaluate import evaluate_rig, load_avatar

    av = load_avatar(avatar)
    scan_meta = av.metadata.get("scan", {})
    result = evaluate_rig(av, load_ground_truth(gt), scan_meta.get("to_canonical"))
    result["seconds"] = av.metadata.get("seconds")
    typer.echo(json.dumps(result, indent=2))
