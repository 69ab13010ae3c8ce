"""What every physical term of the energy answers (:class:`Term`)."""

from __future__ import annotations

import numpy as np


class Term:
    """One piece of the energy; subclasses define :meth:`forces` and :meth:`hessian`."""

    name = "term"

    def at(self, growth: float) -> Term:
        """Set the growth A(t) the term is evaluated at (terms that do not grow ignore
        it); returns the term."""
        return self

    def forces(self, X, F) -> float:
        raise NotImplementedError

    def hessian(self, X, project: bool = False):
        raise NotImplementedError

    def energy(self, X) -> float:
        return self.forces(X, np.zeros_like(X, dtype=np.float64))

    def gradient(self, X) -> np.ndarray:
        F = np.zeros_like(X, dtype=np.float64)
        self.forces(X, F)
        return -F
