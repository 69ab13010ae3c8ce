"""Off-screen rendering with pyvista: frames, an MP4, a contact sheet, debug views.

The camera is fixed for a whole sequence: a three-quarter view of the bounding box of
every frame, so the bloom grows in a still frame instead of the camera chasing it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
if not os.environ.get("DISPLAY"):
    # No X server: go straight to EGL instead of trying X first (and warning about it).
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _pv():
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def _polydata(pv, vertices: np.ndarray, faces: np.ndarray):
    cells = np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces.astype(np.int64)])
    return pv.PolyData(np.asarray(vertices, dtype=np.float64).copy(), cells.ravel())


def camera_for(points: np.ndarray, up: np.ndarray) -> tuple:
    """A three-quarter view of ``points (N, 3)`` looking slightly down, with ``up`` up."""
    up = up / np.linalg.norm(up)
    lo, hi = points.min(axis=0), points.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    side = np.cross(up, helper)
    side /= np.linalg.norm(side)
    front = np.cross(side, up)
    direction = 0.75 * front + 0.55 * side + 0.45 * up
    direction /= np.linalg.norm(direction)
    position = center + direction * radius * 3.4  # the bounding sphere fills most of a 30 degree view
    return (tuple(position), tuple(center), tuple(up))


def new_plotter(width: int, height: int):
    pv = _pv()
    p = pv.Plotter(off_screen=True, window_size=(width, height), lighting="three lights")
    p.set_background("white", top="#dfe6ee")
    p.enable_anti_aliasing("ssaa")
    return p


#: the "petals" palette: soft blossom colours, one per petal (repeating)
PETAL_COLOURS = ("#f4a6c1", "#e97fa5", "#f7c6d9", "#d8668f", "#fbd3e0", "#c9577f")


def render_frames(positions: np.ndarray, faces: np.ndarray, out_dir: Path, *, width: int,
                  height: int, fps: int, color: str, contact_frames: int,
                  up: np.ndarray | None = None,
                  labels: list[str] | None = None, petal: np.ndarray | None = None,
                  growth: np.ndarray | None = None, turntable_frames: int = 0,
                  progress=None) -> list[Path]:
    """Render every frame of ``positions (T, V, 3)`` to ``out_dir/frames/NNNN.png``, then
    ``out_dir/bloom.mp4``, ``out_dir/contact_sheet.png`` and, with ``turntable_frames``,
    ``out_dir/turntable.mp4`` (one turn around the last frame). Colours: ``color``;
    or one of :data:`PETAL_COLOURS` per ``petal``; or the growth map ``growth (V,)``.
    Returns the frame paths."""
    import imageio.v2 as imageio

    pv = _pv()
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    plotter = new_plotter(width, height)
    mesh = _polydata(pv, positions[0], faces)
    look = dict(smooth_shading=True, specular=0.25, diffuse=0.85, ambient=0.15, show_edges=False)
    if growth is not None:
        mesh.point_data["growth"] = np.asarray(growth, dtype=np.float64)
        plotter.add_mesh(mesh, scalars="growth", cmap="RdPu", show_scalar_bar=True,
                         scalar_bar_args={"title": "growth ratio", "color": "#333333"}, **look)
    elif petal is not None:
        rgb = np.array([[int(c[i:i + 2], 16) for i in (1, 3, 5)] for c in PETAL_COLOURS],
                       dtype=np.uint8)
        mesh.point_data["colour"] = rgb[np.asarray(petal) % len(rgb)]
        plotter.add_mesh(mesh, scalars="colour", rgb=True, **look)
    else:
        plotter.add_mesh(mesh, color=color, **look)
    plotter.camera_position = camera_for(positions.reshape(-1, 3), up)
    text = plotter.add_text("", position="lower_left", font_size=10, color="#333333")
    images, paths = [], []
    for k, frame in enumerate(positions):
        mesh.points = frame
        mesh.compute_normals(inplace=True, auto_orient_normals=False, split_vertices=False)
        if labels is not None:
            text.SetText(0, labels[k])
        plotter.render()
        img = plotter.screenshot(return_img=True)
        path = frames_dir / f"{k:04d}.png"
        imageio.imwrite(path, img)
        images.append(img)
        paths.append(path)
        if progress is not None:
            progress(1)
    turn = []
    if turntable_frames:
        text.SetText(0, "")
        plotter.camera.SetViewUp(*up)
        for _ in range(turntable_frames):
            plotter.camera.Azimuth(360.0 / turntable_frames)
            plotter.render()
            turn.append(plotter.screenshot(return_img=True))
            if progress is not None:
                progress(1)
    plotter.close()
    for name, seq in (("bloom.mp4", images), ("turntable.mp4", turn)):
        if not seq:
            continue
        with imageio.get_writer(out_dir / name, fps=fps, codec="libx264", quality=8,
                                macro_block_size=2, pixelformat="yuv420p",
                                ffmpeg_log_level="error") as writer:
            for img in seq:
                writer.append_data(img)
    contact_sheet(images, out_dir / "contact_sheet.png", contact_frames)
    return paths


def contact_sheet(images: list[np.ndarray], path: Path, count: int, columns: int = 4) -> None:
    """Tile ``count`` evenly spaced images (first and last included) into one PNG."""
    import imageio.v2 as imageio

    count = min(count, len(images))
    pick = np.round(np.linspace(0, len(images) - 1, count)).astype(int)
    tiles = [images[i] for i in pick]
    h, w = tiles[0].shape[:2]
    columns = min(columns, count)
    rows = -(-count // columns)
    sheet = np.full((rows * h, columns * w, tiles[0].shape[2]), 255, dtype=np.uint8)
    for n, tile in enumerate(tiles):
        r, c = divmod(n, columns)
        sheet[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile
    imageio.imwrite(path, sheet)


def render_debug(vertices: np.ndarray, faces: np.ndarray, path: Path, *, width: int, height: int,
                 scalars: np.ndarray | None, scalar_name: str, cmap: str,
                 clim: tuple | None = None, points: dict | None = None,
                 up: np.ndarray | None = None, title: str = "") -> None:
    """One still image of a mesh coloured by ``scalars`` (per vertex), with marked points.

    ``points`` maps a label to ``(positions (N, 3), colour)``: e.g. base, tip, axis.
    """
    import imageio.v2 as imageio

    pv = _pv()
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    plotter = new_plotter(width, height)
    mesh = _polydata(pv, vertices, faces)
    if scalars is not None:
        mesh.point_data[scalar_name] = scalars
        plotter.add_mesh(mesh, scalars=scalar_name, cmap=cmap, clim=clim, smooth_shading=True,
                         show_edges=True, edge_color="#555555", line_width=0.5,
                         scalar_bar_args={"title": scalar_name, "vertical": True})
    else:
        plotter.add_mesh(mesh, color="#f4a6c1", smooth_shading=True, show_edges=True)
    radius = 0.004 * np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0))
    for label, (pts, colour) in (points or {}).items():
        if len(pts):
            cloud = pv.PolyData(np.asarray(pts, dtype=np.float64))
            plotter.add_mesh(cloud.glyph(geom=pv.Sphere(radius=max(radius, 0.3)), scale=False,
                                         orient=False), color=colour, label=label)
    if points:
        plotter.add_legend(bcolor="white", size=(0.16, 0.12), loc="upper left")
    if title:
        plotter.add_text(title, position="lower_left", font_size=10, color="#333333")
    plotter.camera_position = camera_for(vertices, up)
    plotter.render()
    img = plotter.screenshot(return_img=True)
    plotter.close()
    imageio.imwrite(path, img)
