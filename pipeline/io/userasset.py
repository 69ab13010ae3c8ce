"""The user's asset as the file gives it: per part, its own vertices, polygons, UVs,
normals and material names, for the export to give it back.

:func:`pipeline.io.meshfile.read_parts` reads a file for simulating (trimesh's triangles;
an OBJ's vertices split where its UVs are); :func:`read_asset` reads the same parts, in
the same order and under the same names, as a modelling tool would write them back:

- OBJ: parsed here. A part's points are the ``v`` lines its faces use, in file order;
  its faces are the file's polygons (not triangulated), in file order; UVs (``vt``) and
  normals (``vn``) are indexed per face corner (face-varying), as the file has them;
  ``usemtl`` names each face's material.
- glTF / GLB: through trimesh, as :func:`~pipeline.io.meshfile.read_parts` reads them (one
  part per node with a mesh, its primitives joined, placed by the scene's transforms).
  Points are the file's vertices in accessor order; UVs and normals are per vertex (the
  format's own layout); each primitive's material names its faces.
- STL, PLY, OFF: the parts :func:`~pipeline.io.meshfile.read_parts` finds, no UVs.

:func:`write` and :func:`read` store an asset in an artifact under ``input/asset``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from pipeline.artifact import put
from pipeline.errors import BloomError
from pipeline.io.meshfile import (
    _check_path,
    _gltf_header,
    _load,
    _obj_units,
    gltf_node_frames,
    obj_text,
    placed,
    read_parts,
)

GROUP = "input/asset"


@dataclass
class AssetPart:
    """One part of the user's file, in the file's units and axes."""

    name: str  #: the file's own name (as :func:`~pipeline.io.meshfile.read_parts` gives it)
    points: np.ndarray  #: (n, 3) float64, the file's vertices of this part, in its order
    face_counts: np.ndarray  #: (m,) int64, corners of each polygon
    face_indices: np.ndarray  #: (sum(face_counts),) int64, into ``points``
    uv: np.ndarray | None = None  #: (k, 2) float64 texture coordinates, or None
    #: (sum(face_counts),) int64 into ``uv`` per face corner (face-varying); None with
    #: ``uv`` given: one UV per point (vertex)
    uv_indices: np.ndarray | None = None
    normals: np.ndarray | None = None  #: (j, 3) float64 the file's normals, or None
    normal_indices: np.ndarray | None = None  #: as ``uv_indices``, for ``normals``
    materials: list = field(default_factory=list)  #: material names, first use first
    face_material: np.ndarray | None = None  #: (m,) int64 into ``materials``, -1: none

    def triangles(self) -> np.ndarray:
        """``(F, 3)`` the polygons as fans from their first corner, in order."""
        return fan_triangles(self.face_counts, self.face_indices)


@dataclass
class Asset:
    parts: list[AssetPart]
    up: str | None  #: "+y" for glTF; None where the file does not say
    meters_per_unit: float | None  #: glTF 1; an OBJ's unit comment (Maya); else None
    source: str = ""  #: the file it came from

    @property
    def names(self) -> list[str]:
        return [p.name for p in self.parts]


def fan_triangles(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Polygons (``counts``, flat ``indices``) as triangle fans, ``(sum(counts - 2), 3)``."""
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    start = np.r_[0, np.cumsum(counts)[:-1]]
    fans = counts - 2
    face = np.repeat(np.arange(len(counts)), fans)
    k = np.arange(int(fans.sum())) - np.repeat(np.cumsum(fans) - fans, fans)
    first = start[face]
    return np.stack([indices[first], indices[first + k + 1], indices[first + k + 2]], axis=1)


def read_asset(path: str | Path) -> Asset:
    """Read ``path`` as its parts with their own vertices, polygons, UVs, normals and
    materials (see the module notes). Raises :class:`BloomError` naming the file."""

    path = Path(path)
    where = _check_path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        return _read_obj(path, where)
    if suffix in (".glb", ".gltf"):
        return _read_gltf(path, where)
    mesh_file = read_parts(path)
    parts = [AssetPart(p.name, p.vertices, np.full(len(p.faces), 3, dtype=np.int64),
                       p.faces.ravel().copy(), face_material=np.full(len(p.faces), -1))
             for p in mesh_file.parts]
    return Asset(parts, mesh_file.up, mesh_file.meters_per_unit, str(path))


# --- OBJ --------------------------------------------------------------------------------

def _index(token: str, count: int, where: str, line_no: int) -> int:
    i = int(token)
    i = i - 1 if i > 0 else count + i
    if not 0 <= i < count:
        raise BloomError(f"line {line_no}: face refers to a vertex that does not exist", where=where)
    return i


def _read_obj(path: Path, where: str) -> Asset:

    text = obj_text(path, where)
    v, vt, vn = [], [], []
    obj = group = named_group = None
    material = None
    parts: dict[tuple, dict] = {}  # (o, g) as trimesh keys them -> what the part collects
    for line_no, raw in enumerate(text.split("\n"), start=1):
        line = raw.strip()
        if not line or line[0] == "#":
            continue
        tag, _, rest = line.partition(" ")
        if tag == "v":
            v.append([float(x) for x in rest.split()[:3]])
        elif tag == "vt":
            vals = rest.split()
            vt.append([float(vals[0]), float(vals[1]) if len(vals) > 1 else 0.0])
        elif tag == "vn":
            vn.append([float(x) for x in rest.split()[:3]])
        elif tag == "o":
            obj, named_group = rest.strip(), None
        elif tag == "g":
            group = named_group = rest.strip()
        elif tag == "usemtl":
            material = rest.strip()
        elif tag == "f":
            key = (obj, group)
            if key not in parts:  # named as pipeline.io.meshfile._obj_keys names it
                if obj is not None and named_group is not None and named_group != obj:
                    name = f"{obj}/{named_group}"
                else:
                    name = obj if obj is not None else named_group
                parts[key] = {"name": name, "counts": [], "v": [], "vt": [], "vn": [],
                              "mat": [], "has_vt": True, "has_vn": True}
            part = parts[key]
            corners = rest.split()
            if len(corners) < 3:
                continue
            part["counts"].append(len(corners))
            for c in corners:
                fields = c.split("/")
                part["v"].append(_index(fields[0], len(v), where, line_no))
                if len(fields) > 1 and fields[1]:
                    part["vt"].append(_index(fields[1], len(vt), where, line_no))
                else:
                    part["has_vt"] = False
                if len(fields) > 2 and fields[2]:
                    part["vn"].append(_index(fields[2], len(vn), where, line_no))
                else:
                    part["has_vn"] = False
            part["mat"].append(material)
    v_all = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    vt_all = np.asarray(vt, dtype=np.float64).reshape(-1, 2)
    vn_all = np.asarray(vn, dtype=np.float64).reshape(-1, 3)
    out = []
    for k, part in enumerate(parts.values()):
        if not part["counts"]:
            continue
        used, local = np.unique(np.asarray(part["v"], dtype=np.int64), return_inverse=True)
        item = AssetPart(part["name"] or f"part_{k}", v_all[used],
                         np.asarray(part["counts"], dtype=np.int64), local.astype(np.int64))
        if part["has_vt"] and part["vt"]:
            used_t, local_t = np.unique(np.asarray(part["vt"], dtype=np.int64), return_inverse=True)
            item.uv, item.uv_indices = vt_all[used_t], local_t.astype(np.int64)
        if part["has_vn"] and part["vn"]:
            used_n, local_n = np.unique(np.asarray(part["vn"], dtype=np.int64), return_inverse=True)
            item.normals, item.normal_indices = vn_all[used_n], local_n.astype(np.int64)
        names = [m for m in dict.fromkeys(part["mat"]) if m is not None]
        item.materials = names
        item.face_material = np.asarray([names.index(m) if m is not None else -1
                                         for m in part["mat"]], dtype=np.int64)
        out.append(item)
    if not np.all(np.isfinite(v_all)):
        raise BloomError("non-finite (NaN or inf) vertex coordinates", where=where)
    return Asset(out, None, _obj_units(text), str(path))


# --- glTF --------------------------------------------------------------------------------

def _read_gltf(path: Path, where: str) -> Asset:

    scene = _load(path, where, force="scene")
    header = _gltf_header(path)
    meshes = header.get("meshes", [])
    parts = []
    for node, name, frames in gltf_node_frames(scene, header):
        m = node.get("mesh")
        prims = meshes[m].get("primitives", []) if m is not None and m < len(meshes) else []
        file_normals = bool(prims) and all("NORMAL" in p.get("attributes", {}) for p in prims)
        points, faces, _ = placed(frames)
        uvs, nrm, mats, face_mat = [], [], [], []
        for transform, mesh in frames:
            vtx = mesh.vertices
            uv = getattr(mesh.visual, "uv", None)
            uvs.append(None if uv is None or len(uv) != len(vtx) else np.asarray(uv, dtype=np.float64))
            if file_normals:
                inv_t = np.linalg.inv(transform[:3, :3]).T  # normals go by the inverse transpose
                n = np.asarray(mesh.vertex_normals, dtype=np.float64) @ inv_t.T
                nrm.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
            material = getattr(getattr(mesh.visual, "material", None), "name", None)
            if material is not None and material not in mats:
                mats.append(material)
            face_mat.append(np.full(len(mesh.faces), mats.index(material) if material is not None
                                    else -1, dtype=np.int64))
        if not len(points):
            continue
        part = AssetPart(name, points, np.full(len(faces), 3, dtype=np.int64),
                         faces.ravel().copy(), materials=mats, face_material=np.concatenate(face_mat))
        if all(u is not None for u in uvs):
            part.uv = np.vstack(uvs)
        if file_normals:
            part.normals = np.vstack(nrm)
        parts.append(part)
    return Asset(parts, "+y", 1.0, str(path))


# --- in an artifact ------------------------------------------------------------------------

#: the per-part arrays of :func:`write`, each stored once for all parts, concatenated
#: (``<name>``), with where each part's run starts (``<name>_offsets``, ``(P + 1,)``) and,
#: for those a part may lack, whether it has one (``<name>_given``, ``(P,)``)
#: (and each row's width: 3 for points, ``()`` for one index per row)
_PACKED = (("points", "(n, 3) each part's vertices, in the file's order", False, (3,)),
           ("face_counts", "(m,) corners of each polygon", False, ()),
           ("face_indices", "(sum face_counts,) into the part's points", False, ()),
           ("face_material", "(m,) into the part's materials, -1: none", False, ()),
           ("uv", "(k, 2) texture coordinates", True, (2,)),
           ("uv_indices", "per face corner, into the part's uv", True, ()),
           ("normals", "(j, 3) the file's normals", True, (3,)),
           ("normal_indices", "per face corner, into the part's normals", True, ()))


def write(h5, asset: Asset) -> None:
    """Store ``asset`` under ``input/asset`` of an open HDF5 file (see :func:`read`):
    each array once for all parts, concatenated (a branch of 5,000 parts wrote 25,000
    datasets, and every later stage copied them)."""
    group = h5.require_group(GROUP)
    group.attrs["doc"] = ("the input's parts as the file gives them (input units and axes), "
                          "for the export; part i is part i of mesh/part_names; each array "
                          "of all parts concatenated, <name>_offsets where each part's starts")
    group.attrs["up"] = asset.up or ""
    group.attrs["meters_per_unit"] = float(asset.meters_per_unit or 0.0)
    parts = asset.parts
    put(h5, f"{GROUP}/names", np.array([p.name for p in parts], dtype=object).astype(
        h5py.string_dtype("utf-8")) if parts else np.zeros(0, dtype=h5py.string_dtype("utf-8")),
        "(P,) each part's name")
    for name, doc, optional, width in _PACKED:
        runs = [getattr(p, name) for p in parts]
        if name == "face_material":
            runs = [r if r is not None else np.full(len(p.face_counts), -1, dtype=np.int64)
                    for r, p in zip(runs, parts, strict=True)]
        given = np.array([r is not None for r in runs], dtype=bool)
        arrays = [np.asarray(r) for r in runs if r is not None]
        dtype = np.float64 if width else np.int64
        data = (np.concatenate([a.reshape((-1, *width)).astype(dtype) for a in arrays])
                if arrays else np.zeros((0, *width), dtype=dtype))
        lengths = [0 if r is None else len(np.asarray(r)) for r in runs]
        put(h5, f"{GROUP}/{name}", data, doc)
        put(h5, f"{GROUP}/{name}_offsets", np.cumsum([0, *lengths]).astype(np.int64),
            f"(P + 1,) where each part's {name} starts")
        if optional:
            put(h5, f"{GROUP}/{name}_given", given, f"(P,) whether a part has {name}")
    materials = [list(p.materials) for p in parts]
    put(h5, f"{GROUP}/materials", np.array([m for ms in materials for m in ms], dtype=object)
        .astype(h5py.string_dtype("utf-8")) if any(materials)
        else np.zeros(0, dtype=h5py.string_dtype("utf-8")), "material names, part after part")
    put(h5, f"{GROUP}/materials_offsets",
        np.cumsum([0, *[len(m) for m in materials]]).astype(np.int64),
        "(P + 1,) where each part's materials start")


def _text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def read(src) -> Asset | None:
    """The asset stored in an artifact (an :class:`~pipeline.artifact.Artifact` or an
    h5py File), or None if it holds none. Reads the packed layout :func:`write` writes,
    and the one of a part per group an earlier version wrote."""
    f = getattr(src, "file", src)
    if GROUP not in f:
        return None
    group = f[GROUP]
    up = str(group.attrs.get("up", "")) or None
    mpu = float(group.attrs.get("meters_per_unit", 0.0)) or None
    if "names" not in group:
        return Asset(_read_per_group(group), up, mpu)
    names = [_text(n) for n in group["names"][()]]
    arrays = {}
    for name, _, optional, _ in _PACKED:
        data, at = group[name][()], group[f"{name}_offsets"][()]
        given = group[f"{name}_given"][()] if optional else np.ones(len(names), dtype=bool)
        arrays[name] = [data[at[i]:at[i + 1]] if given[i] else None for i in range(len(names))]
    materials, at = group["materials"][()], group["materials_offsets"][()]
    parts = [AssetPart(names[i], arrays["points"][i], arrays["face_counts"][i],
                       arrays["face_indices"][i], arrays["uv"][i], arrays["uv_indices"][i],
                       arrays["normals"][i], arrays["normal_indices"][i],
                       [_text(m) for m in materials[at[i]:at[i + 1]]],
                       arrays["face_material"][i]) for i in range(len(names))]
    return Asset(parts, up, mpu)


def _read_per_group(group) -> list[AssetPart]:
    """The parts of the layout an earlier version wrote: a group per part."""
    parts = []
    for i in range(len(group)):
        g = group[str(i)]

        def get(name, g=g):
            return g[name][()] if name in g else None

        parts.append(AssetPart(
            str(g.attrs["name"]), get("points"), get("face_counts"), get("face_indices"),
            get("uv"), get("uv_indices"), get("normals"), get("normal_indices"),
            [_text(m) for m in g["materials"][()]], get("face_material")))
    return parts
