"""The per-scene report: what each effect did, measured on sim.h5's frames.

Opening angle per petal, mean cross-section curvature, boundary wrinkles, petal
crossings, intersections (an exact triangle-triangle test, every frame), connection
breaks and the sign of each petal's Gaussian curvature, over time; written as JSON and
drawn as a small plot.
"""

from __future__ import annotations

import numpy as np

from pipeline.flower import measure
from pipeline.mesh import topology
from pipeline.mesh.remesh import boundary_loops

#: what the report reads from sim.h5 beyond what every sim.h5 holds
NEEDS = ("mesh/petal", "growth/hinges", "axis/s", "axis/x", "diagnostics/opening_angle_per_petal")


def compute(sim) -> dict:
    """Measure an open sim.h5 (an :class:`artifact.Artifact`)."""
    X = sim["frames/positions"]
    t = sim["frames/time"]
    faces, petal = sim["mesh/faces"], sim["mesh/petal"]
    hinges, s, x = sim["growth/hinges"], sim["axis/s"], sim["axis/x"]
    petals = int(petal.max()) + 1
    boundary = topology.boundary_vertices(faces, len(petal))
    loops = boundary_loops(faces)
    weights = measure.section_weights(hinges, s[hinges[:, :2]], x[hinges[:, :2]])
    hinge_petal = petal[hinges[:, 0]]
    rim = boundary[hinges].any(axis=1)
    curvature, wrinkles, crossing, rim_fold = [], [], [], []
    for frame in X:
        rim_fold.append(measure.rim_bending(frame, hinges, rim))
        curvature.append(measure.cross_section_curvature(frame, hinges, weights, hinge_petal, petals))
        wrinkles.append(measure.wrinkle_count(frame, loops, topology.vertex_normals(frame, faces)))
        crossing.append(measure.crossings(frame, faces, petal) if petals > 1 else 0)
    curvature = np.asarray(curvature)
    from pipeline.sim.terms.contact import frame_intersections

    intersecting = frame_intersections(X, faces)  # ipctk's exact test, self-contact included
    diag = {k: sim[f"diagnostics/{k}"] for k in ("opening_angle_per_petal", "kinetic_energy")}
    report = {
        "scene": sim.config().get("scene", {}).get("name", "") or sim.path.parent.name,
        "effects": [e for e in str(sim.attrs.get("effects", "")).split(",") if e],
        "time": t.tolist(),
        "opening_angle_per_petal": diag["opening_angle_per_petal"].tolist(),
        "opening_angle_final_mean": float(diag["opening_angle_per_petal"][-1].mean()),
        "cross_section_curvature": curvature.mean(axis=1).tolist(),
        "cross_section_curvature_per_petal_final": curvature[-1].tolist(),
        "boundary_wrinkles": wrinkles,
        "rim_bending": rim_fold,
        "crossings": crossing,
        "intersecting": intersecting,
        "intersecting_frames": int(sum(intersecting)),
        "gaussian_curvature_sign": {
            "start": measure.gaussian_curvature_sign(X[0], faces, petal, ~boundary).tolist(),
            "end": measure.gaussian_curvature_sign(X[-1], faces, petal, ~boundary).tolist()},
        "kinetic_energy_final": float(diag["kinetic_energy"][-1]),
    }
    if "effects/connections/broken_step" in sim:
        broken = sim["effects/connections/broken_step"]
        h = float(sim.attrs["h"])
        times = np.sort(broken[broken >= 0]) * h
        report["connections"] = {
            "count": int(len(broken)), "broken": int(len(times)),
            "first_break_time": float(times[0]) if len(times) else None,
            "last_break_time": float(times[-1]) if len(times) else None,
            "intact": sim["diagnostics/connections_intact"].tolist()}
    if "diagnostics/contacts" in sim:
        report["contacts"] = sim["diagnostics/contacts"].tolist()
    return report


def plot(report: dict, path) -> None:
    """A 2x2 figure: opening per petal, cross-section curvature, wrinkles, and crossings
    (with the intact connection springs when there are any)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(report["time"])
    fig, ax = plt.subplots(2, 2, figsize=(8, 5.5), constrained_layout=True)
    ax[0, 0].plot(t, np.asarray(report["opening_angle_per_petal"]), lw=1)
    ax[0, 0].set(title="opening angle per petal", ylabel="degrees")
    ax[0, 1].plot(t, report["cross_section_curvature"], color="k")
    ax[0, 1].set(title="mean cross-section curvature", ylabel="rad per edge")
    ax[1, 0].plot(t, report["boundary_wrinkles"], color="tab:purple", label="wrinkles (sign changes)")
    twin = ax[1, 0].twinx()
    twin.plot(t, report["rim_bending"], color="tab:orange", label="rim bending (rad)")
    ax[1, 0].legend(loc="upper left", fontsize=8)
    twin.legend(loc="lower right", fontsize=8)
    ax[1, 0].set(title="the rim", xlabel="time")
    ax[1, 1].plot(t, report["crossings"], color="tab:red", label="edges through another petal")
    if "connections" in report:
        ax[1, 1].plot(t, report["connections"]["intact"], color="tab:green",
                      label="connection springs intact")
    ax[1, 1].legend(fontsize=8)
    ax[1, 1].set(title="crossings / connections", xlabel="time")
    title = report["scene"] + (" (" + ", ".join(report["effects"]) + ")" if report["effects"] else "")
    fig.suptitle(title)
    fig.savefig(path, dpi=80)
    plt.close(fig)
