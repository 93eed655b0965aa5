"""``bodystudio view PATH`` and ``bodystudio report RUN_OR_SESSION``: look at data, write HTML reports."""

from __future__ import annotations

from pathlib import Path

import typer

from bodystudio.errors import InputError


def view(
    path: Path = typer.Argument(..., help="session folder, arm capture folder, mirror session or "
                                "`mirror run` folder (before/after frames, source body), `garment fit` folder "
                                "or its render/ (fitted body, garment, light arrows, before/after frames), "
                                "mesh/scan (.ply .obj .stl .off .glb) or avatar (.glb)"),
    bone: str | None = typer.Option(None, "--bone", help="show the skin weights of this bone (avatars)"),
    frame: int | None = typer.Option(None, "--frame", help="session (or garment fit) frame to show first"),
    images: str = typer.Option("image", "--images", help="what camera frusta show: image | mask | none"),
    reference: Path | None = typer.Option(None, "--reference", help="ground-truth mesh: colour PATH by error (mm)"),
    screenshot: Path | None = typer.Option(None, "--screenshot", help="render offscreen to this PNG and exit"),
    html: Path | None = typer.Option(None, "--html", help="write a standalone HTML page of the scene and exit"),
    size: str = typer.Option("1024x768", "--size", help="window / screenshot size WxH"),
    cloud: bool = typer.Option(True, "--cloud/--no-cloud", help="show the Kinect point cloud (sessions, arm captures)"),
) -> None:
    """Open a session, mesh, scan or avatar in the 3D viewer (or save a screenshot / HTML page)."""
    from bodystudio.fileio import check_output_file
    from bodystudio.viewer.scene import save_screenshot
    from bodystudio.viewer.views import build_view, open_viewable, session_payload
    from bodystudio.viewer.webgl import save_scene_html

    window_size = _parse_size(size)
    for out, what, suffixes in ((screenshot, "--screenshot", (".png",)), (html, "--html", (".html", ".htm"))):
        if out is not None:
            check_output_file(out, what, suffixes)
    off_screen = screenshot is not None or html is not None
    item = open_viewable(path)
    if not off_screen and not has_display():
        raise InputError("no display to open a window ($DISPLAY is not set); add --screenshot OUT.png or "
                         "--html OUT.html, or run under a desktop / ssh -X")
    plotter = build_view(item, bone=bone, frame=frame, images=images, off_screen=off_screen,
                         window_size=window_size, reference=reference, cloud=cloud)
    try:
        if not off_screen:
            plotter.show(title=f"bodystudio view {path}")
            return
        if screenshot is not None:
            save_screenshot(plotter, screenshot)
            typer.echo(f"wrote {screenshot}")
        if html is not None:
            payload = None
            if item.kind == "session":  # every frame goes into the page, with a frame slider
                payload = session_payload(item.data, plotter, images=images, cloud=cloud, start=frame)
            elif item.kind == "arm":
                from bodystudio.viewer.arm import arm_payload

                payload = arm_payload(item.data, plotter, cloud=cloud, start=frame)
            elif item.kind == "garment":  # the fit's frames (up to 12) with a frame slider
                from bodystudio.viewer.garment import garment_payload

                payload = garment_payload(item.data, plotter, start=frame)
            save_scene_html(plotter, html, title=f"bodystudio view {path.name}", payload=payload)
            typer.echo(f"wrote {html}")
    finally:
        plotter.close()


def has_display() -> bool:
    """Whether an interactive window can open (X11 or Wayland on Linux; always elsewhere)."""
    import os
    import sys

    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _parse_size(size: str, option: str = "--size") -> tuple[int, int]:
    """``WxH`` -> (w, h), each 64..8192; a refusal names ``option`` (the command's own option name)."""
    try:
        w, h = (int(v) for v in size.lower().split("x"))
        if w < 64 or h < 64 or w > 8192 or h > 8192:
            raise ValueError
    except ValueError:
        raise InputError(f"{option} {size!r} is not WxH between 64 and 8192, e.g. 1024x768") from None
    return w, h


def report(
    path: Path = typer.Argument(..., help="a run folder (e.g. the demo's output) or a session folder"),
    out: Path = typer.Option(..., "--out", help="the report page to write (.html)"),
    no_3d: bool = typer.Option(False, "--no-3d", help="leave out the embedded 3D view"),
) -> None:
    """Write one self-contained HTML report: metrics tables, plots, screenshots and a 3D view."""
    from bodystudio.fileio import check_output_file
    from bodystudio.viewer.report import write_report

    check_output_file(out, "--out", (".html", ".htm"))
    result = write_report(path, out, with_3d=not no_3d)
    typer.echo(f"wrote {result.path} ({len(result.tables)} tables, {len(result.plots)} plots, "
               f"{len(result.screenshots)} screenshots, {'a' if result.has_3d else 'no'} 3D view)")
