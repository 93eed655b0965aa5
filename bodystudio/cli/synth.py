"""``bodystudio synth ...``: synthetic studio data with ground truth (sessions, calibration captures, scans).

Stages add their command to :data:`app` from their own CLI module (``@app.command("session")``);
``synth mirror`` (issue 12) lives here.
"""

from __future__ import annotations

import math
from pathlib import Path

import typer

from bodystudio.errors import InputError

app = typer.Typer(no_args_is_help=True)

MIRROR_MAX_FRAMES = 9000  # 5 minutes at 30 fps


@app.command("mirror")
def synth_mirror(
    out: Path = typer.Argument(..., help="new session folder"),
    subject_seed: int = typer.Option(..., "--subject-seed", help="actor 1 from the population (seed); actor 2: +1"),
    frames: int = typer.Option(120, "--frames", help="frames at 30 fps; the first 10 show the empty room"),
    actors: int = typer.Option(1, "--actors", help="1 or 2 actors"),
    kinect: str = typer.Option("v2", "--kinect", help="v1 (depth 320x240) | v2 (depth 512x424); colour 640x480"),
    motion: str = typer.Option("arms_raise", "--motion",
                               help="what the actors do once in place: arms_raise | walk | turn | arm_flex | "
                                    "a_pose | t_pose"),
    seed: int = typer.Option(0, "--seed", help="motion variation and sensor noise"),
    taller: float = typer.Option(0.0, "--taller", help="edit: stature change (m)"),
    heavier: float = typer.Option(0.0, "--heavier", help="edit: mass change (kg)"),
    muscular: float = typer.Option(0.0, "--muscular", help="edit: muscularity change (model units)"),
    chest: float = typer.Option(0.0, "--chest", help="edit: chest girth change (m)"),
    waist: float = typer.Option(0.0, "--waist", help="edit: waist girth change (m)"),
    hips: float = typer.Option(0.0, "--hips", help="edit: hip girth change (m)"),
    walk_in: bool = typer.Option(True, "--walk-in/--no-walk-in", help="actors walk in (else appear in place)"),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar on a terminal"),
) -> None:
    """Synthesise a Kinect mirror session (1-2 actors in a furnished room) with the ground truth of the edits."""
    from bodystudio.fileio import check_output_folder
    from bodystudio.mirror.reshape import check_edits
    from bodystudio.mirror.synthetic import MIRROR_MOTIONS, N_BACKGROUND_FRAMES, synth_mirror_session

    if actors not in (1, 2):
        raise InputError(f"--actors {actors}: a mirror session has 1 or 2 actors")
    if kinect not in ("v1", "v2"):
        raise InputError(f"--kinect {kinect!r}: valid: v1, v2")
    if motion not in MIRROR_MOTIONS:
        raise InputError(f"--motion {motion!r}: valid: {', '.join(MIRROR_MOTIONS)}")
    if not N_BACKGROUND_FRAMES + 1 <= frames <= MIRROR_MAX_FRAMES:
        raise InputError(f"--frames {frames}: must be in [{N_BACKGROUND_FRAMES + 1}, {MIRROR_MAX_FRAMES}] (the "
                         f"first {N_BACKGROUND_FRAMES} show the empty room)")
    if not 0 <= subject_seed <= 2**31 - 2:
        raise InputError(f"--subject-seed {subject_seed}: must be in [0, {2**31 - 2}]")
    if not 0 <= seed <= 2**31 - 1:
        raise InputError(f"--seed {seed}: must be in [0, {2**31 - 1}]")
    given = {"taller": taller, "heavier": heavier, "muscular": muscular, "chest": chest, "waist": waist, "hips": hips}
    for name, value in given.items():
        if not math.isfinite(value):
            raise InputError(f"--{name} {value}: must be a finite number")
    edits = check_edits({k: v for k, v in given.items() if v != 0.0})
    check_output_folder(out, "session folder", new=True)
    session = synth_mirror_session(out, subject_seed, n_frames=frames, actors=actors, edits=edits, version=kinect,
                                   motion=motion, seed=seed, progress=progress, walk_in=walk_in)
    shown = ", ".join(f"{k} {v:+g}" for k, v in edits.items()) or "none"
    typer.echo(f"wrote {out}: {len(session)} frames, {actors} actor(s), Kinect {kinect}, edits: {shown}")
