"""Reading a user's mesh file into clean triangle arrays.

:func:`read_mesh` joins everything in the file into one mesh; :func:`read_parts` keeps
the file's named parts apart (petals, stem, leaves, ...) so that each can be judged on
its own (:mod:`pipeline.flower.classify`).
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from trimesh.util import unique_name

from pipeline.errors import BloomError
from pipeline.mesh.topology import stack

FORMATS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")

#: OBJ header comments that state the unit (Maya: "This file uses centimeters as units
#: for non-parametric coordinates."), in metres per unit
OBJ_UNITS = {"millimeter": 0.001, "centimeter": 0.01, "meter": 1.0, "kilometer": 1000.0,
             "inch": 0.0254, "foot": 0.3048, "feet": 0.3048, "yard": 0.9144}


@dataclass
class Part:
    """One named part of a mesh file, placed by the file's transforms."""

    name: str  #: the file's own name for it (OBJ o/g, glTF node), else part_N
    vertices: np.ndarray  #: (V, 3) float64, in the file's units and axes
    faces: np.ndarray  #: (F, 3) int64, triangles, indices into this part's vertices


@dataclass
class MeshFile:
    """What :func:`read_parts` returns: the parts in the file's order and what the format
    says about axes and units."""

    parts: list[Part]  #: in the file's order (first appearance in an OBJ, node order in glTF)
    up: str | None  #: "+y" for glTF (the format's convention); None where the format is silent
    meters_per_unit: float | None  #: 1.0 for glTF; an OBJ's header comment (Maya); else None


def _check_path(path: Path) -> str:
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
    return where


#: the last file loaded: ``(key, scene)``; the remesh stage reads a glTF for its parts and
#: again for the user's asset (materials, UVs, normals): the file is parsed once
_LOADED: list = [None, None]


def _load(path: Path, where: str, **kwargs):
    """``trimesh.load`` of ``path`` (unprocessed), kept for the next call with the same
    file (same size and modification time) and arguments; callers only read it."""
    stat = Path(path).stat()
    key = (str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size, tuple(sorted(kwargs.items())))
    if _LOADED[0] == key:
        return _LOADED[1]
    try:
        _LOADED[:] = [key, trimesh.load(path, process=False, **kwargs)]
        return _LOADED[1]
    except Exception as exc:  # trimesh raises many types for broken files
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise BloomError(f"not a readable {path.suffix[1:].upper()} mesh ({reason})",
                         where=where) from None


def _checked(vertices, faces, where: str, what: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or len(vertices) == 0 or faces.ndim != 2 or len(faces) == 0:
        raise BloomError(f"{what} has no triangles", where=where)
    if not np.all(np.isfinite(vertices)):
        raise BloomError(f"{what}: {int(np.sum(~np.isfinite(vertices).all(axis=1)))} vertices "
                         "have non-finite (NaN or inf) coordinates", where=where)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise BloomError(f"{what}: faces refer to vertices that do not exist", where=where)
    return vertices, faces


def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh file; polygons are triangulated. Returns ``(vertices (V,3), faces (F,3))``.

    Raises :class:`BloomError` naming the file for a missing, unreadable, empty or
    non-finite mesh, or a format that is not a mesh.
    """
    path = Path(path)
    where = _check_path(path)
    loaded = _load(path, where, force="mesh")
    return _checked(getattr(loaded, "vertices", np.zeros((0, 3))),
                    getattr(loaded, "faces", np.zeros((0, 3))), where)


def read_parts(path: str | Path) -> MeshFile:
    """Read a mesh file as its named parts; polygons are triangulated, nothing is merged.

    Returns a :class:`MeshFile`: ``parts`` (each a :class:`Part` with ``name``,
    ``vertices (V, 3) float64`` placed by the file's transforms and ``faces (F, 3)
    int64`` local to the part), ``up`` and ``meters_per_unit``.

    Notes
    -----
    Names, in the file's order:

    - OBJ: one part per distinct ``o`` / ``g`` pair that has faces, in order of first
      appearance (faces of the same pair further down join it). With only ``o`` or only
      ``g`` (Blender writes ``o``, Maya and 3ds Max ``g``), that name; with both, ``o/g``
      (the group within its object; a ``g`` equal to its ``o`` is not repeated; a new
      ``o`` starts without a group). Maya's vertex-only ``g default`` makes no part.
      No ``o`` nor ``g``: ``part_0``.
    - glTF/GLB: one part per node with a mesh, in the file's node order (a node's
      primitives are one part; a mesh used by two nodes is two parts), named after the
      node, else its mesh, else ``part_N``; vertices are in the scene's frame (parent
      transforms applied), glTF axes kept (+Y up, metres).
    - STL, PLY, OFF: no names; ``part_N`` for each body trimesh finds (one for most).

    Names are the file's own, so two parts may share one. Vertices are not welded,
    degenerate faces are kept: cleaning is a later step's job.

    Raises :class:`BloomError` naming the file for a missing, unreadable or empty file,
    non-finite coordinates or out-of-range faces (naming the part).
    """
    path = Path(path)
    where = _check_path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        mesh_file = _read_obj(path, where)
    elif suffix in (".glb", ".gltf"):
        mesh_file = _read_gltf(path, where)
    else:
        loaded = _load(path, where, force="scene")
        meshes = [g for g in loaded.geometry.values() if len(getattr(g, "faces", ())) > 0]
        parts = [Part(f"part_{k}", *_checked(m.vertices, m.faces, where, f"part_{k}"))
                 for k, m in enumerate(meshes)]
        mesh_file = MeshFile(parts, None, None)
    if not mesh_file.parts:
        raise BloomError(_no_triangles(path), where=where)
    return mesh_file


#: vertex properties of a 3D Gaussian splatting PLY (Kerbl et al. 2023)
SPLAT_PROPERTIES = ("opacity", "scale_0", "rot_0", "f_dc_0")


def _no_triangles(path: Path) -> str:
    """Why a file with no faces is not a flower model: a Gaussian splat, a point cloud, or
    nothing at all."""
    points, splat = 0, False
    if path.suffix.lower() == ".ply":
        try:
            with open(path, "rb") as fh:
                header = fh.read(65536).split(b"end_header")[0].decode("ascii", "replace")
        except OSError:
            header = ""
        for line in header.splitlines():
            words = line.split()
            if words[:2] == ["element", "vertex"] and len(words) > 2 and words[2].isdigit():
                points = int(words[2])
            if words[:1] == ["property"] and words[-1] in SPLAT_PROPERTIES:
                splat = True
    if splat:
        return (f"a Gaussian splat ({points} splats with opacity, scale and rotation, no faces), "
                "not a mesh: there are no petal surfaces to simulate; export the petals as a mesh")
    if points:
        return (f"a point cloud ({points} points, no faces), not a mesh: there are no petal surfaces "
                "to simulate; reconstruct a surface first (e.g. Poisson) or export the mesh")
    return "mesh has no triangles"


def _obj_keys(text: str) -> tuple[list[tuple], list[str]]:
    """Each distinct (o, g) pair with faces, in order of first appearance, as trimesh keys
    them (o and g persist until changed) and as named here (a new o drops the group)."""
    obj = group = None
    named_group = None
    keys: dict[tuple, str] = {}
    for line in text.splitlines():
        if line.startswith("o "):
            obj = line[2:].strip()
            named_group = None
        elif line.startswith("g "):
            group = named_group = line[2:].strip()
        elif line.startswith("f ") and (obj, group) not in keys:
            if obj is not None and named_group is not None and named_group != obj:
                name = f"{obj}/{named_group}"
            else:
                name = obj if obj is not None else named_group
            keys[(obj, group)] = name
    return list(keys), list(keys.values())


def _obj_units(text: str) -> float | None:
    for line in text.splitlines()[:20]:
        if not line.startswith("#"):
            continue
        m = re.search(r"uses (\w+?)s? as units", line, flags=re.IGNORECASE)
        if m and m.group(1).lower() in OBJ_UNITS:
            return OBJ_UNITS[m.group(1).lower()]
    return None


def obj_text(path: Path, where: str) -> str:
    """An OBJ file's text, line ends made ``\\n`` (undecodable bytes replaced)."""
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise BloomError(f"not a readable OBJ mesh ({exc})", where=where) from None
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _read_obj(path: Path, where: str) -> MeshFile:
    text = obj_text(path, where)
    keys, names = _obj_keys(text)
    loaded = _load(path, where, force="scene", split_objects=True, split_groups=True,
                   group_material=False)
    # trimesh builds its geometries from the last (o, g) pair to the first
    meshes = [g for g in reversed(list(loaded.geometry.values())) if len(getattr(g, "faces", ())) > 0]
    if len(meshes) != len(keys):  # a layout this reading did not foresee: keep trimesh's names
        names = [str(n) for n, g in reversed(list(loaded.geometry.items())) if len(g.faces) > 0]
    parts = []
    for k, (mesh, name) in enumerate(zip(meshes, names, strict=True)):
        name = name or f"part_{k}"
        parts.append(Part(name, *_checked(mesh.vertices, mesh.faces, where, f"part {name!r}")))
    return MeshFile(parts, None, _obj_units(text))


def _gltf_header(path: Path) -> dict:
    """The glTF JSON (of a .gltf, or the first chunk of a .glb); {} if unreadable."""
    try:
        data = path.read_bytes()
        if data[:4] == b"glTF":
            length = struct.unpack("<I", data[12:16])[0]
            return json.loads(data[20:20 + length])
        return json.loads(data)
    except (OSError, ValueError, struct.error):
        return {}


def gltf_node_frames(scene, header: dict):
    """Each glTF node with a mesh, in the file's node order, as trimesh loaded it:
    ``(node, name, [(transform (4, 4), trimesh.Trimesh), ...])``, one pair per primitive
    with triangles (the node's own frame for one primitive, a child frame each for
    several). ``name`` is the node's name, else its mesh's, else ``part_N``."""

    nodes = header.get("nodes", [])
    meshes = header.get("meshes", [])
    # trimesh names node i after its "name" (made unique) or else str(i): the same here
    frame_of: dict[int, str] = {}
    taken: dict = {}
    counts: dict = {}
    for i, node in enumerate(nodes):
        frame = unique_name(node.get("name", str(i)), taken, counts=counts)
        taken[frame] = i
        frame_of[i] = frame
    graph = scene.graph
    children = graph.transforms.children
    found = 0
    for i, node in enumerate(nodes):
        if "mesh" not in node or frame_of[i] not in graph.nodes:
            continue
        mesh_name = meshes[node["mesh"]].get("name") if node["mesh"] < len(meshes) else None
        name = node.get("name") or mesh_name or f"part_{found}"
        # one primitive: the node's own frame; several: one child frame each
        frames = [frame_of[i]] + [c for c in children.get(frame_of[i], [])
                                  if c not in taken.keys() and c.startswith(frame_of[i] + "_")]
        out = []
        for frame in frames:
            transform, geometry = graph[frame]
            mesh = scene.geometry.get(geometry) if geometry is not None else None
            if mesh is None or len(getattr(mesh, "faces", ())) == 0:
                continue
            out.append((np.asarray(transform, dtype=np.float64), mesh))
        if out:
            found += 1
            yield node, name, out


def placed(frames) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A node's primitives (:func:`gltf_node_frames`) in the scene's frame, as one mesh:
    ``(vertices, faces, which)`` (:func:`~pipeline.mesh.topology.stack`)."""
    return stack([(np.asarray(mesh.vertices, dtype=np.float64) @ t[:3, :3].T + t[:3, 3],
                   np.asarray(mesh.faces, dtype=np.int64)) for t, mesh in frames])


def _read_gltf(path: Path, where: str) -> MeshFile:
    scene = _load(path, where, force="scene")
    header = _gltf_header(path)
    graph = scene.graph
    parts = []
    for _, name, frames in gltf_node_frames(scene, header):
        verts, faces, _ = placed(frames)
        parts.append(Part(name, *_checked(verts, faces, where, f"part {name!r}")))
    if not parts and scene.geometry:  # no node table (unexpected): trimesh's own frames
        for k, frame in enumerate(graph.nodes_geometry):
            transform, geometry = graph[frame]
            mesh = scene.geometry[geometry]
            if len(getattr(mesh, "faces", ())) == 0:
                continue
            v = np.asarray(mesh.vertices, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]
            parts.append(Part(f"part_{k}", *_checked(v, mesh.faces, where, f"part_{k}")))
    return MeshFile(parts, "+y", 1.0)
