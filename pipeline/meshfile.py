"""Reading a user's mesh file into clean triangle arrays."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import BloomError

FORMATS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file; polygons are triangulated. Returns ``(vertices (V,3), faces (F,3))``.

    Raises :class:`BloomError` naming the file for a missing, unreadable, empty or
    non-finite mesh, or a format that is not a mesh.
    """
    import trimesh

    path = Path(path)
    where = str(path)
    if not path.exists():
        raise BloomError("mesh file not found", where=where)
    if path.is_dir():
        raise BloomError("is a folder, not a mesh file", where=where)
    if path.suffix.lower() not in FORMATS:
        raise BloomError(f"unsupported mesh format {path.suffix or '(none)'}; use one of "
                         + ", ".join(FORMATS), where=where)
    try:
        with open(path, "rb") as f:
            f.read(1)
    except PermissionError:
        raise BloomError("mesh file not readable (permission denied)", where=where) from None
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise BloomError(f"not a readable {path.suffix[1:].upper()} mesh ({reason})",
                         where=where) from None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if vertices.ndim != 2 or len(vertices) == 0 or faces.ndim != 2 or len(faces) == 0:
        raise BloomError("mesh has no triangles", where=where)
    if not np.all(np.isfinite(vertices)):
        raise BloomError(f"{int(np.sum(~np.isfinite(vertices).all(axis=1)))} vertices have "
                         "non-finite (NaN or inf) coordinates", where=where)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise BloomError("faces refer to vertices that do not exist", where=where)
    return vertices, faces
