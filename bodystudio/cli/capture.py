"""``bodystudio capture ...`` (import, silhouettes, verify, recover), ``synth session`` and ``eval silhouettes``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from bodystudio.cli import eval as eval_cli
from bodystudio.cli import synth

app = typer.Typer(no_args_is_help=True)


@synth.app.command("session")
def synth_session(
    out: Path = typer.Argument(..., help="new session folder"),
    cameras: int = typer.Option(10, "--cameras", help="studio cameras on the ring"),
    frames: int = typer.Option(30, "--frames", help="frames to render"),
    motion: str = typer.Option("walk", "--motion", help="motion name (capture.motion.MOTIONS)"),
    subject_seed: int = typer.Option(7, "--subject-seed", min=0, help="subject drawn from the population"),
    kinect: str | None = typer.Option("v2", "--kinect", help="simulated Kinect: v1, v2 or none"),
    resolution: str = typer.Option("640x480", "--resolution", help="studio camera image size WxH"),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="camera sensor and Kinect noise"),
    seed: int = typer.Option(0, "--seed", min=0, help="motion variation, noise and background texture"),
    template: str = typer.Option("full", "--template", help="body template resolution: full, 6k, 2k"),
) -> None:
    """Render a synthetic studio session with ground truth (meshes, joints, poses, masks)."""
    from bodystudio.capture.synth import parse_resolution
    from bodystudio.capture.synth import synth_session as run
    from bodystudio.fileio import check_output_folder

    check_output_folder(out, "synth session", new=True)
    session = run(out, cameras, frames, motion, subject_seed, None if kinect in (None, "none") else kinect,
                  parse_resolution(resolution), noise, seed, template, progress=True)
    typer.echo(f"wrote {out}: {len(session.camera_names)} cameras x {len(session)} frames, "
               f"streams {', '.join(session.streams)}")


@app.command("import")
def import_cmd(
    out: Path = typer.Argument(..., help="new session folder"),
    cameras: Path | None = typer.Option(None, "--cameras",
                                        help="cameras.json, or a folder / file of EasyMocap intri.yml+extri.yml"),
    images: Path | None = typer.Option(None, "--images", help="folder with one image folder per camera"),
    videos: Path | None = typer.Option(None, "--videos", help="folder with one video per camera (<cam>.avi ...)"),
    timestamps: Path | None = typer.Option(None, "--timestamps", help="folder with <cam>.txt frame times (s)"),
    backgrounds: Path | None = typer.Option(None, "--backgrounds", help="empty-studio frames per camera"),
    tum: Path | None = typer.Option(None, "--tum", help="TUM RGB-D folder (depth.txt, rgb.txt, depth/, rgb/)"),
    kinect_calibration: Path | None = typer.Option(None, "--kinect-calibration", help="Kinect calibration JSON"),
    depth_scale: float | None = typer.Option(None, "--depth-scale", help="depth units per metre (TUM: 5000)"),
    joints: Path | None = typer.Option(None, "--joints", help="tracker joints: JSON folder, .json or .csv"),
    frames: int | None = typer.Option(None, "--frames", help="import at most this many frames"),
    masks: Path | None = typer.Option(None, "--masks", help="existing silhouettes: one image folder per camera"),
    joints_frame: str = typer.Option("studio", "--joints-frame", help="studio, or kinect-sdk (camera space)"),
) -> None:
    """Import a real recording (image folders or videos, TUM depth, joints) as a session."""
    from bodystudio.capture.importer import import_recording
    from bodystudio.fileio import check_output_folder

    check_output_folder(out, "capture import", new=True)
    session = import_recording(out, cameras, images, videos, timestamps, backgrounds, tum, kinect_calibration,
                               depth_scale, joints, frames, masks, joints_frame, progress=True)
    typer.echo(f"wrote {out}: {len(session.camera_names)} cameras x {len(session)} frames, "
               f"streams {', '.join(session.streams)}")


@app.command("silhouettes")
def silhouettes_cmd(
    session: Path = typer.Argument(..., help="session folder"),
    tau_cd: float = typer.Option(4.0, "--tau-cd", help="chromaticity-distortion threshold (normalised)"),
    close_px: int = typer.Option(0, "--close", help="morphological closing kernel (px, 0 = none)"),
    open_px: int = typer.Option(0, "--open", help="morphological opening kernel (px, 0 = none)"),
) -> None:
    """Segment the subject by background subtraction and write cam_NN/mask/ (prints JSON, IoU if GT)."""
    from bodystudio.capture.silhouettes import SegmentationParams, segment_session
    from bodystudio.errors import InputError
    from bodystudio.fileio import check_output_folder

    if not session.is_dir():
        raise InputError(f"{session}: no such session folder")
    check_output_folder(session, "session")
    params = SegmentationParams(tau_cd=tau_cd, close_px=close_px, open_px=open_px)
    typer.echo(json.dumps(segment_session(session, params, progress=True).to_dict(), indent=2))


@eval_cli.app.command("silhouettes")
def eval_silhouettes(session: Path = typer.Argument(..., help="synthetic session folder")) -> None:
    """IoU of the session's masks against its ground-truth masks (JSON)."""
    from bodystudio.capture.session import open_session
    from bodystudio.capture.silhouettes import silhouette_scores

    typer.echo(json.dumps(silhouette_scores(open_session(session)).to_dict(), indent=2))


@app.command("verify")
def verify_cmd(session: Path = typer.Argument(..., help="session folder")) -> None:
    """Check every file of a session against the manifest's sha256."""
    from bodystudio.capture.session import open_session

    s = open_session(session)
    typer.echo(f"{session}: {s.verify()} files ok ({len(s.camera_names)} cameras x {len(s)} frames)")


@app.command("recover")
def recover_cmd(session: Path = typer.Argument(..., help="session folder")) -> None:
    """Finish or discard a write that was interrupted (power loss, kill)."""
    from bodystudio.capture.session import recover_session
    from bodystudio.errors import InputError

    if not session.is_dir():
        raise InputError(f"{session}: no such session folder")
    typer.echo(f"{session}: {recover_session(session)}")
