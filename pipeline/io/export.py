"""Caches that DCC tools read: a USD stage (Blender, Houdini, Maya, usdview) and OBJ or
PLY sequences, from a sim.h5, at the user's original scale.

- USD (usd-core, the official wheel): one ``UsdGeom.Mesh`` per petal under
  ``/Bloom`` (``/Bloom/petal_00`` ...), with faces, time-sampled points, vertex normals
  and extents at every frame; the stage's time codes are frame numbers, played at the
  scene's ``render.fps``. Points are divided by the artifact's ``scale`` (mesh units per
  input unit), so they come back in the units of the mesh the user gave `bloom remesh`
  (never rotated); ``metersPerUnit`` is ``export.meters_per_unit`` (1: the input was in
  meters, as Blender's are); the up axis is Y or Z, whichever the flower's axis is
  nearer (the input's own convention).
- OBJ / PLY: one file per frame, ``bloom_0000.obj`` ..., in a folder (meshio).
- XDMF (ParaView): ``bloom.xdmf`` + ``bloom.h5`` in a folder (meshio's time series):
  the first frame's mesh, and per frame the point data ``displacement`` (from the
  first frame; Warp By Vector shows the bloom) and ``petal``.
"""

from __future__ import annotations

import os

import numpy as np

from pipeline.io.binding import deform, sides
from pipeline.io.binding import keep_thickness as keep
from pipeline.mesh import topology


def petal_meshes(faces: np.ndarray, petal: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each petal's ``(vertex indices into the whole, faces in its own numbering)``."""
    out = []
    for p in range(int(petal.max()) + 1):
        idx = np.flatnonzero(petal == p)
        local = np.full(len(petal), -1, dtype=np.int64)
        local[idx] = np.arange(len(idx))
        out.append((idx, local[faces[petal[faces[:, 0]] == p]]))
    return out


def _new_stage(path, source: dict | None, up: str, meters_per_unit: float,
               frame_numbers: np.ndarray, fps: float):
    """A new USD stage at ``path``: ``source`` in the layer's custom data under ``bloom``,
    the up axis ("Y" or "Z"), metres per unit, time codes the frame numbers at ``fps``,
    and the default prim ``/Bloom``."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    stage.GetRootLayer().customLayerData = {"bloom": {k: str(v) for k, v in
                                                      (source or {}).items()}}
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    stage.SetStartTimeCode(float(frame_numbers[0]))
    stage.SetEndTimeCode(float(frame_numbers[-1]))
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/Bloom").GetPrim())
    return stage


def write_usd(path, positions: np.ndarray, faces: np.ndarray, petal: np.ndarray,
              fps: float, source: dict | None = None, up: str = "Z",
              meters_per_unit: float = 1.0, frame_numbers: np.ndarray | None = None) -> None:
    """Write ``positions (T, V, 3)`` (already at the user's scale) as a USD stage with
    ``up`` ("Y" or "Z") as its up axis and ``meters_per_unit``; ``source`` goes into the
    layer's custom data under ``bloom``."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    numbers = np.arange(len(positions)) if frame_numbers is None else np.asarray(frame_numbers)
    stage = _new_stage(path, source, up, meters_per_unit, numbers, fps)
    for p, (idx, local) in enumerate(petal_meshes(faces, petal)):
        mesh = UsdGeom.Mesh.Define(stage, Sdf.Path(f"/Bloom/petal_{p:02d}"))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(local)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(local.ravel().tolist()))
        mesh.CreateDoubleSidedAttr(True)
        points, normals, extent = (mesh.CreatePointsAttr(), mesh.CreateNormalsAttr(),
                                   mesh.CreateExtentAttr())
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        for number, X in zip(numbers, positions, strict=True):
            code = Usd.TimeCode(float(number))
            P = np.ascontiguousarray(X[idx], dtype=np.float64)
            points.Set(Vt.Vec3fArray.FromNumpy(P.astype(np.float32)), code)
            N = topology.vertex_normals(P, local).astype(np.float32)
            normals.Set(Vt.Vec3fArray.FromNumpy(N), code)
            lo, hi = P.min(axis=0), P.max(axis=0)
            extent.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]), code)
    stage.GetRootLayer().Save()


def read_usd_points(path, time: float) -> np.ndarray:
    """All meshes' points at ``time``, in prim order (for checks and tests)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    parts = []
    for prim in stage.GetPrimAtPath("/Bloom").GetChildren():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        pts = UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode(time))
        parts.append(np.asarray(pts, dtype=np.float64))
    return np.concatenate(parts)


def write_sequence(folder, positions: np.ndarray, faces: np.ndarray, fmt: str) -> list:
    """One ``bloom_NNNN.<fmt>`` per frame into ``folder``; returns the paths."""
    import meshio

    paths = []
    for t, X in enumerate(positions):
        path = folder / f"bloom_{t:04d}.{fmt}"
        meshio.write_points_cells(str(path), np.asarray(X, dtype=np.float64),
                                  [("triangle", np.asarray(faces, dtype=np.int64))],
                                  file_format=fmt if fmt == "obj" else "ply")
        paths.append(path)
    return paths


def write_xdmf(folder, positions: np.ndarray, faces: np.ndarray, petal: np.ndarray,
               fps: float) -> None:
    """An XDMF time series in ``folder``: times in seconds at ``fps``."""

    import meshio

    here = os.getcwd()
    os.chdir(folder)  # meshio writes the .h5 beside the .xdmf, by name
    try:
        with meshio.xdmf.TimeSeriesWriter("bloom.xdmf") as writer:
            writer.write_points_cells(np.asarray(positions[0], dtype=np.float64),
                                      [("triangle", np.asarray(faces, dtype=np.int64))])
            for t, X in enumerate(positions):
                writer.write_data(t / fps, point_data={
                    "displacement": np.asarray(X - positions[0], dtype=np.float64),
                    "petal": np.asarray(petal, dtype=np.float64)})
    finally:
        os.chdir(here)


# --- the user's asset, deformed by the sheet (export.mesh = "input") -------------------------

def asset_frames(positions: np.ndarray, faces: np.ndarray, asset, bindings: dict,
                 scale: float, keep_thickness: bool = True,
                 sides: dict | None = None, progress=None) -> list[np.ndarray]:
    """Each part's points through the frames, at the input's scale: ``(T, n, 3)`` for a
    part bound to the sheet (``bindings``: part -> :class:`pipeline.io.binding.Binding`),
    deformed by each frame of ``positions (T, V, 3)`` (mesh units), a thick part's sides
    then kept as far apart as at rest (:func:`pipeline.io.binding.keep_thickness`, unless
    ``keep_thickness`` is off: the binding alone, as Surface Deform does); ``(n, 3)``,
    its own points, for a part that stays where it is. ``sides``: the bound parts'
    :func:`part_sides`, if already found. ``progress(name)``: called as each part is done."""

    if keep_thickness and sides is None:
        sides = part_sides(asset, bindings, positions[0], faces, scale)
    out = []
    normals = [topology.vertex_normals(X, faces) for X in positions] if bindings else []
    for i, part in enumerate(asset.parts):
        if i in bindings:
            b = bindings[i]
            frames = np.stack([deform(X, faces, b, N) / scale
                               for X, N in zip(positions, normals, strict=True)])
            if keep_thickness and len(sides[i].point):
                tris = part.triangles()
                frames = np.stack([keep(F, tris, sides[i]) for F in frames])
            out.append(frames)
        else:
            out.append(np.asarray(part.points, dtype=np.float64))
        if progress is not None:
            progress(part.name)
    return out


def part_sides(asset, bindings: dict, rest: np.ndarray, faces: np.ndarray, scale: float) -> dict:
    """Each bound part's two sides facing each other across the sheet
    (:func:`pipeline.io.binding.sides`; none for a one-sided part), by part; ``rest``: the
    sheet's rest vertices (mesh units)."""

    return {i: sides(asset.parts[i].points, asset.parts[i].triangles(), b, rest / scale,
                     faces, scale) for i, b in bindings.items()}


def asset_normals(part, points: np.ndarray, turn: np.ndarray | None = None):
    """A part's normals for USD: ``(normals, interpolation)``. The file's own (per vertex,
    or per face corner where the file indexes them so), turned by ``turn (n, 3, 3)``
    (each point's rotation from rest, for a deformed part) where given; without the
    file's, area-weighted vertex normals of ``points``."""
    if part.normals is None:
        return topology.vertex_normals(points, part.triangles()), "vertex"
    if part.normal_indices is None:
        n = np.asarray(part.normals, dtype=np.float64)
        return (n if turn is None else np.einsum("nij,nj->ni", turn, n)), "vertex"
    n = np.asarray(part.normals, dtype=np.float64)[part.normal_indices]
    if turn is not None:
        n = np.einsum("nij,nj->ni", turn[part.face_indices], n)
    return n, "faceVarying"


def prim_names(names: list[str]) -> list[str]:
    """The names made valid USD prim names (Tf.MakeValidIdentifier: "Circle.003" ->
    "Circle_003") and unique (a repeat gets _1, _2, ...)."""
    from pxr import Tf

    out, seen = [], set()
    for name in names:
        base = Tf.MakeValidIdentifier(name) if name else "part"
        candidate, k = base, 0
        while candidate in seen:
            k += 1
            candidate = f"{base}_{k}"
        seen.add(candidate)
        out.append(candidate)
    return out


def write_usd_asset(path, frames: list[np.ndarray], asset, fps: float, frame_numbers: np.ndarray,
                    turns: dict | None = None, source: dict | None = None, up: str = "Z",
                    meters_per_unit: float = 1.0, progress=None) -> None:
    """Write the user's parts (``asset``, a :class:`pipeline.io.userasset.Asset`) as a USD
    stage: one ``UsdGeom.Mesh`` per part under ``/Bloom``, named after the part (made a
    valid prim name; the file's own name is the prim's ``displayName``), with the part's
    own points, polygons and order; ``primvars:st`` (face-varying where the file's UVs
    are, else per vertex); normals; each material name a ``UsdShade.Material`` under
    ``/Bloom/Looks`` bound to its faces through a ``GeomSubset``. ``frames[i]`` is part
    i's points: ``(T, n, 3)`` time-sampled at ``frame_numbers`` (the time codes), or
    ``(n, 3)`` static. ``turns[i] (T, n, 3, 3)`` turns a deformed part's own normals.
    ``progress(name)``: called as each part is written."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    frame_numbers = np.asarray(frame_numbers)
    stage = _new_stage(path, source, up, meters_per_unit, frame_numbers, fps)
    material_names = list(dict.fromkeys(m for p in asset.parts for m in p.materials))
    looks = {}
    if material_names:
        UsdGeom.Scope.Define(stage, "/Bloom/Looks")
        for name, prim in zip(material_names, prim_names(material_names), strict=True):
            material = UsdShade.Material.Define(stage, f"/Bloom/Looks/{prim}")
            material.GetPrim().SetDisplayName(name)
            shader = UsdShade.Shader.Define(stage, f"/Bloom/Looks/{prim}/PreviewSurface")
            shader.CreateIdAttr("UsdPreviewSurface")
            material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            looks[name] = material
    turns = turns or {}
    for i, (part, prim, pts) in enumerate(zip(asset.parts, prim_names(asset.names), frames,
                                              strict=True)):
        mesh = UsdGeom.Mesh.Define(stage, Sdf.Path(f"/Bloom/{prim}"))
        mesh.GetPrim().SetDisplayName(part.name)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(part.face_counts.astype(np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(part.face_indices.astype(np.int32)))
        mesh.CreateDoubleSidedAttr(True)
        points, normals, extent = (mesh.CreatePointsAttr(), mesh.CreateNormalsAttr(),
                                   mesh.CreateExtentAttr())
        animated = pts.ndim == 3
        samples = ([(Usd.TimeCode(float(f)), P, turns[i][t] if i in turns else None)
                    for t, (f, P) in enumerate(zip(frame_numbers, pts, strict=True))]
                   if animated else [(Usd.TimeCode.Default(), pts, None)])
        for code, P, turn in samples:
            points.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(P, dtype=np.float32)), code)
            N, how = asset_normals(part, P, turn)
            normals.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(N, dtype=np.float32)), code)
            lo, hi = P.min(axis=0), P.max(axis=0)
            extent.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]), code)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying if how == "faceVarying"
                                     else UsdGeom.Tokens.vertex)
        if part.uv is not None:
            face_varying = part.uv_indices is not None
            st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
                "st", Sdf.ValueTypeNames.TexCoord2fArray,
                UsdGeom.Tokens.faceVarying if face_varying else UsdGeom.Tokens.vertex)
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(part.uv, dtype=np.float32)))
            if face_varying:
                st.SetIndices(Vt.IntArray.FromNumpy(part.uv_indices.astype(np.int32)))
        if part.materials:
            binding_api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
            covered = np.all(part.face_material >= 0)
            for k, (name, sub) in enumerate(zip(part.materials, prim_names(part.materials),
                                                strict=True)):
                subset = UsdGeom.Subset.CreateGeomSubset(
                    mesh, sub, UsdGeom.Tokens.face,
                    Vt.IntArray.FromNumpy(np.flatnonzero(part.face_material == k).astype(np.int32)),
                    UsdShade.Tokens.materialBind,
                    UsdGeom.Tokens.partition if covered else UsdGeom.Tokens.nonOverlapping)
                UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(looks[name])
            binding_api.SetMaterialBindSubsetsFamilyType(
                UsdGeom.Tokens.partition if covered else UsdGeom.Tokens.nonOverlapping)
        if progress is not None:
            progress(part.name)
    stage.GetRootLayer().Save()


def write_obj_asset(folder, frames: list[np.ndarray], asset, frame_numbers: np.ndarray) -> list:
    """One ``bloom_NNNN.obj`` per frame (NNNN the frame number) into ``folder``: every part
    as ``o <name>`` with its points, UVs (``vt``) and polygons, ``usemtl`` naming its
    materials. Returns the paths."""
    paths = []
    for t, number in enumerate(frame_numbers):
        lines = ["# bloom: the input's parts, deformed by the simulated sheet"]
        v_base = vt_base = 0
        for part, pts in zip(asset.parts, frames, strict=True):
            P = pts[t] if pts.ndim == 3 else pts
            lines.append(f"o {part.name}")
            lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in P]
            if part.uv is not None:
                lines += [f"vt {u:.9g} {v:.9g}" for u, v in part.uv]
                uv_idx = part.uv_indices if part.uv_indices is not None else part.face_indices
            start = 0
            current = None
            mats = part.face_material if part.face_material is not None else \
                np.full(len(part.face_counts), -1)
            for count, m in zip(part.face_counts.tolist(), mats.tolist(), strict=True):
                if m >= 0 and part.materials[m] != current:
                    current = part.materials[m]
                    lines.append(f"usemtl {current}")
                corners = range(start, start + count)
                if part.uv is not None:
                    lines.append("f " + " ".join(f"{part.face_indices[c] + 1 + v_base}/"
                                                 f"{uv_idx[c] + 1 + vt_base}" for c in corners))
                else:
                    lines.append("f " + " ".join(str(part.face_indices[c] + 1 + v_base)
                                                 for c in corners))
                start += count
            v_base += len(P)
            vt_base += 0 if part.uv is None else len(part.uv)
        path = folder / f"bloom_{int(number):04d}.obj"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    return paths


def joined_asset(frames: list[np.ndarray], asset) -> tuple[np.ndarray, np.ndarray]:
    """Every part as one triangle mesh through the frames: ``(positions (T, N, 3),
    triangles (F, 3))`` (polygons as fans), for the PLY and XDMF caches."""
    count = max((p.shape[0] for p in frames if p.ndim == 3), default=1)
    _, tris, _ = topology.stack([(part.points, part.triangles()) for part in asset.parts])
    positions = np.concatenate([p if p.ndim == 3 else np.broadcast_to(p, (count, *p.shape))
                                for p in frames], axis=1)
    return positions, tris
