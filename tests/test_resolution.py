"""The resolution study's pieces (``bloom study resolution``, issue 31): the irregular
triangulation lies on the asset's surface, and a bloom measured against itself differs by
nothing. The study's runs themselves are slow: they are the study command's, not the
suite's (docs/shell.md has the measured table)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.studies import resolution as study

ROOT = Path(__file__).resolve().parents[1]


def test_the_irregular_petal_is_the_assets_surface_other_triangles():
    flat, V, F, petal = study.asset_pattern(ROOT / "assets" / "petal.obj")
    assert flat.shape == (len(V), 2) and np.all(petal == 0)
    v, f = study.irregular_mesh(ROOT / "assets" / "petal.obj", 300)
    assert 240 <= len(v) <= 360 and f.min() == 0 and f.max() == len(v) - 1
    # every point on the asset: within rounding of its nearest face's plane (a coarse check:
    # the distance to the nearest asset vertex is under an asset edge)
    from scipy.spatial import cKDTree

    edge = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean()
    assert cKDTree(V).query(v)[0].max() < edge
    # the area is the asset's (the same surface)
    def area(X, T):
        return 0.5 * np.linalg.norm(np.cross(X[T[:, 1]] - X[T[:, 0]], X[T[:, 2]] - X[T[:, 0]]),
                                    axis=1).sum()

    assert abs(area(v, f) / area(V, F) - 1.0) < 0.01


def test_a_bloom_against_itself_differs_by_nothing():
    rng = np.random.default_rng(0)
    flat, V, F, petal = study.asset_pattern(ROOT / "assets" / "petal.obj")
    s = np.clip(flat[:, 1] / flat[:, 1].max(), 0.0, 1.0)
    x = flat[:, 0] / np.abs(flat[:, 0]).max()
    P = np.stack([V, V + rng.normal(scale=0.01, size=V.shape)])
    tip = np.array([int(np.argmax(s))])
    run = dict(P=P, s=s, x=x, faces=F, petal=petal, base=s < 0.05, tip=tip,
               opening=np.array([10.0, 50.0]))
    rows = study.measure({"a": run}, "a")
    assert rows[0]["shape_difference"] < 1e-12 and rows[0]["opening_difference"] == 0.0


def test_the_picture_draws_each_model_and_triangulation(tmp_path):
    """resolution.png: a curve per model and triangulation, the reference left out."""
    rows = [{"model": m, "run": f"{k} {n}", "reference": (k, n) == ("regular", 800),
             "vertices": n, "opening": 60.0, "opening_difference": d / n,
             "shape_difference": 1e-15 if (k, n) == ("regular", 800) else d / n / 100}
            for m, d in (("paper", 900.0), ("shell", 300.0)) for k in ("regular", "irregular")
            for n in (100, 200, 400, 800)]
    study.plot(rows, tmp_path / "r.png", "test")
    from PIL import Image

    image = np.asarray(Image.open(tmp_path / "r.png").convert("RGB"))
    assert image.shape[0] > 300 and image.shape[1] > 800
    # four coloured curves (matplotlib's first four colours) are on it
    for colour in ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)):
        assert np.any(np.all(np.abs(image.astype(int) - colour) < 10, axis=2)), colour
    table = "\n".join(study.table(rows))
    assert "| shell | irregular 100 |" in table and "| regular 800 | 800 | 60.00 deg | (reference)" in table


def test_accuracy_png_carries_the_resolution_axis(tmp_path):
    """accuracy.png with a resolution study's rows: the cost curves, then its two panels
    (a curve per model and triangulation) to their right."""
    from PIL import Image

    from pipeline.studies import accuracy

    rows = [{"integrator": "quasi-static", "wall_seconds": t, "error": e}
            for t, e in ((1.0, 1e-2), (2.0, 1e-3))]
    meshes = [{"model": m, "run": f"{k} {n}", "reference": (k, n) == ("regular", 800),
               "vertices": n, "opening": 60.0, "opening_difference": d / n,
               "shape_difference": d / n / 100}
              for m, d in (("paper", 900.0), ("shell", 300.0))
              for k in ("regular", "irregular") for n in (100, 200, 400, 800)]
    accuracy.plot(rows, tmp_path / "a.png", "test")
    accuracy.plot(rows, tmp_path / "b.png", "test", resolution=meshes)
    alone = np.asarray(Image.open(tmp_path / "a.png").convert("RGB"))
    image = np.asarray(Image.open(tmp_path / "b.png").convert("RGB"))
    assert image.shape[1] > 2 * alone.shape[1]
    right = image[:, image.shape[1] * 9 // 20:].astype(int)  # (the two resolution panels)
    for colour in ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)):
        assert np.any(np.all(np.abs(right - colour) < 10, axis=2)), colour


def test_an_unknown_model_is_one_line_and_no_run(tmp_path):
    from click.testing import CliRunner

    from stages.cli import cli

    r = CliRunner().invoke(cli, ["study", "resolution", "--config", str(ROOT / "configs/petal.toml"),
                                 "--models", "shell,springs", "--out", str(tmp_path / "r")])
    assert r.exit_code != 0 and "--models" in r.output and "'springs'" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "r").exists()


def test_a_run_that_is_not_sound_says_so_in_the_table():
    """A run whose bloom stopped (a bud remeshed to 200 vertices a petal once stopped at
    A = 0.35 and read as 21.6 deg of opening, 41 deg off, among figures of 1 deg) is
    marked in the table, and its row records it."""
    rows = [{"model": "shell", "run": f"regular {n}", "reference": n == 800, "sound": ok,
             "vertices": 6 * n, "opening": 60.0, "opening_difference": 0.5,
             "shape_difference": 0.01} for n, ok in ((200, False), (800, True))]
    lines = study.table(rows)
    assert "regular 200 (unsound)" in lines[2] and "unsound" not in lines[3]
