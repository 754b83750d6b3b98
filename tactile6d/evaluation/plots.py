"""Figures (matplotlib, headless): objects and sensors at poses, candidate sets, latent angles, curves.

Each function draws into a new figure and returns it; the caller saves it. Points are in metres and
drawn in millimetres.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tactile6d.core.geometry import transform_points  # noqa: E402
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS, contact_points  # noqa: E402
from tactile6d.evaluation.tracking_accuracy import true_runs  # noqa: E402

SENSOR_COLOURS = ("tab:red", "tab:green", "tab:blue", "tab:orange", "tab:purple")


def _equal_axes(ax, points_mm: np.ndarray) -> None:
    centre = (points_mm.max(axis=0) + points_mm.min(axis=0)) / 2
    half = (points_mm.max(axis=0) - points_mm.min(axis=0)).max() / 2
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - half, c + half)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")


def _box_edges(T_world_sensor: np.ndarray) -> np.ndarray:
    """The 12 edges of a sensor's body box in the world: (12, 2, 3) metres."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * BOX_HALF_EXTENTS
    corners = transform_points(T_world_sensor, corners + BOX_CENTER)
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    return np.stack([corners[[a, b]] for a, b in pairs])


def draw_sensors(ax, T_world_sensors: np.ndarray) -> None:
    """Body boxes and contact points of L sensors."""
    for i, T in enumerate(T_world_sensors):
        colour = SENSOR_COLOURS[i % len(SENSOR_COLOURS)]
        for edge in _box_edges(T) * 1000:
            ax.plot(*edge.T, color=colour, linewidth=0.8)
        ax.scatter(*(contact_points(T) * 1000), color=colour, s=30, marker="x")


def poses_figure(points: np.ndarray, T_true: np.ndarray, T_est: np.ndarray, T_world_sensors: np.ndarray, title: str):
    """The object's points (N, 3) at the true pose (grey) and the estimated pose (orange), with the sensors."""
    fig = plt.figure(figsize=(5.5, 5))
    ax = fig.add_subplot(projection="3d")
    true_mm = transform_points(T_true, points) * 1000
    ax.scatter(*true_mm.T, s=1, color="0.6", alpha=0.5, label="true pose")
    if T_est is not None and np.all(np.isfinite(T_est)):
        est_mm = transform_points(T_est, points) * 1000
        ax.scatter(*est_mm.T, s=1, color="tab:orange", alpha=0.5, label="estimate #1")
    draw_sensors(ax, T_world_sensors)
    _equal_axes(ax, true_mm)
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=8, markerscale=8)
    fig.tight_layout()
    return fig


def omegas_figure(points: np.ndarray, omegas: list[np.ndarray], true_points: np.ndarray, title: str):
    """The database points (M, 3, object frame) in grey, each sensor's tactile selection Omega_i in its
    colour, and the true contact points (L, 3) as stars."""
    fig = plt.figure(figsize=(5.5, 5))
    ax = fig.add_subplot(projection="3d")
    mm = points * 1000
    ax.scatter(*mm.T, s=1, color="0.8", alpha=0.4)
    for i, omega in enumerate(omegas):
        colour = SENSOR_COLOURS[i % len(SENSOR_COLOURS)]
        ax.scatter(*mm[omega].T, s=4, color=colour, alpha=0.6, label=f"Omega_{i + 1} ({len(omega)} points)")
        ax.scatter(*(true_points[i] * 1000), s=120, color=colour, marker="*", edgecolor="k")
    _equal_axes(ax, mm)
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=7, markerscale=3)
    fig.tight_layout()
    return fig


def angle_maps_figure(maps: dict[str, tuple[np.ndarray, np.ndarray]]):
    """For each object, its database points (M, 3) coloured by latent angle (M,), one panel each."""
    n = len(maps)
    cols = min(5, n)
    rows = int(np.ceil(n / cols))
    fig = plt.figure(figsize=(3.2 * cols, 3.2 * rows))
    vmin = min(float(np.min(a)) for _, a in maps.values())
    vmax = max(float(np.max(a)) for _, a in maps.values())
    for k, (name, (points, angles)) in enumerate(maps.items()):
        ax = fig.add_subplot(rows, cols, k + 1, projection="3d")
        mm = points * 1000
        sc = ax.scatter(*mm.T, c=angles, s=2, cmap="viridis", vmin=vmin, vmax=vmax)
        _equal_axes(ax, mm)
        ax.set_title(name, fontsize=8)
        ax.set_xticklabels([])
        ax.set_yticklabels([])
        ax.set_zticklabels([])
    fig.colorbar(sc, ax=fig.axes, shrink=0.6, label="latent angle to no contact (rad)")
    return fig


def sensor_count_figure(results: dict, title: str):
    """Positional error and contact accuracy against L, one line per method or ablation variant
    (``results[name]['L<k>']``, as the sensor_study and ablation stages write them)."""
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
    for method, by_l in results.items():
        ls = sorted(int(k[1:]) for k in by_l)
        axes[0].plot(ls, [by_l[f"L{k}"].get("pos_err_cm_top1", np.nan) for k in ls], marker="o", label=method)
        axes[1].plot(ls, [by_l[f"L{k}"].get("contact_acc_top1", np.nan) for k in ls], marker="o", label=method)
    axes[0].set_ylabel("positional error #1 (cm)")
    axes[1].set_ylabel("contact accuracy #1 (%)")
    for ax in axes:
        ax.set_xlabel("number of sensors L")
        ax.set_xticks([1, 2, 3])
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def ablation_figure(results: dict, title: str):
    """Positional error and contact accuracy of each ablation variant (``results[variant]``: metrics at one
    sensor count), one horizontal bar each, top to bottom in the given order."""
    names = list(results)
    y = np.arange(len(names))[::-1]
    fig, axes = plt.subplots(1, 2, figsize=(8, 0.8 + 0.3 * len(names)), sharey=True)
    for ax, key, label in ((axes[0], "pos_err_cm_top1", "positional error #1 (cm)"),
                           (axes[1], "contact_acc_top1", "contact accuracy #1 (%)")):
        ax.barh(y, [results[n].get(key, np.nan) for n in names], color="tab:blue")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3, axis="x")
    axes[0].set_yticks(y, names)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def confusion_figure(matrix: np.ndarray, names: list[str], title: str):
    """Identification counts (O, O) over a library of O names, row = true object, column = identified
    first. Drawn: the rows of the objects the scenes show, and the columns of those objects and of every
    other object identified at least once, in library order, so that a library of distractors adds
    only the ones something was taken for. A cell (r, c) with r and c the same object is right."""
    matrix = np.asarray(matrix)
    shown = matrix.sum(axis=1) > 0
    rows, cols = np.flatnonzero(shown), np.flatnonzero(shown | (matrix.sum(axis=0) > 0))
    part = matrix[np.ix_(rows, cols)]
    fig, ax = plt.subplots(figsize=(1.0 + 0.55 * len(cols), 0.8 + 0.5 * len(rows)))
    ax.imshow(part, cmap="Blues", vmin=0)
    for (i, j), v in np.ndenumerate(part):
        if v:
            ax.text(j, i, str(v), ha="center", va="center", color="white" if v > part.max() / 2 else "black")
    ax.set_xticks(range(len(cols)), [names[c] for c in cols], rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), [names[r] for r in rows], fontsize=8)
    ax.set_xlabel("identified first")
    ax.set_ylabel("true object")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def reliability_figure(bins_by_set: dict[str, list[dict]], title: str):
    """Reliability diagram: per named group of scenes (``confidence.reliability``'s bins), the observed share of right
    estimates against the mean predicted probability in each bin, marker area by the bin's count; a
    calibrated confidence lies on the diagonal."""
    fig, ax = plt.subplots(figsize=(4.6, 4.2))
    ax.plot([0, 1], [0, 1], color="grey", lw=1, ls="--", label="calibrated")
    for name, bins in bins_by_set.items():
        if not bins:
            continue
        x, y = [b["predicted"] for b in bins], [b["observed"] for b in bins]
        ax.plot(x, y, marker="o", ms=0, lw=1, label=name)
        ax.scatter(x, y, s=[12 + 4 * b["count"] for b in bins], alpha=0.6, color=ax.lines[-1].get_color())
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("predicted P(ADI #1 < 1 cm), bin mean")
    ax.set_ylabel("observed share with ADI #1 < 1 cm")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def tracking_figure(names: list[str], frames: list[dict], fps: float, lost_threshold: float):
    """Positional error over time, one panel per sequence: the tracker's on every frame (line), single-shot
    estimation's on the compared frames (dots), re-detections (ticks at the top), frames where a sensor's
    image shows no contact (shaded) and the lost threshold (dashed). frames[q]: the stage evaluate_tracking's
    per-frame record (``track_position_m``, ``single_frames``, ``single_position_m``, ``modes``, ``touching``)."""
    n = len(names)
    cols = 2 if n > 1 else 1
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 2.2 * rows), sharey=True, squeeze=False)
    top = 100 * max(2.0 * lost_threshold, *(np.nanmax(f["single_position_m"] + f["track_position_m"]) for f in frames))
    top = min(top, 10.0)
    for ax, name, f in zip(axes.ravel(), names, frames):
        t = np.arange(len(f["track_position_m"])) / fps
        lifted = ~np.asarray(f["touching"], dtype=bool).all(axis=1)
        for start, stop in true_runs(lifted):
            ax.axvspan(t[start], t[stop - 1] + 1 / fps, color="0.9", lw=0)
        ax.plot(t, 100 * np.asarray(f["track_position_m"]), color="tab:blue", lw=1.2, label="tracked")
        ax.plot(np.asarray(f["single_frames"]) / fps, 100 * np.asarray(f["single_position_m"]), "o", ms=2.5,
                color="tab:orange", label="single-shot")
        redetected = [i for i, m in enumerate(f["modes"]) if m == "redetect"]
        ax.plot(t[redetected], np.full(len(redetected), 0.95 * top), "v", ms=4, color="tab:red", label="re-detection")
        ax.axhline(100 * lost_threshold, color="0.4", lw=0.8, ls="--")
        ax.set_ylim(0, top)
        ax.set_title(name, fontsize=8)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("position error (cm)")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return fig

