"""Off-screen rendering with pyvista: frames, an MP4, a contact sheet, debug views.

A bloom is drawn as layers (:class:`Layer`): the user's own parts, the petals deformed
through their binding and the other parts in place (:func:`asset_layers`), or the
simulated sheet. The camera is fixed for a whole sequence (:func:`flower_camera`): the
flower upright along its own axis, seen from three-quarters above, framed on the petals
and what sits among them (stamens, pistil) over every frame, so the bloom grows in a
still frame instead of the camera chasing it. Both sides of a petal are lit alike: the
lights follow the camera and the back of a face is lit as its front.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.mesh import topology

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


#: the camera of a bloom: this far above the flower's horizon (degrees) ...
ELEVATION = 30.0
#: ... and turned this far from the front (degrees): a three-quarter view
AZIMUTH = 36.0
#: pyvista's (VTK's) vertical view angle, degrees
VIEW_ANGLE = 30.0
#: the framed points fill the picture up to this fraction of its height or width
FILL = 0.86


def flower_camera(points: np.ndarray, up: np.ndarray, aspect: float = 4.0 / 3.0) -> tuple:
    """The camera of a bloom: ``(position, focal point, view up)``.

    Parameters
    ----------
    points : (N, 3) what is framed (the petals over every frame, and what sits among them).
    up : (3,) the flower's axis, from the receptacle toward the open flower.
    aspect : the picture's width over its height.

    Notes
    -----
    The flower stands upright (``up`` is the picture's vertical), seen from
    :data:`ELEVATION` degrees above its horizon and :data:`AZIMUTH` degrees round from a
    front fixed by ``up`` alone (the world axis least along it), so every render of the
    same flower has the same view. The distance fits the points' extent across the view
    (and their depth toward the camera) to :data:`FILL` of the picture.
    """
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    helper = np.eye(3)[int(np.argmin(np.abs(up)))]
    side = np.cross(up, helper)
    side /= np.linalg.norm(side)
    front = np.cross(side, up)
    el, az = np.radians(ELEVATION), np.radians(AZIMUTH)
    toward = np.cos(el) * (np.cos(az) * front + np.sin(az) * side) + np.sin(el) * up
    right = np.cross(up, toward)
    right /= np.linalg.norm(right)
    screen_up = np.cross(toward, right)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u, v, w = pts @ right, pts @ screen_up, pts @ toward
    center = (0.5 * (u.min() + u.max()) * right + 0.5 * (v.min() + v.max()) * screen_up
              + 0.5 * (w.min() + w.max()) * toward)
    half_h = max(0.5 * np.ptp(v), 0.5 * np.ptp(u) / aspect, 1e-12)
    tan = np.tan(np.radians(0.5 * VIEW_ANGLE))
    distance = half_h / (tan * FILL) + 0.5 * np.ptp(w)
    position = center + toward * distance
    return (tuple(position), tuple(center), tuple(screen_up))


def flower_up(flower_axis: np.ndarray | None, declared: np.ndarray | None = None,
              rise: np.ndarray | None = None) -> np.ndarray:
    """The picture's up: the flower's axis, pointing toward the open flower.

    ``flower_axis``: (6,) point and direction (nan for a lone petal); ``declared``: the
    up the file or the scene says (glTF's +y, ``scene.up``), or None; ``rise``: the
    petals' mean base-to-tip chord at the start, or None. The axis is turned to agree
    with ``declared`` where it is not across it (within 78 degrees), else with ``rise``.
    Without an axis: ``declared``, else +z.
    """
    d = None if flower_axis is None else np.asarray(flower_axis, dtype=np.float64)[3:]
    if d is None or not np.all(np.isfinite(d)) or not np.any(d):
        return np.array([0.0, 0.0, 1.0]) if declared is None else np.asarray(declared, float)
    d = d / np.linalg.norm(d)
    if declared is not None and abs(float(d @ declared)) > 0.2:
        return d if d @ declared > 0 else -d
    if rise is not None and float(d @ rise) < 0.0:
        return -d
    return d


@dataclass
class Layer:
    """One mesh drawn in every frame of a bloom."""

    faces: np.ndarray  #: (F, 3) int triangles
    points: np.ndarray  #: (T, n, 3) through the frames, or (n, 3) where it stays still
    color: str = "#f4a6c1"  #: its colour where ``rgb`` and ``scalars`` are None
    rgb: np.ndarray | None = None  #: (n, 3) uint8 a colour per point
    scalars: np.ndarray | None = None  #: (n,) the growth map, drawn with a colour bar
    framed: bool = True  #: the camera frames it (a long stem or a leaf is left to run out)

    def at(self, t: int) -> np.ndarray:
        return self.points[t] if self.points.ndim == 3 else self.points


#: colours of the parts that are not petals, by the kind remesh's classifier gives them
PART_COLOURS = {"stem": "#5f8f4a", "leaf": "#6f9e55", "sepal": "#7faa5e",
                "receptacle": "#a9c46c", "stamen": "#e3b341", "pistil": "#cfd86f",
                "other": "#b8b39a"}
#: kinds the camera does not frame (they run out of the picture)
UNFRAMED = ("stem", "leaf")


def _rgb(colour: str) -> np.ndarray:
    return np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=np.uint8)


def asset_layers(frames: list[np.ndarray], asset, bindings: dict, faces: np.ndarray,
                 petal: np.ndarray, *, color: str, palette: str,
                 growth: np.ndarray | None = None, kinds: list[str] | None = None) -> list[Layer]:
    """The user's parts as layers: ``frames[i]`` part i's points (``(T, n, 3)`` for a part
    bound to the sheet, ``(n, 3)`` for one that stays, as :func:`pipeline.io.export.asset_frames`
    gives them); ``bindings`` part -> :class:`pipeline.io.binding.Binding` onto ``faces``.

    A bound part is a petal: ``color``, or with ``palette`` "petals" the colour of the
    sheet petal each point is bound to, or with "growth" ``growth (V,)`` (per sheet
    vertex) at each point's place on the sheet. Another part is coloured by its kind
    (``kinds[i]``, :data:`PART_COLOURS`; a petal kind left unbound takes ``color``), and a
    stem or leaf is not framed; so are the pieces of a petal's part that stay (its points
    bound to no triangle: a leaf or stem modelled with the petals), coloured as a leaf."""
    palette_rgb = np.array([_rgb(c) for c in PETAL_COLOURS])
    faces = np.asarray(faces, dtype=np.int64)
    layers = []
    for i, (part, pts) in enumerate(zip(asset.parts, frames, strict=True)):
        tris = part.triangles()
        if not len(tris):
            continue
        if i in bindings:
            b = bindings[i]
            stays = np.all(b.face[tris] < 0, axis=1)  # a leaf or stem of a petal's part
            if stays.any():  # (but not the hub a petal piece is held at: a petal's colour;
                # pieces by position, as an STL's triangles share no points)
                _, same = np.unique(np.asarray(part.points), axis=0, return_inverse=True)
                same = same.reshape(-1)
                piece = topology.components(same[tris], int(same.max()) + 1)[same[tris[:, 0]]]
                moves = np.bincount(piece, weights=~stays, minlength=piece.max() + 1) > 0
                stays &= ~moves[piece]
            if stays.any():
                layers.append(Layer(tris[stays], np.asarray(pts, dtype=np.float64),
                                    color=PART_COLOURS["leaf"], framed=False))
                tris = tris[~stays]
            layer = Layer(tris, np.asarray(pts, dtype=np.float64), color=color)
            if palette == "petals":
                layer.rgb = palette_rgb[np.asarray(petal)[faces[b.face, 0]] % len(palette_rgb)]
            elif palette == "growth" and growth is not None:
                layer.scalars = np.einsum("ij,ij->i", b.bary, np.asarray(growth)[faces[b.face]])
            layers.append(layer)
            continue
        kind = kinds[i] if kinds is not None else "other"
        if "petal" in kind:
            shade, framed = color, True
        else:
            shade, framed = PART_COLOURS.get(kind, PART_COLOURS["other"]), kind not in UNFRAMED
        layers.append(Layer(tris, np.asarray(pts, dtype=np.float64), color=shade, framed=framed))
    return layers


def sheet_layer(positions: np.ndarray, faces: np.ndarray, petal: np.ndarray | None, *,
                color: str, palette: str, growth: np.ndarray | None = None) -> Layer:
    """The simulated sheet ``positions (T, V, 3)`` as one layer, coloured as
    :func:`asset_layers` colours a petal."""
    layer = Layer(np.asarray(faces, dtype=np.int64), np.asarray(positions, dtype=np.float64),
                  color=color)
    if palette == "petals" and petal is not None:
        palette_rgb = np.array([_rgb(c) for c in PETAL_COLOURS])
        layer.rgb = palette_rgb[np.asarray(petal) % len(palette_rgb)]
    elif palette == "growth" and growth is not None:
        layer.scalars = np.asarray(growth, dtype=np.float64)
    return layer


#: the light rig, camera lights so that they turn with the turntable and whatever faces the
#: camera is lit: (intensity, elevation, azimuth) of a key light above and to the left, a
#: fill low on the right, and a headlight
LIGHTS = ((0.8, 40.0, -35.0), (0.35, -25.0, 55.0), (0.35, 0.0, 0.0))
#: the surface's response: enough ambient that a petal turned away from every light is
#: still a petal, not a black shape
LOOK = dict(smooth_shading=True, specular=0.15, specular_power=20.0, diffuse=0.75, ambient=0.3,
            show_edges=False)


def new_plotter(width: int, height: int):
    """An off-screen plotter with :data:`LIGHTS` and two-sided lighting: the back of a
    face is lit as its front (its normal turned toward the camera)."""
    pv = _pv()
    p = pv.Plotter(off_screen=True, window_size=(width, height), lighting="none")
    for intensity, elevation, azimuth in LIGHTS:
        light = pv.Light(light_type="camera light", intensity=intensity)
        el, az = np.radians(elevation), np.radians(azimuth)
        light.position = (np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el))
        light.focal_point = (0.0, 0.0, 0.0)
        p.add_light(light)
    p.renderer.SetTwoSidedLighting(True)
    p.set_background("white", top="#dfe6ee")
    p.enable_anti_aliasing("ssaa")
    return p


#: the "petals" palette: soft blossom colours, one per petal (repeating)
PETAL_COLOURS = ("#f4a6c1", "#e97fa5", "#f7c6d9", "#d8668f", "#fbd3e0", "#c9577f")


def render_frames(layers: list[Layer], out_dir: Path, *, width: int, height: int, fps: int,
                  contact_frames: int, up: np.ndarray | None = None,
                  labels: list[str] | None = None, turntable_frames: int = 0,
                  progress=None) -> list[Path]:
    """Render every frame of ``layers`` (:class:`Layer`; the first's frame count is the
    sequence's) to ``out_dir/frames/NNNN.png``, then ``out_dir/bloom.mp4``,
    ``out_dir/contact_sheet.png`` and, with ``turntable_frames``, ``out_dir/turntable.mp4``
    (one turn around the last frame, about ``up``). One camera for all
    (:func:`flower_camera`, ``up`` the flower's; default +z). Returns the frame paths."""
    import imageio.v2 as imageio

    pv = _pv()
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, dtype=np.float64)
    count = max((layer.points.shape[0] for layer in layers if layer.points.ndim == 3), default=1)
    plotter = new_plotter(width, height)
    meshes = []
    scalars = [layer.scalars for layer in layers if layer.scalars is not None]
    clim = (min(map(np.min, scalars)), max(map(np.max, scalars))) if scalars else None
    bar = True
    for layer in layers:
        mesh = _polydata(pv, layer.at(0), layer.faces)
        if layer.scalars is not None:
            mesh.point_data["growth"] = np.asarray(layer.scalars, dtype=np.float64)
            plotter.add_mesh(mesh, scalars="growth", cmap="RdPu", clim=clim, show_scalar_bar=bar,
                             scalar_bar_args={"title": "growth ratio", "color": "#333333"},
                             **LOOK)
            bar = False
        elif layer.rgb is not None:
            mesh.point_data["colour"] = np.asarray(layer.rgb, dtype=np.uint8)
            plotter.add_mesh(mesh, scalars="colour", rgb=True, **LOOK)
        else:
            plotter.add_mesh(mesh, color=layer.color, **LOOK)
        meshes.append(mesh)
    framed = [layer.points.reshape(-1, 3) for layer in layers if layer.framed] or \
        [layer.points.reshape(-1, 3) for layer in layers]
    plotter.camera_position = flower_camera(np.concatenate(framed), up, width / height)
    plotter.camera.view_angle = VIEW_ANGLE
    text = plotter.add_text("", position="lower_left", font_size=10, color="#333333")
    images, paths = [], []
    for k in range(count):
        for layer, mesh in zip(layers, meshes, strict=True):
            if layer.points.ndim == 3 and k:
                # pyvista's smooth-shading filter recomputes the normals from the new
                # points; normals of our own on the mesh went stale behind it (a petal
                # turned over kept its first frame's normals: a black underside)
                mesh.points = layer.at(k)
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
        plotter.camera.SetViewUp(*up)  # so that Azimuth turns about the flower's axis
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
