"""``bodystudio mirror run SESSION --taller .. --heavier .. --out out.mp4 [--live FOLDER]`` (issue 12 §4)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from bodystudio.errors import InputError


def mirror_run(
    session: Path = typer.Argument(..., help="mirror session folder (with SESSION/mirror/source_body.npz from "
                                   "`bodystudio mirror init`)"),
    out: Path = typer.Option(..., "--out", help="output video (.mp4); --side-by-side adds <out>_side_by_side.mp4"),
    taller: float = typer.Option(0.0, help="stature change (m)"),
    heavier: float = typer.Option(0.0, help="mass change (kg)"),
    muscular: float = typer.Option(0.0, help="muscularity change (model units)"),
    chest: float = typer.Option(0.0, help="chest girth change (m)"),
    waist: float = typer.Option(0.0, help="waist girth change (m)"),
    hips: float = typer.Option(0.0, help="hip girth change (m)"),
    source: list[Path] | None = typer.Option(None, help="source body .npz, one per --player in the same order "
                                             "(default SESSION/mirror/source_body.npz, for player N > 1 "
                                             "source_body_playerN.npz from `mirror init --player N`)"),
    run: Path | None = typer.Option(None, "--run", help="run folder for frames, masks and run.json "
                                    "(default SESSION/mirror/run)"),
    player: list[int] | None = typer.Option(None, help="Kinect player id to reshape, 1..6 (default 1); repeat to "
                                            "reshape several players: --player 1 --player 2"),
    warp: str = typer.Option("similarity", help="MLS variant: affine | similarity | rigid (the MLS of "
                             "--correspondence mls; the dense warp solves no MLS)"),
    correspondence: str = typer.Option("dense", help="warp correspondence: dense (the target body rasterised, "
                                       "each pixel mapped to the same surface point, outline onto outline, 1 px "
                                       "beyond it) | mls (Eq. 5 from vertex pairs only, the paper)"),
    refine_pose: bool = typer.Option(True, "--refine-pose/--no-refine-pose",
                                     help="refine each frame's IK pose (root, swing of spine and limbs) so the "
                                     "projected body fits the foreground, depth and joints (default): warp_iou "
                                     "+0.02 on MIR-SYNTH for ~4 ms per frame; --no-refine-pose: the IK pose alone"),
    ramp_frames: int = typer.Option(30, help="frames over which the edit is reached gradually (0: at once)"),
    side_by_side: bool = typer.Option(True, help="also write an input | output video"),
    video_preset: str = typer.Option("veryfast", help="x264 preset of the videos: ultrafast | superfast | veryfast "
                                     "(default) | faster | fast | medium | ...; ultrafast costs the encoder less "
                                     "than half the CPU at the same quality, in a ~3x larger file"),
    live: str | None = typer.Option(None, help="FOLDER a recorder is filling (kinect/ streams): process frames "
                                    "as they arrive; the latest output is RUN/live_latest.png"),
    live_timeout: float = typer.Option(5.0, help="--live: stop after this many seconds without a new frame"),
    accept_implausible: bool = typer.Option(False, "--accept-implausible", help="run even when the source body "
                                            "does not fit the session's tracked skeleton (another person's init; "
                                            "docs/mirror.md)"),
) -> None:
    """Show the actor (or, with --player repeated, several actors) reshaped (virtual mirror, §5): writes the video,
    RUN/frames, RUN/masks and RUN/run.json."""
    from bodystudio.mirror.run import run_mirror

    if not session.is_dir():
        raise InputError(f"{session}: no such session folder")
    if not 0.1 <= live_timeout <= 3600:
        raise InputError(f"--live-timeout {live_timeout}: use 0.1..3600 seconds")
    _check_run_folder(run if run is not None else session / "mirror" / "run")
    given = {"taller": taller, "heavier": heavier, "muscular": muscular, "chest": chest, "waist": waist, "hips": hips}
    edits = {k: v for k, v in given.items() if v != 0.0}
    players = list(player) if player else [1]
    sources = list(source) if source else None
    if sources is not None and len(sources) != len(players):
        raise InputError(f"--source given {len(sources)} times for {len(players)} players; give one --source per "
                         "--player (in the same order), or none to read each player's body from the session")
    one = len(players) == 1  # one player: the run of earlier versions (run.json without "players")
    doc = run_mirror(session, edits, out, source=sources if sources is None or not one else sources[0],
                     side_by_side=side_by_side, progress=True, run_dir=run, player=players[0] if one else players,
                     kind=warp, ramp_frames=ramp_frames, live=live, live_timeout_s=live_timeout,
                     correspondence=correspondence, refine_pose=refine_pose,
                     accept_implausible=accept_implausible, video_preset=video_preset)
    summary = doc["summary"]
    typer.echo(json.dumps({"run": str(run if run is not None else session / "mirror" / "run"),
                           "videos": doc["videos"], "edits": doc["edits"], **summary}, indent=1))


def _check_run_folder(run_dir: Path) -> None:
    """Refuse a ``--run`` folder that holds something other than a mirror run (a session, a reconstruction, any
    folder of files): the run's run.json, frames/ and masks/ would be written over it (a reconstruction's
    run.json, for one, replaced). An empty folder, or a previous mirror run, is fine."""
    from bodystudio.mirror.run import RUN_FORMAT

    if not run_dir.is_dir():
        return
    visible = [p for p in run_dir.iterdir() if not p.name.startswith(".")]
    if not visible:
        return
    try:
        fmt = json.loads((run_dir / "run.json").read_text(encoding="utf-8")).get("format")
    except (OSError, ValueError, AttributeError):
        fmt = None
    if fmt != RUN_FORMAT:
        raise InputError(f"--run {run_dir}: holds other files ({visible[0].name}, ...), not a mirror run; give a new "
                         "or empty folder, or a previous `mirror run` folder")
