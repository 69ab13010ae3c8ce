"""bloom study models: the verdict on a bloom from its sim.h5, and the table kept in the
docs between its markers."""

import h5py
import numpy as np
import pytest

from pipeline.studies import models


def _sim(path, *, start="bud", petals=2, opening=(0.0, 30.0), distance=None, crossed=0):
    frames = len(opening)
    with h5py.File(path, "w") as h:
        h["frames/positions"] = np.zeros((frames, 4 * petals, 3))
        h["mesh/petal"] = np.repeat(np.arange(petals), 4)
        h["diagnostics/intersecting"] = np.arange(frames) < crossed
        h["diagnostics/opening_angle"] = np.asarray(opening, dtype=float)
        h["diagnostics/opening_angle_per_petal"] = np.repeat(
            np.asarray(opening, dtype=float)[:, None], petals, axis=1)
        h.attrs["growth_start"] = start
        h.attrs["effects"] = "collisions" if petals > 1 else ""
        h.attrs["wall_seconds"] = 1.5
        if distance is not None:
            h.attrs["distance_to_model"] = distance
            h.attrs["bud_seconds"] = 0.5


@pytest.mark.parametrize("kw, verdict", [
    (dict(), "ok"),
    (dict(crossed=1), "petals through each other"),
    (dict(opening=(0.0, -4.0)), "opens backward (-4.0 deg); a petal did not open (-4.0 deg)"),
    (dict(opening=(0.0, 3.0)), "a petal did not open (3.0 deg)"),
    (dict(petals=1, opening=(0.0, 8.0)), "opens 8.0 deg"),
    (dict(start="open", opening=(0.0, 25.0), distance=0.004), "ok"),
    (dict(start="open", opening=(0.0, 25.0), distance=0.02), "ends 0.02 petal lengths from the model"),
    (dict(start="open", opening=(0.0, 12.0), distance=0.004), "bud only 12.0 deg more closed"),
])
def test_the_verdict_follows_the_checks(tmp_path, kw, verdict):
    _sim(tmp_path / "sim.h5", **kw)
    row = models.Row("m")
    with h5py.File(tmp_path / "sim.h5") as h:
        models.judge(row, h)
    assert row.verdict == verdict
    assert row.seconds == (2.0 if "distance" in kw else 1.5)  # the bud search counts


def test_a_models_simulate_seconds_are_its_commands(tmp_path, monkeypatch):
    """run_model's simulate seconds are the command's wall time (every try it made), not
    the kept bloom's that sim.h5 records (1.5 s here, with 0.5 of bud search)."""
    import subprocess
    import time
    from types import SimpleNamespace

    def fake(cmd, **kwargs):
        if "simulate" in cmd:
            time.sleep(2.5)
            _sim(tmp_path / "work" / "sim.h5", start="open", opening=(0.0, 25.0),
                 distance=0.004)
        return SimpleNamespace(returncode=0, stdout="", stderr="")

    monkeypatch.setattr(subprocess, "run", fake)
    row = models.run_model(tmp_path / "m.obj", tmp_path / "work", timeout=60.0)
    assert row.verdict == "ok" and 2.5 <= row.seconds < 60.0


def test_the_table_goes_between_its_markers_and_nothing_else_changes(tmp_path):
    doc = tmp_path / "performance.md"
    doc.write_text("# Performance\n\nbefore\n")
    rows = [models.Row("a", 2, 100, "bud", "collisions", 1.0, 2.0, "0 of 3", 30.0, 29.0,
                       float("nan"), "ok")]
    models.into(doc, models.table(rows))
    first = doc.read_text()
    assert first.startswith("# Performance\n\nbefore\n") and "| a | 2 | 100 | bud |" in first
    rows[0].verdict = "petals through each other"
    models.into(doc, models.table(rows))
    second = doc.read_text()
    assert second.count(models.BEGIN) == 1 and "| a | 2 | 100 | bud |" in second
    assert "petals through each other" in second and second.startswith("# Performance\n\nbefore\n")
