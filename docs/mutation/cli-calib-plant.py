"""Plant mutants of bodystudio/cli/calib.py's decorated commands by hand (mutmut does not mutate decorated
functions: ``calib board``, ``calib kinect``, ``calib export``, ``calib import``, ``synth calibration``, ``eval calib``)
in a scratch copy and run tests/reliability/test_calib_cli_mutants.py against each: the refusals, the defaults the
command line states, and ``calib kinect``'s own wiring."""
# usage (from the repository root): python docs/mutation/cli-calib-plant.py [TEST ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

work = "/work/wt-mutII-work/cli-calib-plant"
F = "bodystudio/cli/calib.py"
mutants = [
    # calib board
    ('squares_x: int = typer.Option(12,', 'squares_x: int = typer.Option(13,', "board: default squares_x 13"),
    ('squares_y: int = typer.Option(9,', 'squares_y: int = typer.Option(10,', "board: default squares_y 10"),
    ('square_mm: float = typer.Option(100.0,', 'square_mm: float = typer.Option(101.0,', "board: default square 101"),
    ('marker_mm: float = typer.Option(75.0,', 'marker_mm: float = typer.Option(76.0,', "board: default marker 76"),
    ('dictionary: str = typer.Option("DICT_4X4_100",', 'dictionary: str = typer.Option("DICT_4X4_250",',
     "board: default dictionary"),
    ('dpi: float = typer.Option(300.0,', 'dpi: float = typer.Option(301.0,', "board: default dpi 301"),
    ('check_output_file(out, "calib board", (".png", ".pdf"))', 'check_output_file(out, "calib board")',
     "board: no suffix check first"),
    ('    check_output_file(out.with_name("board.json"), "calib board")\n', "", "board: board.json not checked first"),
    ("square_mm / 1000, marker_mm / 1000, dictionary)", "square_mm / 100, marker_mm / 1000, dictionary)",
     "board: square mm / 100"),
    ("square_mm / 1000, marker_mm / 1000, dictionary)", "square_mm / 1000, marker_mm / 100, dictionary)",
     "board: marker mm / 100"),
    ("square_mm / 1000, marker_mm / 1000, dictionary)", "square_mm / 1000, marker_mm / 1000)",
     "board: dictionary dropped"),
    ("CharucoBoardSpec(squares_x, squares_y,", "CharucoBoardSpec(squares_y, squares_x,", "board: x and y swapped"),
    ("suffix = out.suffix.lower()", "suffix = out.suffix", "board: suffix case kept"),
    ('if suffix == ".pdf":', 'if suffix != ".pdf":', "board: pdf test negated"),
    ("write_board_png(out, spec, dpi=dpi)", "write_board_png(out, spec)", "board: --dpi not passed"),
    ("    save_board_json(out.with_name(\"board.json\"), spec)\n", "", "board: board.json not written"),
    ("({w * 1000:.0f} x {h * 1000:.0f} mm)", "({h * 1000:.0f} x {w * 1000:.0f} mm)", "board: size swapped in line"),
    # calib kinect
    ('    check_output_file(out, "--out", (".json",))\n    spec = load_board_json(folder / "board.json")',
     '    check_output_file(out, "--out")\n    spec = load_board_json(folder / "board.json")',
     "kinect: no .json check"),
    ('elif model in ("v1", "v2"):', 'elif model in ("v2",):', "kinect: v1 refused"),
    ('elif model in ("v1", "v2"):', 'elif model in ("v1", "v2", "v3"):', "kinect: v3 accepted"),
    ('rgbd = kinect_v2() if model == "v2" else kinect_v1()', 'rgbd = kinect_v1() if model == "v2" else kinect_v2()',
     "kinect: models swapped"),
    ("frames, views = detect_rgbd_capture(folder, spec)", "frames, views = detect_rgbd_capture(folder.parent, spec)",
     "kinect: wrong folder"),
    ('if str(f) in poses else np.full((4, 4), np.nan)', 'if str(f) not in poses else np.full((4, 4), np.nan)',
     "kinect: pose test negated"),
    ("shared = [k for k, T in enumerate(board_to_world) if np.isfinite(T[0, 0])]",
     "shared = list(range(len(board_to_world)))", "kinect: unseen poses kept"),
    ("        if not shared:\n", "        if not shared and False:\n", "kinect: no shared frame accepted"),
    ("views_w = [views[k] for k in shared]", "views_w = views", "kinect: every view to the PnP"),
    ("calibrated, rep = calibrate_rgbd_sensor(rgbd, spec, views, None)",
     "calibrated, rep = calibrate_rgbd_sensor(rgbd, spec, views, board_to_world)", "kinect: poses to the planes' fit"),
    ("Wd = rigid_inverse(calibrated.depth_to_color) @ W", "Wd = calibrated.depth_to_color @ W",
     "kinect: depth pose not inverted"),
    ("Camera(d.name, d.K, d.dist, Wd[:3, :3], Wd[:3, 3], d.width, d.height),",
     "Camera(d.name, d.K, d.dist, W[:3, :3], W[:3, 3], d.width, d.height),", "kinect: depth at the colour pose"),
    ("calibrated.depth_to_color, rgbd.baseline_m, rgbd.depth_range_m)",
     "calibrated.depth_to_color, 0.075, rgbd.depth_range_m)", "kinect: baseline reset"),
    ('"in_studio_frame": board_to_world is not None', '"in_studio_frame": board_to_world is None',
     "kinect: in_studio_frame negated"),
    ('**rep, "in_studio_frame"', '"in_studio_frame"', "kinect: report dropped from the line"),
    # calib export / import, eval calib, synth calibration
    ("if not easymocap and not colmap:", "if not easymocap or not colmap:", "export: and -> or"),
    ("        if folder:\n            check_output_folder(folder, what)\n", "        pass\n",
     "export: folders not checked"),
    ("    if colmap:\n        check_colmap_output(colmap)\n    rig = load_cameras_json(cameras)",
     "    rig = load_cameras_json(cameras)", "export: colmap folder not checked"),
    ("    if not source.is_dir():", "    if source.is_file():", "import: missing folder passed on"),
    ('    check_output_file(out, "--out", (".json",))\n    if not source.is_dir():',
     '    if not source.is_dir():', "import: --out not checked"),
    ("if len(kinect) != 2:", "if len(kinect) > 2:", "eval: one --kinect accepted"),
    ('    check_output_folder(out, "synth calibration")\n', "", "synth: output folder not checked"),
]
tests = sys.argv[1:] or ["tests/reliability/test_calib_cli_mutants.py"]
only = os.environ.get("PLANT_ONLY")  # a comma-separated subset of the names, to replay a few
replay(F, [m for m in mutants if not only or m[2] in only.split(",")], tests, work)
