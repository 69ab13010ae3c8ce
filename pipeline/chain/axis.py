"""The axis stage: each petal's base, tip, center plane and cross-section coordinates
(:func:`pipeline.flower.axis.find_axes`) -> axis.h5."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline import artifact
from pipeline.chain import carried_attrs
from pipeline.config import Config
from pipeline.directions import DIRECTIONS
from pipeline.errors import BloomError
from pipeline.flower.axis import BASE_REACH, BadPetal, WeakBase, check_axes, find_axes
from pipeline.flower.stagger import flower_count
from pipeline.io import binding
from pipeline.progress import Steps

log = logging.getLogger("bloom")
#: petals named in a line of many (the rest counted)
SHOWN = 12

#: what the later stages need of remesh.h5, carried forward
CARRIED = ("mesh/vertices", "mesh/faces", "mesh/petal", "mesh/left", "mesh/part_names",
           "mesh/part", "mesh/thickness",
           "mesh/flower", "flower/petal_flower", "flower/centre", "input/asset", "bind")
#: more petals than this: one summary line instead of a line per petal
LINES = 50


def axis_options(get) -> dict:
    """The scene's choices :func:`~pipeline.flower.axis.find_axes` is run with, from its
    keys (``get(dotted key)``): the shell (simulate.model = shell) runs on s and x along
    the surface and holds a band (the same region at any resolution); the paper's springs
    on distances along edges and the rim."""
    shell = get("simulate.model") == "shell"
    region = get("axis.base_region")
    if region == "auto":
        region = "band" if shell else "rim"
    fraction = get("axis.base_band") if region == "band" else get("axis.base_fraction")
    return {"base_mode": get("axis.base"), "base_fraction": fraction, "base_region": region,
            "surface": shell, "flower_axis": get("axis.flower_axis")}


def run(remesh_h5: str | Path, out: str | Path, cfg: Config, *, overwrite: bool = False) -> None:
    """Find each petal's base, tip, center plane and cross-section coordinates, and each
    flower's axis from its own petals (``flower/axis``, (K, 6))."""
    out = artifact.check_output(out, "axis", overwrite)
    with artifact.Artifact(remesh_h5, needs="remesh", reader="axis") as src:
        v, f, petal = src["mesh/vertices"], src["mesh/faces"], src["mesh/petal"]
        # the scene's up: the key, else the file's own (remesh records it; "" if the format
        # has none), else +z
        up = cfg["scene.up"]
        if up == "auto":
            up = str(src.attrs.get("file_up", "")) or "+z"
            if up not in DIRECTIONS:
                raise BloomError(f"file_up: {up!r} is not one of {', '.join(DIRECTIONS)}; set "
                                 "scene.up", where=remesh_h5)
        # each petal's flower (remesh.h5 of before the flowers were found: one flower)
        flower = src["flower/petal_flower"] if "flower/petal_flower" in src else None
        try:
            with Steps("axis", str(remesh_h5)) as progress:
                axes = find_axes(v, f, petal, **axis_options(cfg.__getitem__),
                                 planes=src["mesh/plane"] if "mesh/plane" in src else None,
                                 up=np.array(DIRECTIONS[up]),
                                 flower=flower, progress=progress,
                                 hold_bad=flower_count(src) > 1,
                                 held_rim=src["mesh/cut_rim"] if "mesh/cut_rim" in src else None)
            check_axes(axes, petal)  # no NaN, x in [-1, 1], s in [0, 1], a base and a tip
        except BadPetal as exc:
            part = _part_name(src, petal, exc.petal)
            fix = f" (the key to change: {exc.key})" if exc.key else ""
            if exc.key == "scene.exclude" and part:
                fix = f" (the key to change: scene.exclude, e.g. scene.exclude = [\"{part}\"])"
            label = f"petal {exc.petal} ({part})" if part else f"petal {exc.petal}"
            raise BloomError(f"{label}: {exc.reason}{fix}", where=remesh_h5) from None
        except WeakBase as exc:  # held on a line, the petal has no equilibrium to find
            raise BloomError(f"axis.base_fraction: {exc}; remedy: an axis.base_fraction above "
                             f"{BASE_REACH:g} (the widening's reach; now "
                             f"{cfg['axis.base_fraction']:g}), another axis.base end, or a mesh "
                             "whose petal base is not a straight row", where=remesh_h5) from None
        if len(axes.widened):  # (one line: a branch of blossoms can have hundreds)
            held = np.bincount(petal[axes.base], minlength=int(petal.max()) + 1)
            shown = ", ".join(f"{p} ({held[p]})" for p in list(axes.widened)[:SHOWN])
            more = len(axes.widened) - SHOWN
            log.warning("%d petal(s) had their base on a line (they could spin about it): "
                        "widened to the fixed vertices in brackets: petal(s) %s%s",
                        len(axes.widened), shown, f" and {more} more" if more > 0 else "")
        if axes.held:  # (one line: a branch of blossoms can have many)
            named = "; ".join(f"petal {p} ({_part_name(src, petal, p) or 'no part'}): {why}"
                              for p, why in list(axes.held)[:SHOWN])
            more = len(axes.held) - SHOWN
            log.warning("%d petal(s) have no sound axis and are held as modelled (every "
                        "vertex fixed; the other flowers bloom; scene.exclude leaves a part "
                        "out): %s%s", len(axes.held), named,
                        f"; and {more} more" if more > 0 else "")
        _log_axes(axes, petal, flower)
        bindings = binding.read_bindings(src)
        if bindings:  # (the hub of a flower modelled as one solid stays with the hub)
            held = binding.hold_hub(bindings, v, f, petal, axes.base,
                                    src["mesh/thickness"] if "mesh/thickness" in src else None)
            for i, n in held.items():
                log.info("part %s: %d point(s) behind its petals' bases, off the sheet's rim, "
                         "held with the hub (they stay where they are)",
                         _asset_part_name(src, i), n)
        attrs = {**carried_attrs(src), "flower_axis": axes.flower_axis, "up": up,
                 "flower_count": len(axes.flower_axes)}
        if axes.held:
            attrs["held_petals"] = np.asarray([p for p, _ in axes.held], dtype=np.int64)
        with artifact.writing(out, stage="axis", config_json=cfg.to_json(),
                              inputs=artifact.input_hashes(cfg, remesh_h5), attrs=attrs, previous=src) as h5:
            src.copy_to(h5, [name for name in CARRIED if name != binding.BIND_GROUP])
            if bindings:
                binding.write_bindings(h5, bindings)
            artifact.put(h5, "axis/base", axes.base, "(V,) fixed base vertices")
            artifact.put(h5, "axis/on_axis", axes.on_axis, "(V,) vertices on the petal axis")
            artifact.put(h5, "axis/tip", axes.tip.astype(np.int64), "(P,) tip vertex per petal")
            artifact.put(h5, "axis/plane", axes.plane, "(P, 4) center plane: unit normal, offset")
            artifact.put(h5, "axis/x", axes.x, "(V,) cross-section coordinate in [-1, 1]")
            artifact.put(h5, "axis/s", axes.s, "(V,) distance from the base, 0 at base, 1 at tip")
            artifact.put(h5, "flower/axis", axes.flower_axes,
                         "(K, 6) each flower's axis: a point, then the unit direction from the "
                         "receptacle toward the tips (nan: a lone petal's flower)")
    log.info("wrote %s", out)


def _log_axes(axes, petal: np.ndarray, flower) -> None:
    """A line per petal (a summary line when there are more than :data:`LINES`) and per
    flower."""
    count = len(axes.tip)
    held = np.bincount(petal[axes.base], minlength=count)
    on = np.bincount(petal[axes.on_axis], minlength=count)
    if count <= LINES:
        for p in range(count):
            mine = petal == p
            log.info("petal %d: %d base vertices, %d on the axis, tip %d, x in [%.3f, %.3f]",
                     p, int(held[p]), int(on[p]), int(axes.tip[p]), axes.x[mine].min(),
                     axes.x[mine].max())
    else:
        log.info("%d petals: %d to %d base vertices, %d to %d on the axis", count,
                 int(held.min()), int(held.max()), int(on.min()), int(on.max()))
    for k, line in enumerate(axes.flower_axes):
        n = int(np.sum(np.asarray(flower) == k)) if flower is not None else count
        if len(axes.flower_axes) <= LINES or not np.all(np.isfinite(line)):
            log.info("flower %d (%d petal(s)): axis %s", k, n,
                     "not found (a lone petal)" if not np.all(np.isfinite(line)) else
                     f"through {np.round(line[:3], 3).tolist()} along "
                     f"{np.round(line[3:], 3).tolist()}")


def _asset_part_name(src, i: int) -> str:
    """Input part ``i``'s name, quoted (``input/asset/names``), or its number."""
    if "input/asset/names" in src:
        name = src["input/asset/names"][i]
        return repr(name.decode() if isinstance(name, bytes) else str(name))
    return str(i)


def _part_name(src, petal, p: int) -> str:
    """The input part petal ``p`` came from (``mesh/part_names``, ``mesh/part``), or ""."""
    if "mesh/part_names" not in src or "mesh/part" not in src:
        return ""
    names, part = src["mesh/part_names"], src["mesh/part"]
    mine = np.flatnonzero(np.asarray(petal) == p)
    if not len(mine):
        return ""
    name = names[int(part[mine[0]])]
    return name.decode() if isinstance(name, bytes) else str(name)
