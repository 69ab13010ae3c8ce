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

import numpy as np

from . import topology


def petal_meshes(faces: np.ndarray, petal: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each petal's ``(vertex indices into the whole, faces in its own numbering)``."""
    out = []
    for p in range(int(petal.max()) + 1):
        idx = np.flatnonzero(petal == p)
        local = np.full(len(petal), -1, dtype=np.int64)
        local[idx] = np.arange(len(idx))
        out.append((idx, local[faces[petal[faces[:, 0]] == p]]))
    return out


def write_usd(path, positions: np.ndarray, faces: np.ndarray, petal: np.ndarray,
              fps: float, source: dict | None = None, up: str = "Z",
              meters_per_unit: float = 1.0) -> None:
    """Write ``positions (T, V, 3)`` (already at the user's scale) as a USD stage with
    ``up`` ("Y" or "Z") as its up axis and ``meters_per_unit``; ``source`` goes into the
    layer's custom data under ``bloom``."""
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    stage.GetRootLayer().customLayerData = {"bloom": {k: str(v) for k, v in
                                                      (source or {}).items()}}
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(len(positions) - 1)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    root = UsdGeom.Xform.Define(stage, "/Bloom")
    stage.SetDefaultPrim(root.GetPrim())
    for p, (idx, local) in enumerate(petal_meshes(faces, petal)):
        mesh = UsdGeom.Mesh.Define(stage, Sdf.Path(f"/Bloom/petal_{p:02d}"))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(local)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(local.ravel().tolist()))
        mesh.CreateDoubleSidedAttr(True)
        points, normals, extent = (mesh.CreatePointsAttr(), mesh.CreateNormalsAttr(),
                                   mesh.CreateExtentAttr())
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        for t, X in enumerate(positions):
            P = np.ascontiguousarray(X[idx], dtype=np.float64)
            points.Set(Vt.Vec3fArray.FromNumpy(P.astype(np.float32)), Usd.TimeCode(t))
            N = topology.vertex_normals(P, local).astype(np.float32)
            normals.Set(Vt.Vec3fArray.FromNumpy(N), Usd.TimeCode(t))
            lo, hi = P.min(axis=0), P.max(axis=0)
            extent.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]),
                       Usd.TimeCode(t))
    stage.GetRootLayer().Save()


def read_usd_points(path, time: float) -> np.ndarray:
    """All petals' points at ``time``, in petal order (for checks and tests)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    parts = []
    for prim in stage.GetPrimAtPath("/Bloom").GetChildren():
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
    import os

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
