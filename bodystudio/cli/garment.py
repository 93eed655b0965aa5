"""``bodystudio garment fit`` (§4-5), ``garment render`` (§6-7) and ``synth garment`` (issue 13)."""

from __future__ import annotations

from pathlib import Path

import typer

from bodystudio.cli import synth

#: ``bodystudio garment ...``: every garment command adds itself here.
app = typer.Typer(no_args_is_help=True)


@synth.app.command("garment")
def synth_garment(
    out: Path = typer.Argument(..., help="new session folder"),
    subject_seed: int = typer.Option(..., "--subject-seed", help="subject drawn from the population (seed)"),
    frames: int = typer.Option(60, "--frames", help="frames at 30 fps"),
    garment: str = typer.Option("tshirt", "--garment", help="target garment: tights | skirt | tshirt | longsleeve"),
    pattern: str = typer.Option("stripes", "--pattern", help="target cloth: stripes | checks | print | plain"),
    motion: str = typer.Option("walk", "--motion", help="walk | arm_flex | turn | arms_raise | a_pose"),
    resolution: str = typer.Option("480x640", "--resolution", help="camera image WIDTHxHEIGHT"),
    seed: int = typer.Option(0, "--seed", help="light, colours, motion variation and sensor noise"),
    no_noise: bool = typer.Option(False, "--no-noise", help="no sensor noise"),
) -> None:
    """Synthesise one camera's video of a subject in a known garment and light, with ground truth and the
    true render of the actor wearing the target garment."""
    from bodystudio.capture.synth import parse_resolution
    from bodystudio.fileio import check_output_folder
    from bodystudio.garment.synthetic import synth_garment_session

    size = parse_resolution(resolution)
    check_output_folder(out, "session folder", new=True)
    session = synth_garment_session(out, subject_seed=subject_seed, n_frames=frames, garment=garment,
                                    pattern=pattern, motion=motion, resolution=size, seed=seed, noise=not no_noise,
                                    progress=True)
    typer.echo(f"wrote {out}: {len(session)} frames of {motion} wearing a plain {garment} (target: {pattern} "
               f"{garment}), streams {', '.join(session.streams)}")


@app.command("fit")
def garment_fit(
    source: Path = typer.Argument(..., help="video file (MP4, MOV, ...) or session folder (cam_00/rgb + mask)"),
    stature: float = typer.Option(None, "--stature", help="the actor's stature in metres (0.5-2.5), required"),
    out: Path = typer.Option(..., "--out", help="new fit folder"),
    frames: str = typer.Option(None, "--frames", help="frame range START:END (default: all)"),
    template: str = typer.Option("2k", "--template", help="body template: 2k | 6k | full"),
    focal_px: float = typer.Option(None, "--focal-px", help="focal length in pixels (default: a 40 deg vertical "
                                                          "field of view)"),
    background: Path = typer.Option(None, "--background", help="clean plate: an image of the empty set, for a "
                                                              "video whose actor stays on the spot"),
    keyframes: Path = typer.Option(None, "--keyframes", help='JSON of soft 2D joint constraints '
                                                            '{"frames": {"12": {"hand_l": [u, v]}}}'),
    no_shape_refinement: bool = typer.Option(False, "--no-shape-refinement",
                                             help="skip the final shape refinement against every frame's silhouette"),
    no_pose_refinement: bool = typer.Option(False, "--no-pose-refinement",
                                            help="skip the poses' refinement on the refined shape (after the shape "
                                                 "refinement)"),
    clothing_mm: float = typer.Option(None, "--clothing-mm", help="thickness of the actor's worn clothes in mm "
                                                                  "(0-30; the shape refinement's allowance)"),
) -> None:
    """Fit the body to a monocular video (§4: shape, pose per frame; §5: albedo and lighting) into OUT."""
    import json

    from bodystudio.errors import InputError
    from bodystudio.fileio import check_output_folder
    from bodystudio.garment.fit import fit_garment_video

    if stature is None:
        raise InputError("--stature is required: give the actor's stature in metres (e.g. --stature 1.78)")
    if keyframes is not None and not keyframes.is_file():
        raise InputError(f"--keyframes {keyframes}: no such file")
    check_output_folder(out, "fit folder", new=True)
    fit = fit_garment_video(source, stature, out, frames=frames, template=template, focal_px=focal_px,
                            keyframes=keyframes, progress=True, background=background,
                            shape_refinement=not no_shape_refinement, pose_refinement=not no_pose_refinement,
                            clothing_allowance_m=None if clothing_mm is None else clothing_mm / 1e3)
    typer.echo(json.dumps({"out": str(out), "frames": len(fit.frame_ids), "stature_m": round(fit.stature_m, 4),
                           "silhouette_iou_mean": round(float(fit.silhouette_iou.mean()), 4),
                           "ms_per_frame": fit.timings_ms, "warnings": list(fit.warnings)}))


@app.command("render")
def garment_render(
    fit_dir: Path = typer.Argument(..., help="garment fit folder (from 'bodystudio garment fit')"),
    garment: str = typer.Option("tshirt", "--garment", help="tights | skirt | tshirt | longsleeve"),
    texture: str = typer.Option("stripes", "--texture", help="cloth pattern: stripes | checks | print | plain"),
    out: Path = typer.Option(..., "--out", help="output video (.mp4)"),
    no_flow: bool = typer.Option(False, "--no-flow", help="skip the optical-flow motion correction (§7.1)"),
    no_rbf: bool = typer.Option(False, "--no-rbf", help="skip the silhouette RBF warp (§7.2)"),
    no_depth: bool = typer.Option(False, "--no-depth", help="no depth compositing: the garment over everything"),
    no_hem: bool = typer.Option(False, "--no-hem", help="keep the new garment's hem lines where the fitted body puts "
                                "them (no hem matte onto the worn garment's edges)"),
    seed: int = typer.Option(0, "--seed", help="cloth colours"),
) -> None:
    """Dress the fitted actor, render with the fit's lights, refine in image space and composite: writes
    DIR/render/ (frames, garment masks, render.json) and the video, as one unit."""
    from bodystudio.garment.composite import check_render_options, render_garment_video

    check_render_options(garment, texture, out, seed)
    if not fit_dir.is_dir():
        from bodystudio.errors import InputError

        raise InputError(f"{fit_dir}: no such fit folder; run 'bodystudio garment fit VIDEO --out {fit_dir}' first")
    doc = render_garment_video(fit_dir, garment, texture, out, flow=not no_flow, rbf=not no_rbf, depth=not no_depth,
                               seed=seed, progress=True, hem=not no_hem)
    ms = ", ".join(f"{k} {v:.0f}" for k, v in doc["ms_per_frame"].items())
    typer.echo(f"wrote {fit_dir / 'render'} and {out}: {len(doc['frame_ids'])} frames of {texture} {garment} "
               f"(ms per frame: {ms}; flow correction used in {doc['n_flow_applied']} of them, hem matte in "
               f"{doc['n_hem_applied']}"
               f"{'' if doc['options']['flow'] else ', --no-flow'})")
