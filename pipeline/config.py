"""Scene configuration: a TOML file checked against a schema when loaded.

Every key is declared once in ``SCHEMA`` with its type, default, allowed range and a
one-line description (``bloom config --help-keys`` prints them). An unknown key, a
wrong type or a value out of range is a :class:`BloomError` naming the file and the key.
``--set section.key=value`` overrides go through the same checks.

The module is long because the schema is: one entry per key, the contract users' scene
files rely on, kept in one table so the guide's key table is generated from it.
"""

from __future__ import annotations

import difflib
import json
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.directions import DIRECTIONS, parse_direction
from pipeline.errors import BloomError
from pipeline.expr import check_curve


@dataclass(frozen=True)
class Key:
    """One config key: its type, default and allowed values."""

    kind: type  #: bool, int, float, str, or list (a list of strings)
    default: Any
    doc: str
    choices: tuple = ()
    low: float | None = None  # inclusive unless low_open
    high: float | None = None  # inclusive unless high_open
    low_open: bool = False
    high_open: bool = False
    check: Callable[[Any], None] | None = None  # raises ValueError with a reason
    items: type = str  #: a list's items: str, or list (pairs of numbers)
    auto: bool = False  #: the string "auto" is also a value (decided from the model)
    whole_numbers: bool = False  #: a str key that also takes a whole number (as its digits)


def _check_color(value: str) -> None:
    from matplotlib.colors import is_color_like

    if not is_color_like(value):
        raise ValueError(f"{value!r} is not a colour name or #rrggbb")


def _check_keys(value: list) -> None:
    """growth.keys: [[frame, A], ...], frames increasing, A in [0, 1] and never falling."""
    for k, item in enumerate(value):
        if (not isinstance(item, list) or len(item) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                           and math.isfinite(x) for x in item)):
            raise ValueError(f"key {k} is {item!r}; each key is [frame, A], two numbers")
        if item[0] < 0:
            raise ValueError(f"key {k}: frame {item[0]} is before frame 0")
        if not 0.0 <= item[1] <= 1.0:
            raise ValueError(f"key {k}: A = {item[1]} is outside [0, 1]")
        if k and item[0] <= value[k - 1][0]:
            raise ValueError(f"key {k}: frame {item[0]} does not come after frame "
                             f"{value[k - 1][0]} (frames must increase)")
        if k and item[1] < value[k - 1][1]:
            raise ValueError(f"key {k}: A falls from {value[k - 1][1]} to {item[1]} (growth "
                             "only increases)")


def _check_direction(value: str) -> None:
    parse_direction(value)


SCHEDULES = ("linear", "smoothstep", "smootherstep")
INTEGRATORS = ("semi-implicit", "explicit-damping", "quasi-static")

SCHEMA: dict[str, Any] = {
    "scene": {
        "name": Key(str, "", "scene name (default: the config file's name)"),
        "mesh": Key(str, "", "input mesh (OBJ/PLY/STL/OFF/GLB), relative to the config file "
                     "(given by --set: to the working folder)"),
        "description": Key(str, "", "free text, shown by `bloom inspect`"),
        "petals": Key(list, [], "glob patterns over the mesh's part names (e.g. [\"Circle.0*\"]): a "
                      "matching part is a petal whatever its shape says"),
        "exclude": Key(list, [], "glob patterns over part names: a matching part is never a petal "
                       "(wins over scene.petals)"),
        "flower": Key(str, "all", "which flower of a file of many (a bush, a bed, a branch) to "
                      "simulate: all, a flower's index (0, 1, ...: in the order of their first "
                      "petals, as the remesh log lists them) or a glob over part names (the one "
                      "flower whose petals those parts hold)", whole_numbers=True),
        "stagger": Key(int, "auto", "a file of many flowers: the spread of their start frames "
                       "(each flower holds its bud, then blooms as the run does, then holds; "
                       "the render and the export run that many frames longer). Staggered "
                       "flowers bloom as problems apart (contact among each flower's own "
                       "petals; flowers that would pass through each other bloom together, "
                       "and start together); 0: all together, one problem, contact between "
                       "flowers too. "
                       "auto: a quarter of simulate.frames for a file of many flowers",
                       low=0, auto=True),
        "stagger_seed": Key(int, 0, "seed of the flowers' start frames within scene.stagger "
                            "(the same seed, the same starts)", low=0),
        "up": Key(str, "auto", "the scene's up direction (+x ... -z): orients the flower's axis "
                  "where its petals do not (a flat open flower); recorded in the artifacts. auto: "
                  "the file's own (glTF: +y), else +z", choices=("auto", *DIRECTIONS)),
    },
    "remesh": {
        "target_edge": Key(float, 0.0, "target edge length in the input's units; 0 keeps the "
                           "input's triangles (the mesh is scaled to mean edge 1 either way)",
                           low=0.0),
        "petal_vertices": Key(int, 0, "remesh each petal to about this many vertices (the edge "
                              "length follows from the petal's area); 0: use target_edge "
                              "(with neither set, a petal under 100 vertices is remeshed "
                              "to about 100, and one over remesh.max_petal_vertices to "
                              "about that many)",
                              low=0),
        "max_petal_vertices": Key(int, 1500, "with remesh.target_edge and petal_vertices "
                                  "unset, a petal of more vertices than this is remeshed to "
                                  "about this many: the shell's bloom converges from about "
                                  "200 a petal, so a denser one costs time, not shape (the "
                                  "user's mesh keeps its detail through the binding); 0: "
                                  "no ceiling", low=0),
        "symmetrize": Key(bool, True, "make each petal mirror-symmetric about its center plane"),
        "workers": Key(int, 0, "processes that remesh petals side by side (8 petals or more); "
                       "0: the CPUs this process may use, at most 4; 1: none. The result is the "
                       "same bit for bit", low=0),
        "closed_parts": Key(str, "refuse", "closed surfaces in the input (a thick petal, a "
                            "receptacle, a stem): refuse the mesh, or drop them and say so",
                            choices=("refuse", "drop")),
        "separate": Key(bool, True, "move petal sheets that pass through or touch each other "
                        "apart before anything else (each pair to the side most of its overlap "
                        "is on, at least effects.collisions.thickness apart, every vertex by at "
                        "most 15% of its petal's length; the log and remesh.h5's separation "
                        "attribute say how far; petals buried in each other toward the "
                        "centre have the buried parts cut from the sheet, where that parts "
                        "every petal of the flower within 40% of each petal's area, the shares "
                        "in the log and in the attribute's cut; a pair still too far into each "
                        "other is left as modelled, named, with no contact between the two); "
                        "false keeps them as the input has them"),
    },
    "axis": {
        "base": Key(str, "auto", "which end of a petal is its base: auto (nearest the flower's "
                    "axis, or the narrow end of a lone petal), narrow, wide, or the end lying "
                    "towards a direction of the input (+x, -x, +y, -y, +z, -z)",
                    choices=("auto", "narrow", "wide", *DIRECTIONS)),
        "base_fraction": Key(float, 0.04, "boundary vertices this close to the base end, as a "
                             "fraction of the petal's length, are fixed", low=0.0, high=0.5,
                             low_open=True),
        "base_region": Key(str, "auto", "which vertices near the base end are fixed: rim "
                           "(the boundary vertices within axis.base_fraction, the paper's), band "
                           "(every vertex within axis.base_band), edge (the base edge: the rim "
                           "between the base corners; the shell clamps it: the same boundary "
                           "condition at any mesh resolution, but a short base edge resolved by few "
                           "vertices holds the petal's twist unevenly) or auto (band with "
                           "simulate.model = shell, else rim)", choices=("auto", "rim", "band", "edge")),
        "base_band": Key(float, 0.08, "base_region = band: the clamped band's extent from the "
                         "base end, as a fraction of the petal's length; keep it wider than an "
                         "edge of the coarsest mesh (5% of the length at 300 vertices)",
                         low=0.0, high=0.5, low_open=True),
        "flower_axis": Key(str, "auto", "direction of the flower's axis, from the receptacle "
                           "toward the tips: auto (where the petals' center planes meet), +x, -x, "
                           "+y, -y, +z, -z, or a vector \"x,y,z\"; given, it passes through the "
                           "point closest to the center planes, and a lone petal's base is its "
                           "end lowest along it", check=_check_direction),
    },
    "growth": {
        "curve": Key(str, "0.2*x**2", "growth ratio alpha as an expression of the cross-section "
                     "coordinate x in [-1, 1] (Eq. 6); parsed safely, never eval'd",
                     check=check_curve),
        "schedule": Key(str, "smootherstep", "shape of A(t) from 0 to 1: linear, smoothstep (C1) "
                        "or smootherstep (C2)", choices=SCHEDULES),
        "ramp": Key(float, 0.6, "fraction of the simulated time over which A(t) rises from 0 "
                    "to 1; the rest is a hold at full growth", low=0.0, high=1.0, low_open=True),
        "keys": Key(list, [], "A keyed in frames, [[frame, A], ...] (frame 0 is the first stored "
                    "frame, simulate.frames - 1 the last): a monotone smooth curve (PCHIP) "
                    "through the keys, held before the first and after the last; e.g. [[0, 0], "
                    "[24, 0], [72, 1]] holds the bud 24 frames, opens over 48 and holds. "
                    "Replaces growth.schedule and growth.ramp when given", check=_check_keys,
                    items=list),
        "start": Key(str, "auto", "what the input mesh is: bud (the paper: it blooms from the "
                     "mesh), open (the mesh is the open flower: Bloom finds the bud it grew "
                     "from by running growth backward, and the bloom ends on the mesh), or "
                     "auto: decided from the model (a flower whose petals lean over 30 deg "
                     "from its axis with their tips turned outward, or whose petals roll "
                     "back (over half its curvature away from its inside), or a lone petal "
                     "that turns under 45 deg, is open), "
                     "logged and recorded as growth_start in sim.h5",
                     choices=("auto", "bud", "open")),
        "close": Key(float, 1.0, "growth.start = open: how far to close, a scale on the "
                     "growth ratios of the backward path (0: the bud is the model; 1: the "
                     "growth curve undone in full); left unset, a bud under 20 deg more "
                     "closed than the model is searched again closing twice as far (up to "
                     "4)", low=0.0),
        "recurve": Key(bool, True, "growth.start = open, the shell: the model's curvature "
                       "away from the flower's inside (tips and rims rolled back, a lily's "
                       "recurved petals) grows in over the bloom, so the bud Bloom finds is "
                       "not rolled back; false keeps it in the bud's rest state (the bud "
                       "is then the model's curl with its growth undone)"),
        "cup": Key(float, 1.5, "growth.start = open, the shell: the bud's curvature toward "
                   "the flower's inside, in 1 / the petal size (the square root of its area), "
                   "that the model has not: it picks the side each petal closes to (a flat "
                   "petal whose rims' growth is undone could cup either way) and fades out over "
                   "the bloom; 0: none", low=0.0),
    },
    "simulate": {
        "steps": Key(int, 200_000, "number of time steps", low=1),
        "frames": Key(int, 121, "number of frames stored, the first at t = 0", low=2),
        "h": Key(float, 1.0, "time step (paper: 1.0)", low=0.0, low_open=True),
        "workers": Key(int, 0, "processes that bloom a file's flowers side by side (a bush, a "
                       "branch: each flower a problem of its own); 0: the CPUs this process may "
                       "use, at most 4; 1: none. The result is the same bit for bit", low=0),
        "eta": Key(float, 0.1, "damping factor of the semi-implicit scheme (Eq. 8): 1/2 is "
                   "Verlet, smaller damps", low=0.0, high=0.5),
        "integrator": Key(str, "quasi-static", "quasi-static (the path of equilibria along "
                          "the growth, by Newton's method; contact and connection springs "
                          "included), semi-implicit (Eq. 7-8, the paper's scheme) or "
                          "explicit-damping (Eq. 9, for comparison)", choices=INTEGRATORS),
        "substeps": Key(int, 0, "dynamic integrators: kernel steps per step of h; 0 chooses them "
                        "per frame from the model's stable time step (and halves the substep "
                        "after a divergence); N > 0 takes exactly N (1: the paper's scheme as "
                        "printed)", low=0),
        "stages": Key(int, 20, "quasi-static: growth increments over the ramp (at least; "
                      "each is halved where Newton fails)", low=1),
        "inertia": Key(bool, False, "quasi-static: add the inertia term (each growth "
                       "increment, at least one per frame, is an implicit Euler step of the "
                       "dynamics in incremental-potential form), so that a motion such as the "
                       "snap after connection springs break plays out over frames and comes "
                       "to rest; off: the path of equilibria, its limit"),
        "tolerance": Key(float, 1e-6, "quasi-static: converged when a Newton step moves no "
                         "vertex further than this (mesh units)", low=0.0, low_open=True),
        "damping": Key(float, 0.9999, "velocity factor d of the explicit-damping integrator "
                       "(Eq. 9)", low=0.0, high=1.0),
        "model": Key(str, "shell", "elasticity: shell (a thin shell whose energy is a property "
                     "of the surface: the same flower blooms the same at any mesh density) or "
                     "paper (the paper's springs and hinges, one K_s per edge and one K_b per "
                     "hinge: the bloom depends on the triangulation)",
                     choices=("paper", "shell")),
        "stretch_modulus": Key(float, 27.3, "shell: Young's modulus times thickness, energy per "
                               "area with area in units of the petal size (sqrt of the mean "
                               "petal area); 27.3 is the paper's K_s = 0.1 on the default petal "
                               "(317 vertices)", low=0.0, low_open=True),
        "thickness": Key(float, 0.025, "shell: thickness over the petal size (sqrt of the mean "
                         "petal area); sets bending (~t^3) against stretching (~t). At 0.025 a bud "
                         "blooms alike (within about 1 deg) from about 200 vertices per petal; "
                         "thinner sheets wrinkle and buckle finer (0.013 is the paper's K_b = "
                         "0.0005 on the default petal) and need finer meshes. A thick petal's "
                         "own thickness (mesh/thickness) wins where it is known", low=0.0,
                         high=0.5, low_open=True),
        "imperfection": Key(float, 1e-4, "shell, quasi-static: the bud's imperfection, given "
                            "at the first growth (frame 0 and a keyed hold are the bud as "
                            "given): a sideways offset along each petal's center-plane normal "
                            "of this fraction of the petal size at the tip (s^2 from the "
                            "base): where a symmetric petal "
                            "must lean or twist one way, it chooses the same way at any mesh "
                            "resolution (0: none; the solver then nudges at random)", low=0.0),
        "petal_vertices": Key(int, 500, "shell: solve each petal on at least about this many "
                              "vertices: a coarser mesh is cut finer for the solve (each "
                              "triangle in four, the new vertices on the smooth surface "
                              "through the old, the axes and growth found again on it), and "
                              "its frames are those of its own vertices, contact keeping its "
                              "own triangles apart; a bud of 50 vertices per petal then "
                              "blooms within about 1-1.6 deg of one of 800, a lone petal of "
                              "300 within 0.6 deg of one of 4,800; where that solve stops "
                              "part way, the mesh as it is (quasi-static only; 0: the mesh "
                              "as it is)", low=0),
        "max_vertices": Key(int, 6000, "shell: a mesh is cut finer for the solve "
                            "(simulate.petal_vertices) only while the solve keeps to this many "
                            "vertices (each flower of a file of many its own, within "
                            "simulate.file_vertices)", low=0),
        "file_vertices": Key(int, 60000, "shell, a file of many flowers: the flowers that are "
                             "not copies share this many vertices for their solves cut finer "
                             "(simulate.petal_vertices): each keeps to its share or to "
                             "simulate.max_vertices, the fewer (a branch of a thousand "
                             "blossoms: 60 each, solved as meshed; 0: no limit but "
                             "simulate.max_vertices)", low=0),
        "poisson": Key(float, 1.0 / 3.0, "shell: Poisson's ratio (1/3: the paper's lattice of "
                       "springs)", low=0.0, high=0.5, high_open=True),
        "stretch_stiffness": Key(float, 0.1, "paper model: K_s, per edge (paper: 0.1); with the "
                                "shell, set alone, it scales stretch_modulus by K_s / 0.1",
                                low=0.0, low_open=True),
        "bending_stiffness": Key(float, 0.0005, "paper model: K_b, per interior edge (paper: "
                                "0.0005); with the shell, set alone, it scales the bending "
                                "stiffness by K_b / 0.0005 (the thickness by its square root)",
                                low=0.0),
        "mass": Key(float, 1.0, "mass of every vertex (paper: 1)", low=0.0, low_open=True),
        "checkpoint_seconds": Key(float, 20.0, "a running simulation writes a checkpoint at "
                                  "most this often (wall seconds; 0: never); `bloom simulate "
                                  "--resume` continues from it", low=0.0),
        "speed_limit": Key(float, 1.0, "divergence guard: a vertex faster than this (mesh "
                           "units per unit time) stops the run as diverged", low=0.0,
                           low_open=True),
    },
    "effects": {
        "curl": {
            "enabled": Key(bool, False, "out-of-plane curl: rest dihedral angles decay (Eq. 11)"),
            "beta": Key(float, 0.5, "curl growth beta in [0, 1]", low=0.0, high=1.0),
        },
        "wrinkles": {
            "enabled": Key(bool, False, "extra growth on boundary edges (Eq. 12)"),
            "alpha_add": Key(float, 0.1, "additional growth ratio of boundary edges", low=0.0),
            "boundary_stiffness": Key(float, 0.5, "factor on boundary edges' stretch stiffness",
                                      low=0.0, high=1.0, low_open=True),
        },
        "collisions": {
            "enabled": Key(bool, "auto", "petals kept from passing through each other: quasi-static, "
                           "a contact barrier with continuous collision detection (no "
                           "crossing); dynamic integrators, the paper's push-back. auto: on "
                           "where two petals can meet (their boxes, grown by half a petal "
                           "length, overlap), off for a lone petal", auto=True),
            "thickness": Key(float, 0.01, "quasi-static: the gap the contact barrier keeps "
                             "between petals (mesh units, mean edge 1); the barrier acts from "
                             "twice this distance on", low=0.0, high=0.25, low_open=True),
            "gap": Key(float, 0.002, "simulate.model = shell: the gap the contact barrier "
                       "keeps between petals, as a fraction of the petal size (sqrt of the mean "
                       "petal area; it replaces thickness, whose mesh units shrink as the mesh "
                       "is refined); 0.002 is 0.03 mean edges on the default petal, a fifth of "
                       "a real petal's thickness (a barrier of far less reach than an edge "
                       "catches on the facets it slides over: the opening jumps 0.4 deg from "
                       "frame to frame where petals press)",
                       low=0.0, high=0.02, low_open=True),
            "offset": Key(float, 0.001, "a vertex that went through a petal is put back this far "
                          "on its side (mesh units; keep it below a step's motion, or the "
                          "push-back pumps energy in)", low=0.0, low_open=True),
        },
        "connections": {
            "enabled": Key(bool, False, "springs between petals that break past a stretch"),
            "critical_stretch": Key(float, 1.5, "a connection breaks when its length exceeds "
                                    "this factor times its rest length (at least one mean "
                                    "edge)", low=1.0, low_open=True),
            "stiffness": Key(float, 0.1, "spring constant of a connection", low=0.0,
                             low_open=True),
            "max_distance": Key(float, 2.0, "a petal's rim vertex is connected to the nearest "
                                "vertex of an inner petal within this distance (mesh units)",
                                low=0.0, low_open=True),
            "min_s": Key(float, 0.3, "only rim vertices farther than this (s, 0 at the base, 1 "
                         "at the tip) are connected", low=0.0, high=1.0),
        },
        "center_plane": {
            "enabled": Key(bool, False, "axis vertices keep their distance to the center plane"),
        },
    },
    "export": {
        "mesh": Key(str, "input", "what the export gives back: input (the user's own parts, "
                    "names, polygons, UVs, normals and materials, the petals deformed by the "
                    "simulated sheet through their binding, the other parts in place) or "
                    "sheet (the simulated sheet, one mesh per petal)", choices=("input", "sheet")),
        "keep_thickness": Key(bool, True, "a thick petal's two sides are kept as far apart as "
                              "in the input in every frame (where its flat faces would cut "
                              "chords across a bend); false: the binding alone, as Blender's "
                              "Surface Deform"),
        "meters_per_unit": Key(float, 1.0, "USD metersPerUnit: how many meters one unit of the "
                               "input mesh is (Blender, Houdini scale by it), where the input "
                               "file does not say (glTF: metres; a Maya OBJ's unit comment)", low=0.0,
                               low_open=True),
    },
    "render": {
        "width": Key(int, 800, "frame width in pixels (even)", low=64, high=8192),
        "height": Key(int, 600, "frame height in pixels (even)", low=64, high=8192),
        "fps": Key(int, 24, "frame rate of the MP4", low=1, high=240),
        "color": Key(str, "#f4a6c1", "petal colour (a name or #rrggbb)", check=_check_color),
        "contact_frames": Key(int, 8, "frames on the contact sheet", low=1, high=64),
        "palette": Key(str, "color", "petal colours: color (render.color everywhere), petals "
                       "(one colour per petal) or growth (the growth map, alpha of Eq. 6)",
                       choices=("color", "petals", "growth")),
        "turntable_frames": Key(int, 72, "frames of turntable.mp4, one turn around the final "
                                "bloom (0: none)", low=0, high=1440),
    },
}


def _flatten(schema: dict, prefix: str = "") -> dict[str, Key]:
    out = {}
    for name, item in schema.items():
        dotted = f"{prefix}{name}"
        if isinstance(item, Key):
            out[dotted] = item
        else:
            out.update(_flatten(item, dotted + "."))
    return out


KEYS: dict[str, Key] = _flatten(SCHEMA)


def _type_name(kind: type) -> str:
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string",
            list: "a list of strings"}[kind]


def _coerce(dotted: str, key: Key, value: Any, where: str) -> Any:
    """Check one value against its key; return it in the key's type."""
    ok = False
    if key.auto and value == "auto":
        return value
    if key.kind is bool:
        ok = isinstance(value, bool)
    elif key.kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif key.kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if ok:
            value = float(value)
            if not math.isfinite(value):
                raise BloomError(f"{dotted}: must be finite, got {value}", where=where)
    elif key.kind is str:
        if key.whole_numbers and isinstance(value, int) and not isinstance(value, bool):
            value = str(value)
        ok = isinstance(value, str)
    elif key.kind is list:
        ok = isinstance(value, list)
        bad = [item for item in value if not isinstance(item, key.items)] if ok else []
        if bad:
            what = "strings" if key.items is str else "[frame, A] pairs"
            raise BloomError(f"{dotted}: expected a list of {what}, got {bad[0]!r} in it",
                             where=where)
        if ok:
            value = list(value)
    if not ok:
        kind = "a list of [frame, A] pairs" if key.items is list else _type_name(key.kind)
        raise BloomError(f"{dotted}: expected {kind}, got {value!r}", where=where)
    if key.choices and value not in key.choices:
        raise BloomError(f"{dotted}: must be one of {', '.join(key.choices)}; got {value!r}",
                         where=where)
    if key.low is not None and (value < key.low or (key.low_open and value == key.low)):
        rel = ">" if key.low_open else ">="
        raise BloomError(f"{dotted}: must be {rel} {key.low:g}, got {value!r}", where=where)
    if key.high is not None and (value > key.high or (key.high_open and value == key.high)):
        rel = "<" if key.high_open else "<="
        raise BloomError(f"{dotted}: must be {rel} {key.high:g}, got {value!r}", where=where)
    if key.check is not None:
        try:
            key.check(value)
        except ValueError as exc:
            raise BloomError(f"{dotted}: {exc}", where=where) from None
    return value


def _walk(table: dict, where: str, prefix: str = ""):
    """Yield (dotted key, value) for every leaf of a parsed TOML table."""
    for name, value in table.items():
        dotted = f"{prefix}{name}"
        if isinstance(value, dict):
            if dotted in KEYS:  # a table where a value belongs
                raise BloomError(f"{dotted}: expected {_type_name(KEYS[dotted].kind)}, got a table",
                                 where=where)
            if not any(k.startswith(dotted + ".") for k in KEYS):
                raise BloomError(f"{dotted}: unknown section", where=where)
            yield from _walk(value, where, dotted + ".")
        else:
            yield dotted, value


def _suggest(dotted: str) -> str:

    close = difflib.get_close_matches(dotted, list(KEYS), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


class Config:
    """A validated scene configuration.

    ``cfg["simulate.h"]`` reads a value by its dotted key; ``cfg.section("simulate")``
    returns the values of one section; ``cfg.to_json()`` is what artifacts record.
    """

    def __init__(self, values: dict[str, Any], path: Path | None, given: frozenset = frozenset()):
        self._values = values
        self.path = path
        self.given = given  #: the keys the file or an override set (the others are defaults)

    def __getitem__(self, dotted: str) -> Any:
        return self._values[dotted]

    def section(self, prefix: str) -> dict[str, Any]:
        n = len(prefix) + 1
        return {k[n:]: v for k, v in self._values.items() if k.startswith(prefix + ".")}

    @property
    def name(self) -> str:
        if self._values["scene.name"]:
            return self._values["scene.name"]
        return self.path.stem if self.path else "scene"

    def mesh_path(self) -> Path | None:
        """``scene.mesh`` resolved against the config file's folder (or the working one)."""
        mesh = self._values["scene.mesh"]
        if not mesh:
            return None
        p = Path(mesh)
        if not p.is_absolute() and self.path is not None:
            p = self.path.parent / p
        return p

    def effects_enabled(self) -> list[str]:
        """The effects the scene turns on (``true``; not those left to ``auto``)."""
        return sorted(k.split(".")[1] for k, v in self._values.items()
                      if k.startswith("effects.") and k.endswith(".enabled") and v is True)

    def effects_auto(self) -> list[str]:
        """The effects the scene leaves to be decided from the model (``auto``)."""
        return sorted(k.split(".")[1] for k, v in self._values.items()
                      if k.startswith("effects.") and k.endswith(".enabled") and v == "auto")

    def nested(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for dotted, value in self._values.items():
            node = out
            *parents, leaf = dotted.split(".")
            for p in parents:
                node = node.setdefault(p, {})
            node[leaf] = value
        return out

    def to_json(self) -> str:
        return json.dumps(self.nested(), sort_keys=True)


def dotted_keys(nested: dict, prefix: str = "") -> dict[str, Any]:
    """A config's nested sections (:meth:`Config.nested`, an artifact's recorded config)
    as one level of dotted keys, unchecked."""
    out: dict[str, Any] = {}
    for key, value in nested.items():
        if isinstance(value, dict):
            out.update(dotted_keys(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def parse_override(text: str) -> tuple[str, Any]:
    """Split ``section.key=value``; the value is read as a TOML value, else as a string."""
    if "=" not in text:
        raise BloomError(f"--set {text!r}: expected section.key=value")
    dotted, raw = (part.strip() for part in text.split("=", 1))
    if dotted not in KEYS:
        raise BloomError(f"--set {dotted}: unknown key{_suggest(dotted)}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    if KEYS[dotted].kind is str and not isinstance(value, str):
        value = raw
    return dotted, value


def load_config(path: str | Path | None = None, overrides: tuple[str, ...] | list[str] = ()) -> Config:
    """Read and check a scene file (or the defaults when ``path`` is None), then apply
    ``--set`` overrides. Raises :class:`BloomError` naming the file and key on any problem."""
    values = {dotted: list(key.default) if key.kind is list else key.default
              for dotted, key in KEYS.items()}
    cfg_path = None
    given = set()
    if path is not None:
        cfg_path = Path(path)
        where = str(cfg_path)
        try:
            text = cfg_path.read_bytes().decode("utf-8")
        except FileNotFoundError:
            raise BloomError("config file not found", where=where) from None
        except IsADirectoryError:
            raise BloomError("is a folder, not a config file", where=where) from None
        except PermissionError:
            raise BloomError("config file not readable (permission denied)", where=where) from None
        except UnicodeDecodeError:
            raise BloomError("not a text file (expected TOML)", where=where) from None
        try:
            table = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise BloomError(f"not valid TOML: {exc}", where=where) from None
        for dotted, value in _walk(table, where):
            if dotted not in KEYS:
                raise BloomError(f"{dotted}: unknown key{_suggest(dotted)}", where=where)
            values[dotted] = _coerce(dotted, KEYS[dotted], value, where)
            given.add(dotted)
    for text in overrides:
        dotted, value = parse_override(text)
        values[dotted] = _coerce(dotted, KEYS[dotted], value, "--set")
        if dotted == "scene.mesh" and values[dotted]:  # (typed on the command line: a
            # relative path is from where it was typed, not from the config file's folder)
            values[dotted] = str(Path(values[dotted]).absolute())
        given.add(dotted)
    cfg = Config(values, cfg_path, frozenset(given))
    _check_together(cfg, str(cfg_path) if cfg_path else "defaults")
    return cfg


def _check_together(cfg: Config, where: str) -> None:
    """Checks that involve more than one key."""
    if cfg["simulate.frames"] > cfg["simulate.steps"] + 1:
        raise BloomError(f"simulate.frames: {cfg['simulate.frames']} frames need at least "
                         f"{cfg['simulate.frames'] - 1} steps (simulate.steps = "
                         f"{cfg['simulate.steps']})", where=where)
    keys = cfg["growth.keys"]
    if keys and keys[-1][0] > cfg["simulate.frames"] - 1:
        raise BloomError(f"growth.keys: a key at frame {keys[-1][0]:g} is past the last frame "
                         f"({cfg['simulate.frames'] - 1}; simulate.frames = "
                         f"{cfg['simulate.frames']})", where=where)
    if cfg["remesh.target_edge"] > 0 and cfg["remesh.petal_vertices"] > 0:
        raise BloomError("remesh.target_edge, remesh.petal_vertices: set one of them, not both",
                         where=where)
    if cfg["growth.start"] == "open" and cfg["effects.connections.enabled"]:
        raise BloomError("growth.start: an open model has no bud lock to break; set "
                         "effects.connections.enabled = false", where=where)
    if cfg["render.width"] % 2 or cfg["render.height"] % 2:
        raise BloomError("render.width, render.height: must be even (H.264)", where=where)


def describe_keys() -> str:
    """All keys with type, default and description, for `bloom config --keys`."""
    lines = []
    for dotted, key in KEYS.items():
        default = json.dumps(key.default)
        lines.append(f"{dotted:36s} {key.kind.__name__:5s} = {default:16s} {key.doc}")
    return "\n".join(lines)


def keys_markdown() -> str:
    """Every key as a Markdown table (key, type, default, meaning), in the schema's order:
    the table docs/guide.md holds (``bloom config --keys --markdown`` prints it)."""
    rows = ["| key | type | default | meaning |", "|---|---|---|---|"]
    for dotted, key in KEYS.items():
        kind = f"{key.kind.__name__} or auto" if key.auto else key.kind.__name__
        if key.choices:
            kind = " \\| ".join(key.choices)
        default = json.dumps(key.default) if key.default != "" else ""
        doc = key.doc.replace("|", "\\|")
        rows.append(f"| `{dotted}` | {kind} | `{default}` | {doc} |" if default else
                    f"| `{dotted}` | {kind} | | {doc} |")
    return "\n".join(rows)


#: the markers around the generated key table in a Markdown file
KEYS_BEGIN = "<!-- keys: generated by `bloom config --keys --markdown` -->"
KEYS_END = "<!-- /keys -->"


def with_keys_table(text: str) -> str:
    """``text`` (a Markdown document holding :data:`KEYS_BEGIN` and :data:`KEYS_END`)
    with the table between them made anew from the schema (:func:`keys_markdown`)."""
    if KEYS_BEGIN not in text or KEYS_END not in text:
        raise ValueError(f"no {KEYS_BEGIN} ... {KEYS_END} block")
    head, rest = text.split(KEYS_BEGIN, 1)
    _, tail = rest.split(KEYS_END, 1)
    return f"{head}{KEYS_BEGIN}\n{keys_markdown()}\n{KEYS_END}{tail}"
