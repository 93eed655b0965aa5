"""Matrices from OpenCV FileStorage (YAML/XML) nodes, read without ``FileNode.mat()``.

OpenCV 5.0's ``FileNode.mat()`` corrupts the heap (``malloc(): invalid size``, then a segfault) on an
``!!opencv-matrix`` node without its ``cols`` entry, so a hand-edited or truncated calibration file
could kill the process instead of giving a one-line error, and its YAML parser loops forever on some
malformed files (a sequence item at column 0 after an indented one). The EasyMocap readers therefore
check a file's YAML syntax with PyYAML first (:func:`check_opencv_yaml`) and read matrices with
:func:`opencv_matrix`.
"""

from __future__ import annotations

import numpy as np

from bodystudio.errors import FileFormatError


def check_opencv_yaml(path) -> dict:
    """The entries of an OpenCV YAML file as PyYAML reads them (OpenCV's ``%YAML`` directive and
    ``!!opencv-matrix`` tags allowed); anything else is a one-line FileFormatError, raised before OpenCV's
    parser, which can hang on it, sees the file. A ``names`` entry must be a list of names."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    _Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", lambda loader, node: loader.construct_mapping(node))
    try:
        text = open(path, encoding="utf-8").read()
    except UnicodeDecodeError:
        raise FileFormatError(f"{path}: not a text (UTF-8) OpenCV YAML file") from None
    skipped = 0
    if text.startswith("%YAML"):  # OpenCV writes "%YAML:1.0", which PyYAML does not take as a directive
        text, skipped = (text.split("\n", 1)[1] if "\n" in text else ""), 1
    try:
        data = yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        at = f" at line {where.line + 1 + skipped}" if where is not None else ""
        raise FileFormatError(f"{path}: not valid YAML{at}; fix or re-export the calibration") from None
    if not isinstance(data, dict):
        raise FileFormatError(f"{path}: not an OpenCV YAML mapping of named entries; fix or re-export the calibration")
    names = data.get("names", [])
    if not isinstance(names, list) or not all(isinstance(n, (str, int)) for n in names):
        raise FileFormatError(f"{path}: 'names' must be a list of camera names; fix or re-export the calibration")
    return data

#: More elements than any camera matrix needs; a bigger ``data`` list is not a calibration.
_MAX_ELEMENTS = 4096


def opencv_matrix(node, where: str) -> np.ndarray | None:
    """The float64 ``(rows, cols)`` matrix stored at an ``!!opencv-matrix`` node, or None if the node is absent.

    A node that is not a single-channel matrix with ``rows * cols`` numbers in ``data`` raises a one-line
    FileFormatError naming ``where`` (the file and key).
    """
    if node.empty() or node.isNone():
        return None
    if not node.isMap():
        raise FileFormatError(f"{where}: not an OpenCV matrix (rows, cols, dt, data); fix or re-export the file")
    rows, cols, dt, data = (node.getNode(k) for k in ("rows", "cols", "dt", "data"))
    if not (rows.isInt() and cols.isInt() and data.isSeq()):
        raise FileFormatError(f"{where}: an OpenCV matrix needs integer rows and cols and a data list; "
                              "fix or re-export the file")
    n_rows, n_cols, n = int(rows.real()), int(cols.real()), data.size()
    if dt.isString() and dt.string().rstrip("ucsifd").strip() not in ("", "1"):
        raise FileFormatError(f"{where}: multi-channel matrix (dt: {dt.string()}); a calibration matrix has one "
                              "channel")
    if n_rows < 0 or n_cols < 0 or n_rows * n_cols != n or n > _MAX_ELEMENTS:
        raise FileFormatError(f"{where}: matrix says {n_rows}x{n_cols} but holds {n} numbers; fix or re-export "
                              "the file")
    values = [data.at(i) for i in range(n)]
    if not all(v.isInt() or v.isReal() for v in values):
        raise FileFormatError(f"{where}: matrix data must be numbers; fix or re-export the file")
    return np.array([v.real() for v in values], dtype=np.float64).reshape(n_rows, n_cols)
