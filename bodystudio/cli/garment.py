"""``bodystudio synth garment``: the single-camera garment-replacement session with ground truth (issue 13)."""

from __future__ import annotations

from pathlib import Path

import typer

from bodystudio.cli import synth


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
