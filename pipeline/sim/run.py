"""Run a simulation frame by frame and collect the per-frame diagnostics."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from pipeline.flower.measure import PetalFrames
from pipeline.sim.effects import NO_EFFECTS, Effects
from pipeline.sim.explicit.semi_implicit import Diverged
from pipeline.sim.model import Control, Model, State
from pipeline.sim.solver.newton import NotConverged

#: energy guard: while growth holds, kinetic + potential energy may only fall (Eq. 8 with
#: eta < 1/2, collisions and breaking springs all remove energy); a rise by more than
#: this fraction of its value when the hold began is an instability (a time step at the
#: scheme's limit grows energy slowly, below the speed limit). Not for a solver whose every
#: frame is an equilibrium (the quasi-static one without inertia): its energy cannot run
#: away, and a path played backward from a model at rest (energy 0 to rounding) meets
#: contact within the hold (hallgeirl's: from 1e-29 to 5e-6, no instability)
HOLD_ENERGY_RISE = 0.5


def frame_steps(steps: int, frames: int) -> np.ndarray:
    """Step index of each stored frame: evenly spread, the first at 0, the last at ``steps``."""
    return np.round(np.linspace(0, steps, frames)).astype(np.int64)


@dataclass
class Recording:
    """Frames of positions and the diagnostics taken at each."""

    time: list = field(default_factory=list)
    positions: list = field(default_factory=list)
    diagnostics: dict = field(default_factory=dict)

    def add(self, name: str, value) -> None:
        self.diagnostics.setdefault(name, []).append(value)

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(values) for name, values in self.diagnostics.items()}


def openings(petals: PetalFrames, X) -> dict:
    """A frame's opening diagnostics: each petal's opening angle (deg) and their mean."""
    angles = petals.opening_angles(X)
    return {"opening_angle": float(angles.mean()), "opening_angle_per_petal": angles}


def record(rec: Recording, model: Model, state: State, control: Control, h: float,
           petals: PetalFrames | None, effects: Effects = NO_EFFECTS, integrator=None) -> None:
    t = state.step * h
    rec.time.append(t)
    rec.positions.append(state.positions.copy())
    ke = state.kinetic_energy(model)
    rec.add("kinetic_energy", ke)
    rec.add("potential_energy", state.potential_energy)
    rec.add("total_energy", ke + state.potential_energy)
    rec.add("max_speed", state.max_speed())
    rec.add("growth", control.growth_at(t))
    if petals is not None and len(petals.tips):
        for name, value in openings(petals, state.positions).items():
            rec.add(name, value)
    for name, value in effects.frame_diagnostics(state.positions, control.growth_at(t)).items():
        rec.add(name, value)
    for name, value in (integrator.diagnostics() if integrator is not None else {}).items():
        rec.add(name, value)


def run(model: Model, state: State, control: Control, integrator, *, steps: int, frames: int,
        h: float, petals: PetalFrames | None = None, effects: Effects = NO_EFFECTS,
        progress: Callable[[int], None] | None = None, resume: Recording | None = None,
        checkpoint: Callable[[Recording, State], None] | None = None
        ) -> tuple[Recording, float]:
    """Advance ``state`` by ``steps`` steps, recording ``frames`` frames.

    ``resume``: the frames a checkpoint recorded, ``state`` (and effects) being restored
    at the last of them; the run goes on from there. ``checkpoint`` is called after each
    frame. Returns the recording and the wall-clock seconds spent stepping. Where the
    quasi-static solver finds no equilibrium, its :class:`NotConverged` carries the frames
    recorded so far (``recording``) and every frame's step (``frame_steps``), for a
    caller that keeps them (:func:`hold_last`).
    """
    if resume is None:
        rec = Recording()
        record(rec, model, state, control, h, petals, effects, integrator)
    else:
        rec = resume
        if progress is not None:
            progress(state.step)
    wall = 0.0
    targets = frame_steps(steps, frames)
    for target in targets[1:]:
        if target <= state.step:
            continue
        n = int(target - state.step)
        t0 = time.perf_counter()
        try:
            integrator.advance(model, state, control, n, h, effects)
        except NotConverged as exc:
            exc.recording, exc.frame_steps = rec, targets
            raise
        wall += time.perf_counter() - t0
        record(rec, model, state, control, h, petals, effects, integrator)
        if not getattr(integrator, "equilibria", False):
            _guard_hold_energy(rec, state)
        if progress is not None:
            progress(n)
        if checkpoint is not None and target < targets[-1]:
            checkpoint(rec, state)
    return rec, wall


def hold_last(rec: Recording, targets, h: float) -> Recording:
    """``rec`` (the frames a run recorded before it stopped) with its last frame held for
    each of the frame steps ``targets`` it did not reach: the same positions and
    diagnostics (its growth too: the sheet does not grow past where it stopped), at the
    frames' times."""
    last = len(rec.time)
    out = Recording(list(rec.time), list(rec.positions),
                    {k: list(v) for k, v in rec.diagnostics.items()})
    for target in targets[last:]:
        out.time.append(int(target) * h)
        out.positions.append(rec.positions[-1].copy())
        for v in out.diagnostics.values():
            v.append(v[last - 1])
    return out


def hold_first(rec: Recording, first: int, petals: PetalFrames | None) -> Recording:
    """``rec`` starting from its frame ``first``: the frames before it hold it (positions
    and diagnostics, its growth too, as :func:`hold_last`'s), and the openings measured
    again from it in ``petals`` (its petal frames), if given."""
    out = Recording(list(rec.time), [rec.positions[max(k, first)] for k in range(len(rec.time))],
                    {k: [v[max(j, first)] for j in range(len(v))]
                     for k, v in rec.diagnostics.items()})
    if petals is not None and len(petals.tips):
        measured = [openings(petals, X) for X in out.positions]
        for name in measured[0]:
            out.diagnostics[name] = [m[name] for m in measured]
    return out


def _guard_hold_energy(rec: Recording, state: State) -> None:
    growth, total = rec.diagnostics["growth"], rec.diagnostics["total_energy"]
    first = len(growth)  # the hold: the frames at full growth up to this one
    while first > 0 and growth[first - 1] >= 1.0:
        first -= 1
    if len(growth) - first < 2:  # (a path played backward leaves full growth: no hold)
        return
    start = total[first]
    if total[-1] > start + HOLD_ENERGY_RISE * abs(start) + 1e-12:
        raise Diverged(state.step, state.potential_energy, state.max_speed(),
                       f"energy rose {100 * (total[-1] - start) / abs(start):.0f}% while "
                       f"growth held (from {start:.3g} to {total[-1]:.3g})")
