"""Inertia: the implicit Euler step in incremental-potential form (``simulate.inertia``)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from pipeline.sim.terms.term import Term


class Inertia(Term):
    """``1/2 sum_v w_v |x_v - x_pred_v|^2``, ``w = m / dt^2``, ``x_pred = x + dt v``:
    with it, a minimum of the energy is an implicit Euler step (incremental-potential
    form)."""

    name = "inertia"

    def __init__(self, predicted, weight):
        self.predicted = np.asarray(predicted, dtype=np.float64)
        self.weight = np.asarray(weight, dtype=np.float64)

    def forces(self, X, F) -> float:
        d = X - self.predicted
        F -= self.weight[:, None] * d
        return 0.5 * float(np.sum(self.weight[:, None] * d * d))

    def diagonal(self) -> np.ndarray:
        """The Hessian's diagonal, per unknown (3V,)."""
        return np.repeat(self.weight, 3)

    def hessian(self, X, project: bool = False) -> sp.csr_matrix:
        return sp.diags(self.diagonal()).tocsr()
