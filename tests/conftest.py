"""Shared fixtures: small procedural petals and buds taken through the library stages."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.flower.axis import find_axes
from pipeline.flower.growth import assign_growth
from pipeline.mesh import clean, procedural
from pipeline.sim.build import Prepared
from pipeline.sim.model import Control, Model

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"


def prepared(petals: int = 1, vertices: int = 150, seed: int = 0, curve: str = "0.2*x**2"):
    """A procedural petal or bud at mean edge 1, with its axes and growth map."""
    v, f, petal = procedural.bud(petals, vertices, seed)
    v = v / clean.mean_edge_length(v, f)
    axes = find_axes(v, f, petal)
    growth = assign_growth(v, f, axes.x, curve)
    return v, f, petal, axes, growth


def build_model(v, growth, axes, ks=0.1, kb=0.0005, pinned=None) -> Model:
    """The model of :func:`prepared`'s results, as the pipeline builds it
    (:class:`pipeline.sim.build.Prepared`)."""
    return Prepared.of(v, None, None, axes, growth).model(ks, kb, pinned=pinned)


@pytest.fixture(scope="session")
def small_petal():
    return prepared(1, 150)


@pytest.fixture
def control_linear():
    return Control("linear", 1000.0)


def min_distance(contact, X, reach: float) -> float:
    """Smallest distance between two petals of ``contact`` (a
    :class:`pipeline.sim.terms.contact.Contact`) at X, if below ``reach`` (else inf)."""
    import math

    import ipctk

    X = np.asfortranarray(X, dtype=np.float64)
    found = ipctk.NormalCollisions()
    found.build(contact.mesh, X, reach)
    return math.sqrt(found.compute_minimum_distance(contact.mesh, X)) if len(found) else math.inf


def prepare(vertices, faces, *, where: str, **options):
    """A lone mesh through the remesh stage's library call
    (:func:`pipeline.flower.petals.prepare_parts`), as a file of one part."""
    from pipeline.flower.petals import prepare_parts
    from pipeline.io.meshfile import MeshFile, Part

    part = Part("mesh", np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    return prepare_parts(MeshFile([part], None, None), where=where, **options)
