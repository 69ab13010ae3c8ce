"""The fixed petal base (Eq. 10): a constraint, not an energy."""

from __future__ import annotations

import numpy as np


class FixedBase:
    """The fixed petal base (Eq. 10): its vertices never move."""

    name = "fixed_base"

    def __init__(self, pinned):
        self.pinned = np.asarray(pinned, dtype=bool)

    def project(self, vec) -> None:
        """Remove from ``vec (V, 3)``, in place, what the constraint forbids."""
        vec[self.pinned] = 0.0
