"""Viewer test helpers: small meshes, a skinned glTF writer and a headless Chromium runner."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bodystudio.geometry.mesh import Mesh

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars"]


@pytest.fixture(scope="session")
def body_mesh(body_2k) -> Mesh:
    return body_2k.mesh


def background_mask(img: np.ndarray, background=None, tol: int = 3) -> np.ndarray:
    """True where a rendered pixel differs from the viewer background."""
    from bodystudio.viewer.scene import BACKGROUND_RGB

    bg = np.asarray(BACKGROUND_RGB if background is None else background, dtype=int)
    return np.abs(img[..., :3].astype(int) - bg).max(-1) > tol


def chromium_binary() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def run_chromium(html_path: Path, size=(1200, 1000), timeout: float = 90.0, extra_flags=(), screenshot=True) -> dict:
    """Load a page headless: its DOM after scripts ran, console lines, and a screenshot (H, W, 3)."""
    from PIL import Image

    exe = chromium_binary()
    if exe is None:
        pytest.skip("headless Chromium not installed (Debian package 'chromium'; `make setup` installs it)")
    url = Path(html_path).resolve().as_uri()
    with tempfile.TemporaryDirectory() as profile:
        base = [exe, *CHROMIUM_FLAGS, *extra_flags, f"--user-data-dir={profile}",
                f"--window-size={size[0]},{size[1]}", "--virtual-time-budget=8000"]
        dom = subprocess.run([*base, "--enable-logging=stderr", "--v=0", "--dump-dom", url], capture_output=True,
                             text=True, timeout=timeout)
    image = None
    if not screenshot:
        return {"dom": dom.stdout, "console": _console(dom.stderr), "stderr": dom.stderr, "screenshot": image}
    with tempfile.TemporaryDirectory() as profile:
        shot = Path(profile) / "shot.png"
        subprocess.run([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}/p", f"--window-size={size[0]},{size[1]}",
                        "--virtual-time-budget=8000", f"--screenshot={shot}", url],
                       capture_output=True, timeout=timeout)
        image = np.asarray(Image.open(shot).convert("RGB")) if shot.is_file() else None
    return {"dom": dom.stdout, "console": _console(dom.stderr), "stderr": dom.stderr, "screenshot": image}


def _console(stderr: str) -> list[str]:
    # Chromium's software GL reports its own performance notes ("GL Driver Message (..., Performance,
    # ...): GPU stall due to ReadPixels") through the page console; they are not page errors.
    return [line for line in stderr.splitlines()
            if ":CONSOLE" in line and not ("GL Driver Message" in line and "Performance" in line)]


def write_skinned_glb(path: Path, V: np.ndarray, F: np.ndarray, weights: np.ndarray, heads: np.ndarray,
                      parents: np.ndarray, names) -> None:
    """A minimal skinned glTF 2.0 (.glb): joints as a node tree at the bone heads, 4 weights per vertex."""
    import pygltflib as g

    B = len(names)
    order = np.argsort(-weights, axis=1)[:, :4]
    W = np.take_along_axis(weights, order, axis=1)
    W = (W / np.maximum(W.sum(1, keepdims=True), 1e-12)).astype(np.float32)
    J = order.astype(np.uint16)
    ibm = np.tile(np.eye(4), (B, 1, 1))
    ibm[:, :3, 3] = -heads
    ibm = ibm.transpose(0, 2, 1).astype(np.float32)  # column-major
    blobs = [V.astype(np.float32), F.astype(np.uint32).ravel(), J, W, ibm]
    data, views, offset = b"", [], 0
    for arr, target in zip(blobs, [34962, 34963, 34962, 34962, None], strict=True):
        raw = np.ascontiguousarray(arr).tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=offset, byteLength=len(raw), target=target))
        data += raw + b"\0" * (-len(raw) % 4)
        offset = len(data)
    acc = [g.Accessor(bufferView=0, componentType=5126, count=len(V), type="VEC3",
                      min=V.min(0).tolist(), max=V.max(0).tolist()),
           g.Accessor(bufferView=1, componentType=5125, count=F.size, type="SCALAR"),
           g.Accessor(bufferView=2, componentType=5123, count=len(V), type="VEC4"),
           g.Accessor(bufferView=3, componentType=5126, count=len(V), type="VEC4"),
           g.Accessor(bufferView=4, componentType=5126, count=B, type="MAT4")]
    joint_nodes = []
    for b in range(B):
        p = parents[b]
        local = heads[b] - (heads[p] if p >= 0 else 0.0)
        children = [int(c) + 1 for c in np.flatnonzero(parents == b)]
        joint_nodes.append(g.Node(name=names[b], translation=local.tolist(), children=children or None))
    roots = [b + 1 for b in range(B) if parents[b] < 0]
    mesh_node = g.Node(name="body", mesh=0, skin=0)
    gltf = g.GLTF2(
        scene=0, scenes=[g.Scene(nodes=[0, *roots])], nodes=[mesh_node, *joint_nodes],
        meshes=[g.Mesh(primitives=[g.Primitive(attributes=g.Attributes(POSITION=0, JOINTS_0=2, WEIGHTS_0=3),
                                               indices=1)])],
        skins=[g.Skin(joints=list(range(1, B + 1)), inverseBindMatrices=4)],
        accessors=acc, bufferViews=views, buffers=[g.Buffer(byteLength=len(data))])
    gltf.set_binary_blob(data)
    gltf.save_binary(str(path))


@pytest.fixture
def drawn():
    """``drawn(img)``: True where a pixel differs from the viewer background."""
    return background_mask


@pytest.fixture
def chromium():
    """``chromium(html_path)``: load a page in headless Chromium (skips when it is not installed)."""
    if chromium_binary() is None:
        pytest.skip("headless Chromium not installed (Debian package 'chromium'; `make setup` installs it)")
    return run_chromium


@pytest.fixture
def skinned_glb():
    return write_skinned_glb
