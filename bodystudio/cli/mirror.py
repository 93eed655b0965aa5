"""``bodystudio mirror ...``: the virtual mirror of Real-time Reshaping of Humans (issue 12).

A thin layer over :mod:`bodystudio.mirror`: ``init`` fits the source body (§4) and writes it into the
session (``SESSION/mirror/source_body.npz`` plus a JSON summary for player 1, ``source_body_player{N}.npz`` /
``.json`` for player N; the body records its player), atomically.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from bodystudio.cli.mirror_run import mirror_run
from bodystudio.errors import InputError

app = typer.Typer(no_args_is_help=True)

SOURCE_SUMMARY_FILE = Path("mirror") / "source_body.json"


@app.command("init")
def init(
    session: Path = typer.Argument(..., help="mirror session folder (Kinect depth, joints and player mask)"),
    frames: int | None = typer.Option(None, "--frames",
                                      help="initialise from the N frames after the player first appears (1-900, "
                                      "at most the session's frames; default 90, or the whole session when "
                                      "shorter)"),
    player: int = typer.Option(1, "--player", help="Kinect SDK player index of the actor (1-6)"),
    resolution: str = typer.Option("6k", "--resolution", help="statistical model template: 6k | 2k"),
    silhouette_shape: bool = typer.Option(False, "--silhouette-shape/--no-silhouette-shape",
                                          help="refine the shape against 6 init frames' silhouettes too (stature "
                                               "and mass held; ~2.5 s CPU more; docs/mirror.md MIR12c)"),
    trunk_refit: bool = typer.Option(False, "--trunk-refit/--no-trunk-refit",
                                     help="move the skeleton's trunk joints (SpineMid, SpineShoulder, Neck) onto the "
                                          "SDK's, unposed by the refined pose (~1 s CPU more; docs/mirror.md MIR12r)"),
    unpose_posture: bool | None = typer.Option(None, "--unpose-posture/--no-unpose-posture",
                                               help="unpose each init frame with the spine, neck and head held at "
                                                    "the subject's own static posture (a stoop), not upright (the "
                                                    "default since mir12y; docs/mirror.md mir12v)"),
    force: bool = typer.Option(False, "--force", help="replace an existing source body (a mirror run made "
                               "from the old one then no longer matches: eval mirror refuses it until re-run)"),
) -> None:
    """Fit the actor's source body (§4) and write SESSION/mirror/source_body.npz (player N > 1:
    source_body_playerN.npz)."""
    from bodystudio.body.statistical import load_statistical_model
    from bodystudio.capture.session import open_session
    from bodystudio.fileio import check_output_file
    from bodystudio.mirror.init import (
        DEFAULT_INIT_FRAMES,
        SILHOUETTE_FRAMES,
        UNPOSE_POSTURE_BONES,
        initialise_source_body,
        save_source_body,
    )
    from bodystudio.mirror.run import source_body_path
    from bodystudio.runfolder import RunWriter

    if frames is not None and not 1 <= frames <= 900:
        raise InputError(f"--frames {frames}: must be in [1, 900] (about 3 s, 90 frames, is enough)")
    if not 1 <= player <= 6:
        raise InputError(f"--player {player}: the Kinect SDK numbers players 1 to 6")
    if resolution not in ("6k", "2k"):
        raise InputError(f"--resolution {resolution!r}: valid: 6k, 2k")
    s = open_session(session)
    if frames is not None and frames > len(s.frame_ids):  # fewer frames than asked for, with exit 0, before
        raise InputError(f"--frames {frames}: {s.path} has {len(s.frame_ids)} frames; give at most "
                         f"{len(s.frame_ids)}")
    out = source_body_path(s.path, player)
    check_output_file(out, "source body", suffixes=(".npz",))
    if out.exists() and not force:  # a mirror run made from the old body would no longer match it
        raise InputError(f"{out}: a source body{'' if player == 1 else f' of player {player}'} exists already; pass "
                         "--force to replace it (then re-run `bodystudio mirror run`: runs made from the old body no "
                         "longer match)")
    model = load_statistical_model(resolution, progress=False)
    source = initialise_source_body(s, model, player=player,
                                    n_frames=DEFAULT_INIT_FRAMES if frames is None else frames,
                                    silhouette_shape=silhouette_shape, trunk_refit=trunk_refit,
                                    unpose_posture=unpose_posture)
    measured = model.measure(source.coeffs)
    from bodystudio.mirror.plausibility import check_init

    coverage = check_init(s, source.frames_used, player)  # what the init saw of the actor (warnings only)
    summary = {"source_body": str(out.relative_to(s.path)), "player": player, "resolution": resolution,
               "silhouette_shape": silhouette_shape,
               # how many silhouettes the shape was refined against (SILHOUETTE_FRAMES spread over the frames used,
               # fewer when fewer frames were): `silhouette_shape: true` alone read as the full refinement
               "silhouette_frames": min(SILHOUETTE_FRAMES, len(source.frames_used)) if silhouette_shape else 0,
               "trunk_refit": trunk_refit, "frames_used": list(source.frames_used),
               "unpose_posture": bool(UNPOSE_POSTURE_BONES) if unpose_posture is None else unpose_posture,
               "residual_mm": round(source.residual_mm, 2),
               "stature_m": round(measured["stature_m"], 4), "mass_kg": round(measured["mass_kg"], 2),
               "coverage": {"seen": coverage["seen"], "cut": coverage["cut"]}, "warnings": coverage["warnings"]}
    # the body and its summary as one unit (a kill between the two files left a summary of another body);
    # `bodystudio recover SESSION/mirror/source_body.npz` finishes or discards a killed write
    with RunWriter(source_body_layout(s.path, player), "bodystudio mirror init",
                   {"stage": "mirror", "kind": "init"}) as w:
        save_source_body(w.path_for(out.name), source, player=player)
        w.commit(summary)
    typer.echo(json.dumps(summary))


def source_body_layout(session_path: Path, player: int = 1):
    """The run layout of ``mirror init``'s two files for ``player``: the manifest ``source_body.json`` (the summary,
    last), lock and staging ``.source_body.npz.lock`` / ``.staging`` beside them (player N > 1:
    ``source_body_playerN.json``, ``.source_body_playerN.npz.lock``, ...; its readers check the same one)."""
    from bodystudio.mirror.init import source_body_layout as layout_of
    from bodystudio.mirror.run import source_body_path

    return layout_of(source_body_path(session_path, player))


app.command("run")(mirror_run)
