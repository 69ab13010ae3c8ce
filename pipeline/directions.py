"""Directions a scene may name (``+x`` ... ``-z``, or a vector ``"x,y,z"``): the keys
``scene.up``, ``axis.flower_axis`` and ``axis.base`` read them."""

from __future__ import annotations

import numpy as np

#: the directions a key may name, as unit vectors
DIRECTIONS = {"+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0),
              "-y": (0.0, -1.0, 0.0), "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


def parse_direction(text: str) -> np.ndarray | None:
    """``"auto"`` -> None; ``"+x"`` ... ``"-z"`` or ``"x,y,z"`` (three finite numbers, not
    all zero) -> the unit vector. Raises ``ValueError`` with a reason otherwise."""
    word = str(text).strip().lower()
    if word == "auto":
        return None
    if word in DIRECTIONS:
        return np.array(DIRECTIONS[word])
    parts = word.split(",")
    try:
        vec = np.array([float(part) for part in parts]) if len(parts) == 3 else None
    except ValueError:
        vec = None
    if vec is None or not np.all(np.isfinite(vec)) or not np.any(vec):
        raise ValueError(f"expected auto, {', '.join(DIRECTIONS)} or a vector \"x,y,z\" (three "
                         f"finite numbers, not all zero); got {text!r}")
    return vec / np.linalg.norm(vec)
