"""``bodystudio body ...``: export, inspect and measure MakeHuman bodies."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from bodystudio.errors import InputError

app = typer.Typer(no_args_is_help=True)


def parse_assignments(items: list[str] | None, what: str) -> dict[str, float]:
    """Parse ``NAME=VALUE`` pairs; malformed ones raise a one-line InputError."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            value = float(value)
        except ValueError:
            raise InputError(f"{what} {item!r} is not NAME=VALUE with a number, "
                             "e.g. upperarm-fat-decr-incr=0.5") from None
        if name.strip() in out:  # the last value silently won (rel6b)
            raise InputError(f"{what} {name.strip()}: given twice; give each once")
        out[name.strip()] = value
    return out


@app.command("export")
def export(
    out: Path = typer.Argument(..., help="output mesh: .ply, .obj or .glb"),
    gender: float = typer.Option(0.5, help="0 female .. 1 male"),
    age: float = typer.Option(0.5, help="0 = 1 year, 0.1875 = 10, 0.5 = 25, 1 = 90 years (piecewise linear)"),
    muscle: float = typer.Option(0.5, help="0 .. 1"),
    weight: float = typer.Option(0.5, help="0 .. 1"),
    height: float = typer.Option(0.5, help="0 .. 1"),
    proportions: float = typer.Option(0.5, help="0 uncommon .. 1 ideal"),
    african: float = typer.Option(1 / 3, help="ethnic weight in [0, 1] (the three are normalised to sum 1)"),
    asian: float = typer.Option(1 / 3, help="ethnic weight in [0, 1]"),
    caucasian: float = typer.Option(1 / 3, help="ethnic weight in [0, 1]"),
    local: list[str] | None = typer.Option(None, "--local", help="local modifier NAME=VALUE in [-1, 1] (repeat)"),
    pose: Path | None = typer.Option(None, "--pose",
                                     help="pose JSON (axis-angle 'rotations' or MPFB 'bone_rotations')"),
    resolution: str = typer.Option("full", help="full | 6k | 2k"),
    rig: str = typer.Option("game_engine", help="game_engine | default | default_no_toes | cmu_mb"),
    skinning: str = typer.Option("lbs", help="lbs | dqs"),
) -> None:
    """Build a body from phenotype and local modifiers, optionally pose it, and write the mesh."""
    from bodystudio.body import Phenotype, build_body, load_pose
    from bodystudio.fileio import check_output_file
    from bodystudio.geometry.mesh import Mesh, save_mesh

    check_output_file(out, "body export", (".ply", ".obj", ".glb"))
    phenotype = Phenotype.from_dict(dict(gender=gender, age=age, muscle=muscle, weight=weight, height=height,
                                         proportions=proportions, african=african, asian=asian,
                                         caucasian=caucasian))
    body = build_body(phenotype, parse_assignments(local, "--local"), resolution=resolution, rig=rig)
    vertices = body.vertices
    if pose is not None:
        vertices, _ = body.pose(load_pose(pose, body.skeleton.bone_names), method=skinning)
    save_mesh(out, Mesh(vertices, body.faces))
    typer.echo(f"wrote {out} ({body.n_vertices} vertices, {len(body.faces)} triangles, "
               f"stature {body.vertices[:, 1].max():.3f} m)")


@app.command("info")
def info(
    modifiers: bool = typer.Option(False, "--modifiers", help="list the local modifier names"),
    rig: str = typer.Option("game_engine", help="rig whose joints are counted"),
) -> None:
    """Vertex, face and joint counts of each template resolution, and the default body's stature."""
    from bodystudio.body import RESOLUTIONS, build_body
    from bodystudio.body.makehuman import load_base
    from bodystudio.body.phenotype import local_modifiers

    if modifiers:
        typer.echo("\n".join(sorted(local_modifiers(load_base().data_dir))))
        return
    report = {}
    for res in RESOLUTIONS:
        body = build_body(resolution=res, rig=rig)
        report[res] = {"vertices": body.n_vertices, "faces": len(body.faces), "joints": body.skeleton.n_bones}
    report["default_body"] = {"stature_m": round(float(body.vertices[:, 1].max()), 4), "rig": rig}
    from bodystudio.body.measure import measure_body

    report["default_body"]["attributes"] = {k: round(v, 4) for k, v in measure_body(build_body(rig=rig)).items()}
    typer.echo(json.dumps(report, indent=2))


@app.command("measure")
def measure(
    mesh: Path = typer.Argument(..., help="rest-pose body mesh in bodystudio's topology (full, 6k or 2k template)"),
    resolution: str | None = typer.Option(None, help="full | 6k | 2k (default: detected from the vertex count)"),
) -> None:
    """Print the mesh's stature, mass, chest/waist/hip girths, arm and leg length as JSON."""
    from bodystudio.body.measure import MESH_ATTRIBUTE_NAMES, measure_attributes
    from bodystudio.errors import FileFormatError
    from bodystudio.geometry.mesh import load_mesh

    body = load_mesh(mesh)
    try:
        attributes = measure_attributes(body.vertices, body.faces, resolution=resolution)
    except InputError as exc:
        raise FileFormatError(f"{mesh}: {exc}") from None
    typer.echo(json.dumps({k: round(attributes[k], 5) for k in MESH_ATTRIBUTE_NAMES}, indent=2))


@app.command("assets")
def assets_command(force: bool = typer.Option(False, "--force", help="download and extract again"),
                   quiet: bool = typer.Option(False, "--quiet")) -> None:
    """Fetch, verify and compile the MakeHuman assets (run by 'make setup')."""
    import os

    from bodystudio.body.assets import compiled_targets_path, fetch_assets, makehuman_data_dir

    if force and not os.environ.get("BODYSTUDIO_MAKEHUMAN_DIR"):
        fetch_assets(force=True)
    targets = compiled_targets_path()
    if not quiet:
        typer.echo(f"body assets ready: {makehuman_data_dir()} (compiled targets: {targets})")
