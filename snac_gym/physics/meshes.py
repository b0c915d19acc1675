"""The arm's COLLADA visual meshes as Wavefront OBJ, for PyBullet: the same triangles, drawn the same, loaded in a
sixth of the time.

PyBullet parses a URDF's ``.dae`` visuals anew for every body it loads (0.16-0.19 s for a UR or the Panda: 7-10 MB of
XML), and no physics client shares them with another, so every rendered env paid it. It reads an ``.obj`` file about
six times faster. :func:`visual_meshes_as_obj` writes each ``.dae`` once as an ``.obj`` of what PyBullet itself takes
from it, and points the URDF's visuals there:

* the triangles of every ``<triangles>``, ``<polylist>`` and ``<polygons>`` primitive (polygons fanned into
  triangles), its vertices moved by its node's transform; lines left out, as PyBullet draws none;
* each vertex normal as the file stores it, **not** turned by the node's transform: PyBullet's COLLADA reader turns the
  vertices only, and an ``.obj`` with turned normals shades the Panda's links differently (about 450 pixels of a
  480×480 frame);
* no material: the scene paints each link one colour (:class:`~snac_gym.physics.bullet.PyBulletScene`).

Frames drawn from the ``.obj`` files are the ``.dae`` files' pixel for pixel on every built-in arm
(tests/physics/test_meshes.py). A file this does not cover the same way keeps its ``.dae``: another unit than the
metre, another up axis than z, a texture, a primitive without normals, pycollada not installed, or a cache folder that
cannot be written (the env is only slower to build then).

The files live in ``meshes`` under :func:`~snac_gym.common.cache_dir.cache_root`, each named by the SHA-256 of its
``.dae`` file and of this conversion's version: a changed mesh gets a file of its own, and an edited one is never read.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from snac_gym.common.cache_dir import cache_root

#: Part of every file's name: raised whenever what :func:`write_obj` writes changes.
CONVERTER_VERSION = "1"
#: A ``<visual>`` element of a URDF.
_VISUAL = re.compile(r"<visual\b.*?</visual>", flags=re.S)
#: A ``.dae`` file name inside a visual's ``<mesh>``.
_DAE_FILENAME = re.compile(r'(filename\s*=\s*")([^"]+\.dae)(")', flags=re.I)
#: Each process's answer per ``.dae`` file (its path, size and modification time): the ``.obj`` to load, or None.
_SEEN: dict[tuple[str, int, int], str | None] = {}


def mesh_folder() -> Path:
    """Where the ``.obj`` files are kept: ``meshes`` under :func:`~snac_gym.common.cache_dir.cache_root`."""
    return cache_root() / "meshes"


def visual_meshes_as_obj(urdf: str) -> str:
    """``urdf`` with each ``<visual>``'s ``.dae`` mesh replaced by its ``.obj`` (:func:`obj_for`), where it has one.

    The collision meshes, and every other element, are left as they are."""

    def visual(match: re.Match[str]) -> str:
        def filename(name: re.Match[str]) -> str:
            obj = obj_for(name.group(2))
            return name.group(0) if obj is None else f"{name.group(1)}{obj}{name.group(3)}"

        return _DAE_FILENAME.sub(filename, match.group(0))

    return _VISUAL.sub(visual, urdf)


def obj_for(dae_path: str | os.PathLike[str]) -> str | None:
    """The ``.obj`` file PyBullet can load instead of ``dae_path``, written on first use; None where the ``.dae``
    should stay (see the module's docstring: not convertible the same way, or nowhere to write)."""
    path = Path(dae_path)
    try:
        status = path.stat()
    except OSError:
        return None  # PyBullet names a missing mesh itself
    seen = (str(path), status.st_size, status.st_mtime_ns)
    if seen not in _SEEN:
        _SEEN[seen] = _cached_obj(path)
    return _SEEN[seen]


def _cached_obj(path: Path) -> str | None:
    data = path.read_bytes()
    digest = hashlib.sha256(CONVERTER_VERSION.encode() + b"\0" + data).hexdigest()
    target = mesh_folder() / f"{digest}.obj"
    if target.is_file():
        return str(target)
    try:
        import collada  # noqa: PLC0415 - pycollada loads only where a .dae file is first converted
    except ImportError:
        return None
    try:
        with warnings.catch_warnings():  # pycollada's own use of NumPy (np.matrix, setting .shape), not the file's
            warnings.simplefilter("ignore", PendingDeprecationWarning)
            warnings.simplefilter("ignore", DeprecationWarning)
            triangles = read_dae(collada.Collada(str(path)))
    except Exception:  # noqa: BLE001 - any file pycollada reads otherwise than PyBullet keeps its .dae
        return None
    if triangles is None:
        return None
    partial = None
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=target.parent, suffix=".tmp", delete=False) as handle:
            partial = handle.name
            write_obj(handle, *triangles)
        os.replace(partial, target)  # whole or absent, whoever else writes it at the same time
    except OSError:
        if partial is not None:  # a full disk midway: no half-written file left behind
            Path(partial).unlink(missing_ok=True)
        return None
    return str(target)


def read_dae(document: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(vertices, normals, faces)`` of a pycollada document as PyBullet draws it (the module's docstring); faces
    index both arrays, ``(n, 3, 2)``: per corner a vertex and a normal row. None where PyBullet would read it
    otherwise."""
    import collada  # noqa: PLC0415 - the caller has imported it already (it made ``document``)

    unit = document.assetInfo.unitmeter
    if (unit is not None and float(unit) != 1.0) or document.assetInfo.upaxis not in (None, "Z_UP"):
        return None
    vertices: list[np.ndarray] = []
    normals: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    n_vertices = n_normals = 0
    for geometry in document.scene.objects("geometry"):
        for primitive in geometry.primitives():
            if isinstance(primitive, collada.lineset.BoundLineSet):
                continue
            if not isinstance(primitive, collada.triangleset.BoundTriangleSet):
                primitive = primitive.triangleset()
            if primitive.normal is None or primitive.normal_index is None or len(primitive.texcoordset):
                return None
            vertices.append(np.asarray(primitive.vertex, dtype=float))  # moved by the node's transform
            normals.append(np.asarray(primitive.original.normal, dtype=float))  # as stored: PyBullet's reading
            corners = np.stack([primitive.vertex_index + n_vertices, primitive.normal_index + n_normals], axis=-1)
            faces.append(corners.reshape(-1, 3, 2))
            n_vertices += len(vertices[-1])
            n_normals += len(normals[-1])
    if not faces:
        return None
    return np.concatenate(vertices), np.concatenate(normals), np.concatenate(faces)


def write_obj(handle: Any, vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray) -> None:
    """Write an OBJ of ``vertices``, ``normals`` and ``faces`` (:func:`read_dae`) to ``handle``, every float to its
    last bit (``repr``)."""
    handle.write("".join("v %r %r %r\n" % tuple(row) for row in vertices.tolist()))
    handle.write("".join("vn %r %r %r\n" % tuple(row) for row in normals.tolist()))
    one_based = (faces + 1).reshape(-1, 6).tolist()
    handle.write("".join("f %d//%d %d//%d %d//%d\n" % tuple(row) for row in one_based))


__all__ = ["CONVERTER_VERSION", "mesh_folder", "obj_for", "read_dae", "visual_meshes_as_obj", "write_obj"]
