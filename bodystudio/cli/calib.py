"""``bodystudio calibrate``, ``bodystudio calib ...``, ``synth calibration`` and ``eval calib``."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from bodystudio.cli import eval as eval_cli
from bodystudio.cli import synth as synth_cli
from bodystudio.errors import InputError

app = typer.Typer(no_args_is_help=True, help="ChArUco boards, rig export/import.")
console = Console(stderr=True)


def _progress() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=console, transient=True, disable=not console.is_terminal)


@app.command("board")
def board(out: Path = typer.Argument(..., help="board image: .png or .pdf (true size); board.json is written beside"),
          squares_x: int = typer.Option(12, help="squares along x (12x9 of 100 mm: the studio protocol's board)"),
          squares_y: int = typer.Option(9, help="squares along y"),
          square_mm: float = typer.Option(100.0, help="square side, mm"),
          marker_mm: float = typer.Option(75.0, help="ArUco marker side, mm"),
          dictionary: str = typer.Option("DICT_4X4_100", help="ArUco dictionary"),
          dpi: float = typer.Option(300.0, help="PNG resolution")) -> None:
    """Write a printable ChArUco board (PNG at DPI, or PDF at true size) and its board.json."""
    from bodystudio.calib.board import CharucoBoardSpec, save_board_json, write_board_pdf, write_board_png
    from bodystudio.fileio import check_output_file

    check_output_file(out, "calib board", (".png", ".pdf"))
    check_output_file(out.with_name("board.json"), "calib board")
    spec = CharucoBoardSpec(squares_x, squares_y, square_mm / 1000, marker_mm / 1000, dictionary)
    suffix = out.suffix.lower()
    if suffix == ".pdf":
        write_board_pdf(out, spec)
    elif suffix == ".png":
        write_board_png(out, spec, dpi=dpi)
    else:
        raise InputError(f"{out}: board image must end in .png or .pdf")
    save_board_json(out.with_name("board.json"), spec)
    w, h = spec.size_m
    typer.echo(f"wrote {out} ({w * 1000:.0f} x {h * 1000:.0f} mm) and {out.with_name('board.json')}")


def _capture_folder(path: Path) -> tuple[Path, Path]:
    """(folder with cam_NN images, default output) for a session or a plain capture folder."""
    if (path / "calibration_images").is_dir():
        return path / "calibration_images", path / "calibration" / "cameras.json"
    return path, path / "cameras.json"


def calibrate(session_or_folder: Path = typer.Argument(..., help="session (with calibration_images/) or capture "
                                                                  "folder of cam_NN/FFFFF.png board images"),
              board: Path | None = typer.Option(None, help="board.json (default: FOLDER/board.json)"),
              out: Path | None = typer.Option(None, help="cameras.json to write (report beside it)"),
              floor_frame: int = typer.Option(0, help="frame number whose board lies on the floor (world frame)"),
              reference_camera: str | None = typer.Option(None, help="use this camera's frame as the world "
                                                                         "instead of the floor board"),
              distortion_terms: int = typer.Option(4, help="4: k1 k2 p1 p2, 5: also k3 (wide-angle lenses)"),
              easymocap: Path | None = typer.Option(None, help="also write intri.yml/extri.yml into this folder"),
              colmap: Path | None = typer.Option(None, help="also write a COLMAP text model into this folder"),
              accept_uncertain: bool = typer.Option(False, "--accept-uncertain",
                                                    help="write the rig even when a camera's centre sigma > 2 mm "
                                                         "or focal sigma > 0.5 % (otherwise: exit 2, only the "
                                                         "report OUT.rejected.json is written)")) -> None:
    """Calibrate all studio cameras from ChArUco images: intrinsics, bundle adjustment, floor world frame,
    and each camera's own uncertainty (sigmas, coverage, verdict)."""
    from bodystudio.calib.board import load_board_json
    from bodystudio.calib.calibrate import CalibrationOptions, calibrate_cameras
    from bodystudio.calib.io import calibration_layout, check_colmap_output, save_colmap_model, save_easymocap_yaml
    from bodystudio.calib.observations import detect_capture
    from bodystudio.calib.render import write_png
    from bodystudio.calib.uncertainty import UncertainCalibrationError, coverage_image
    from bodystudio.fileio import check_output_file, check_output_folder, write_json
    from bodystudio.geometry.camera import save_cameras_json
    from bodystudio.runfolder import RunWriter, check_output_destination

    if distortion_terms not in (4, 5):
        raise InputError(f"--distortion-terms must be 4 (k1 k2 p1 p2) or 5 (also k3), got {distortion_terms}")
    folder, default_out = _capture_folder(session_or_folder)
    if not folder.is_dir():
        raise InputError(f"{session_or_folder}: no such capture folder (cam_NN/FFFFF.png board images)")
    board = board or folder / "board.json"
    if not board.is_file():
        raise InputError(f"{board}: board description not found; pass --board or write one with "
                         "`bodystudio calib board`")
    spec = load_board_json(board)
    out = out or default_out
    check_output_file(out, "--out", (".json",))
    check_output_file(out.with_name(out.stem + ".report.json"), "--out")
    if easymocap:
        check_output_folder(easymocap, "--easymocap")
    if colmap:
        check_output_folder(colmap, "--colmap")
        check_colmap_output(colmap)
    from bodystudio.calib.observations import capture_images

    images = capture_images(folder)  # a listing only: the options are checked against it before detection
    if reference_camera is not None and reference_camera not in images:
        raise InputError(f"--reference-camera {reference_camera}: no such camera in {folder} "
                         f"({', '.join(images)})")
    if reference_camera is None and not any(floor_frame in frames for frames in images.values()):
        raise InputError(f"--floor-frame {floor_frame}: no camera has this frame in {folder}; give the frame whose "
                         "board lies on the floor, or --reference-camera")
    options = CalibrationOptions(distortion_terms=distortion_terms,
                                 floor_frame=None if reference_camera else floor_frame,
                                 reference_camera=reference_camera)
    check_output_destination(out, "--out cameras.json")
    for option, target in (("--easymocap", easymocap), ("--colmap", colmap)):
        if target is not None and target.exists() and not target.is_dir():
            raise InputError(f"{option} {target}: is a file; give a folder for the exported model")
        # the files the export writes there (a probe named otherwise refused a folder holding a folder of that name)
        for name in (() if target is None else ("intri.yml", "extri.yml") if option == "--easymocap"
                     else ("cameras.txt", "images.txt", "points3D.txt")):
            check_output_destination(target / name, f"{option} folder")
    rejected = out.with_name(out.stem + ".rejected.json")
    rejected_png = out.with_name(out.stem + ".rejected.coverage.png")
    # cameras.json, its coverage map, the exports and the report (written last, with their sha256) appear
    # together or not at all; an uncertain calibration writes only its rejected report, the previous rig stays.
    with RunWriter(calibration_layout(out), "bodystudio calibrate", {"capture": str(folder)}) as writer:
        with _progress() as progress:
            obs, quality = detect_capture(folder, spec, progress=progress)
            task = progress.add_task("bundle adjustment", total=None)
            result = calibrate_cameras(obs, spec, options)
            progress.update(task, total=1, completed=1)
        report = result.report()
        report["detections"] = quality
        uncertainty = result.uncertainty
        if not uncertainty.ok and not accept_uncertain:
            # Nothing a later command would read: the report under its own name, and the one-line verdict.
            write_json(rejected, report)
            write_png(rejected_png, coverage_image(uncertainty))
            raise UncertainCalibrationError(f"{uncertainty.summary()}; {out} not written (report: {rejected}); "
                                            "capture those views or pass --accept-uncertain")
        if not uncertainty.ok:
            report["uncertainty"]["verdict"] = "uncertain (accepted)"
            for line in uncertainty.advice():
                console.print(f"warning: {line}", markup=False, highlight=False, soft_wrap=True)
        save_cameras_json(writer.path_for(out.name), result.rig)
        write_png(writer.path_for(out.stem + ".coverage.png"), coverage_image(uncertainty))
        if easymocap:
            save_easymocap_yaml(writer.path_for(easymocap.absolute()), result.rig)
        if colmap:
            save_colmap_model(writer.path_for(colmap.absolute()), result.rig)
        report = writer.commit(report)
    for stale in (rejected, rejected_png):  # a rejected report of an earlier run no longer describes `out`
        stale.unlink(missing_ok=True)
    table = Table(title=f"calibration: {len(obs)} corners, {report['n_outliers']} outliers, "
                        f"{result.seconds:.1f} s, world = {result.world_frame}")
    for col in ("camera", "views", "corners", "outliers", "RMS px", "fx", "fy", "centre sd mm", "focal sd %",
                "coverage %", "verdict"):
        table.add_column(col, justify="right")
    for name, entry in report["cameras"].items():
        cam, unc = result.rig[name], uncertainty[name]
        table.add_row(name, str(entry["n_views"]), str(entry["n_corners"]), str(entry["n_outliers"]),
                      f"{entry['reproj_rms_px']:.3f}", f"{cam.fx:.1f}", f"{cam.fy:.1f}",
                      f"{unc.center_sigma_mm:.2f}", f"{unc.focal_sigma_pct:.3f}", f"{100 * unc.coverage.fraction:.0f}",
                      unc.verdict)
    table.add_row("all", "", str(len(obs)), str(report["n_outliers"]), f"{result.rms_px:.3f}", "", "", "", "", "",
                  report["uncertainty"]["verdict"])
    Console().print(table)
    typer.echo(f"wrote {out}")


@app.command("kinect")
def kinect(folder: Path = typer.Argument(..., help="capture folder with kinect/rgb and kinect/depth board frames"),
           report: Path | None = typer.Option(None, help="studio calibration report (board poses) to place the "
                                                            "Kinect in the studio frame"),
           sensor: Path | None = typer.Option(None, help="Kinect calibration.json with the intrinsics to keep "
                                                            "(default: nominal --model intrinsics)"),
           model: str = typer.Option("v2", help="v1 or v2: nominal intrinsics when no --sensor is given"),
           out: Path = typer.Option(..., help="Kinect calibration.json to write")) -> None:
    """Calibrate a Kinect: depth<->colour from board planes; Kinect<->studio from shared board poses."""
    import numpy as np

    from bodystudio.calib.board import load_board_json
    from bodystudio.calib.depth import calibrate_rgbd_sensor, detect_rgbd_capture
    from bodystudio.capture.session import kinect_calibration_to_dict, load_kinect_calibration
    from bodystudio.fileio import check_output_file, read_json, write_json
    from bodystudio.geometry.camera import kinect_v1, kinect_v2

    check_output_file(out, "--out", (".json",))
    spec = load_board_json(folder / "board.json")
    if sensor is not None:
        rgbd = load_kinect_calibration(sensor)
    elif model in ("v1", "v2"):
        rgbd = kinect_v2() if model == "v2" else kinect_v1()
    else:
        raise InputError(f"--model must be v1 or v2, got {model!r}")
    frames, views = detect_rgbd_capture(folder, spec)
    board_to_world = None
    if report is not None:
        poses = read_json(report, "calibration report").get("board_to_world", {})
        board_to_world = [np.asarray(poses[str(f)], float) if str(f) in poses else np.full((4, 4), np.nan)
                          for f in frames]
        shared = [k for k, T in enumerate(board_to_world) if np.isfinite(T[0, 0])]
        if not shared:
            raise InputError(f"{report}: none of the Kinect's board frames ({frames[:5]}...) was seen by the studio "
                             "cameras; capture boards seen by both")
        views_w = [views[k] for k in shared]
        board_to_world = [board_to_world[k] for k in shared]
    calibrated, rep = calibrate_rgbd_sensor(rgbd, spec, views, None)
    if board_to_world is not None:
        from bodystudio.calib.depth import sensor_to_studio
        from bodystudio.calib.world import rigid_inverse
        from bodystudio.geometry.camera import Camera, RGBDSensor

        W = sensor_to_studio(calibrated.color, spec, views_w, board_to_world)
        Wd = rigid_inverse(calibrated.depth_to_color) @ W
        c, d = calibrated.color, calibrated.depth
        calibrated = RGBDSensor(rgbd.name, rgbd.version,
                                Camera(d.name, d.K, d.dist, Wd[:3, :3], Wd[:3, 3], d.width, d.height),
                                Camera(c.name, c.K, c.dist, W[:3, :3], W[:3, 3], c.width, c.height),
                                calibrated.depth_to_color, rgbd.baseline_m, rgbd.depth_range_m)
    write_json(out, kinect_calibration_to_dict(calibrated))
    typer.echo(json.dumps({"frames": frames, **rep, "in_studio_frame": board_to_world is not None}))


@app.command("export")
def export(cameras: Path = typer.Argument(..., help="cameras.json"),
           easymocap: Path | None = typer.Option(None, help="folder for intri.yml / extri.yml"),
           colmap: Path | None = typer.Option(None, help="folder for a COLMAP text model")) -> None:
    """Convert cameras.json to EasyMocap YAML and/or a COLMAP text model."""
    from bodystudio.calib.io import check_colmap_output, save_colmap_model, save_easymocap_yaml
    from bodystudio.fileio import check_output_folder
    from bodystudio.geometry.camera import load_cameras_json

    if not easymocap and not colmap:
        raise InputError("nothing to export: give --easymocap DIR and/or --colmap DIR")
    for folder, what in ((easymocap, "--easymocap"), (colmap, "--colmap")):
        if folder:
            check_output_folder(folder, what)
    if colmap:
        check_colmap_output(colmap)
    rig = load_cameras_json(cameras)
    if easymocap:
        save_easymocap_yaml(easymocap, rig)
        typer.echo(f"wrote {easymocap}/intri.yml, extri.yml")
    if colmap:
        save_colmap_model(colmap, rig)
        typer.echo(f"wrote COLMAP model {colmap}")


@app.command("import")
def import_(source: Path = typer.Argument(..., help="COLMAP model folder or EasyMocap folder (intri.yml)"),
            out: Path = typer.Option(..., help="cameras.json to write")) -> None:
    """Convert a COLMAP model or EasyMocap intri/extri.yml to cameras.json."""
    from bodystudio.calib.io import load_colmap_model, load_easymocap_yaml
    from bodystudio.fileio import check_output_file
    from bodystudio.geometry.camera import save_cameras_json

    check_output_file(out, "--out", (".json",))
    if not source.is_dir():
        raise InputError(f"{source}: no such folder; give a COLMAP model folder or an EasyMocap folder (intri.yml)")
    rig = load_easymocap_yaml(source) if (source / "intri.yml").is_file() else load_colmap_model(source)
    save_cameras_json(out, rig)
    typer.echo(f"wrote {out} ({len(rig)} cameras)")


@synth_cli.app.command("calibration")
def synth_calibration(out: Path = typer.Argument(..., help="output capture folder"),
                      cameras: int = typer.Option(10, help="cameras on the studio ring"),
                      poses: int = typer.Option(30, help="board poses (frame 0 lies on the floor)"),
                      seed: int = typer.Option(0, min=0),
                      width: int = typer.Option(1280), height: int = typer.Option(960),
                      kinect: str | None = typer.Option(None, help="also render a Kinect (v1 or v2): colour "
                                                                      "and depth of every board pose")) -> None:
    """Render a ChArUco calibration capture of the studio ring with ground truth (OUT/gt/cameras.json)."""
    from bodystudio.calib.synthetic import write_synthetic_calibration
    from bodystudio.fileio import check_output_folder

    check_output_folder(out, "synth calibration")
    with _progress() as progress:
        summary = write_synthetic_calibration(out, cameras, poses, seed, width, height, progress=progress,
                                              kinect=kinect)
    typer.echo(json.dumps(summary))


@eval_cli.app.command("calib")
def eval_calib(est: Path = typer.Argument(..., help="estimated cameras.json"),
               gt: Path = typer.Argument(..., help="ground-truth cameras.json"),
               report: Path | None = typer.Option(None, help="calibration report (default: EST.report.json)"),
               align: str = typer.Option("floor", help="floor: compare world frames as they are; similarity: "
                                                       "Umeyama-align camera centres first"),
               kinect: list[Path] | None = typer.Option(
                   None, help="estimated and ground-truth Kinect calibration.json (give the option twice)")) -> None:
    """Score a calibration against ground truth; prints JSON (overall means, worst camera, per camera)."""
    from bodystudio.calib.evaluate import evaluate_calibration, evaluate_rgbd_sensor
    from bodystudio.calib.io import check_calibration_outputs
    from bodystudio.capture.session import load_kinect_calibration
    from bodystudio.geometry.camera import load_cameras_json

    rep = check_calibration_outputs(est, report)
    scores = evaluate_calibration(load_cameras_json(est), load_cameras_json(gt), rep, align)
    if kinect:
        if len(kinect) != 2:
            raise InputError("--kinect needs the estimated and the ground-truth calibration.json: give it twice")
        scores["kinect"] = evaluate_rgbd_sensor(load_kinect_calibration(kinect[0]), load_kinect_calibration(kinect[1]))
    typer.echo(json.dumps(scores, indent=2))
