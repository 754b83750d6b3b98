"""The figure of one estimate (``tactile6d estimate --plot``): where the object was placed among the sensors, and
whether that pose presses each gel where its image shows the press. For a look at an estimate that has no ground
truth, as a real hand's has none: a pose that presses where the image shows nothing, or misses the press it shows,
is wrong however confident the score, and the picture shows it at a glance.

The presses predicted at the best pose are those of the project's renderer through the sensor poses as given
(``gel_press.poses_to_gel_depths``), without the small sensor corrections the ranking estimates; the observed ones
are the contact patches the estimator read (``Estimate.contacts``).
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.gridspec import GridSpec  # noqa: E402

from tactile6d.core.geometry import transform_points  # noqa: E402
from tactile6d.evaluation.plots import SENSOR_COLOURS, draw_sensors  # noqa: E402
from tactile6d.sim import gel_press  # noqa: E402

# The ray grid's step (pixels) of the predicted presses: 2 is the renderer's own, 160 x 120 rays a sensor.
PLOT_STEP = 2
RIVALS_DRAWN = 2


def grid_to_image(values: np.ndarray, step: int) -> np.ndarray:
    """Values on a ray grid (..., h, w) -> the image's pixels (..., h step, w step), each cell repeated over its
    ``step`` x ``step`` block (the inverse of ``render_and_compare.image_to_grid`` for a value constant per block)."""
    return np.repeat(np.repeat(np.asarray(values), step, axis=-2), step, axis=-1)


def predicted_presses(mesh, T_world_object: np.ndarray, T_world_sensors: np.ndarray,
                      step: int = PLOT_STEP) -> np.ndarray:
    """Each sensor's press depth at one object pose, on the image's pixels.

    mesh: the object (trimesh or ``render.MeshArrays``, its own frame); T_world_object (4, 4); T_world_sensors
    (L, 4, 4). -> (L, 320, 240) float32 m, 0 where the object does not press into the gel."""
    depths = gel_press.poses_to_gel_depths(mesh, T_world_object, T_world_sensors, step)[0]
    return grid_to_image(depths, step)


def press_agreement(observed_masks: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Mask IoU of the observed patches (L, 320, 240) bool with the predicted presses (L, 320, 240) m (pressed
    where > 0) -> (L,); 1 where neither presses (a lifted sensor the pose keeps clear of)."""
    return gel_press.mask_iou(np.asarray(predicted) > 0, observed_masks)


def estimate_figure(points: np.ndarray, mesh, T_world_sensors: np.ndarray, images: np.ndarray, estimate,
                    title: str):
    """The object's points at the best pose among the sensors (a 3D view, with up to ``RIVALS_DRAWN`` of the poses
    that explain the contacts about equally well when the estimate is ambiguous), and one row per sensor: its image
    with the observed patch's outline (white) and the best pose's predicted press (orange), the observed press
    depth and the predicted one (mm, one colour scale per row), titled with their mask IoU.

    points (N, 3) m on the object's surface, its frame; mesh: the object (``predicted_presses``); T_world_sensors
    (L, 4, 4) as given to the estimate; images (L, 320, 240, 3) uint8; estimate: ``estimator.Estimate`` (its
    ``contacts.masks`` and ``depths`` None when the method read no image: then only the predicted press is
    drawn). -> matplotlib Figure."""
    T_world_sensors = np.asarray(T_world_sensors, dtype=np.float64)
    L = len(T_world_sensors)
    predicted = predicted_presses(mesh, estimate.best, T_world_sensors)
    observed = estimate.contacts.masks
    ious = None if observed is None else press_agreement(observed, predicted)

    fig = plt.figure(figsize=(13.5, max(3.3 * L, 5.0)))
    grid = GridSpec(L, 4, figure=fig, width_ratios=(2.0, 1, 1, 1))
    ax3d = fig.add_subplot(grid[:, 0], projection="3d")
    best_mm = transform_points(estimate.best, points) * 1000
    ax3d.scatter(*best_mm.T, s=1, color="tab:orange", alpha=0.5, label="best pose")
    rivals = [] if estimate.distinct is None else list(estimate.distinct[1:1 + RIVALS_DRAWN])
    for k, i in enumerate(rivals):
        rival_mm = transform_points(estimate.poses[i], points) * 1000
        ax3d.scatter(*rival_mm.T, s=1, color=("tab:blue", "tab:purple")[k], alpha=0.35,
                     label=f"pose {i}, about as good")
    draw_sensors(ax3d, T_world_sensors)
    ax3d.scatter(*(estimate.contacts.points * 1000).T, color="black", s=6, label="contacts read")
    ax3d.set_aspect("equal")  # millimetres alike on the three axes, so that the object's shape reads true
    ax3d.set(xlabel="x (mm)", ylabel="y (mm)", zlabel="z (mm)")
    ax3d.legend(loc="upper left", fontsize=7, markerscale=3)

    for i in range(L):
        colour = SENSOR_COLOURS[i % len(SENSOR_COLOURS)]
        image_ax, observed_ax, predicted_ax = (fig.add_subplot(grid[i, c]) for c in (1, 2, 3))
        image_ax.imshow(images[i])
        if observed is not None and observed[i].any():
            image_ax.contour(observed[i], levels=[0.5], colors="white", linewidths=1.0)
        if (predicted[i] > 0).any():
            image_ax.contour(predicted[i] > 0, levels=[0.5], colors="tab:orange", linewidths=1.0)
        image_ax.set_title(f"sensor {i}: image", color=colour, fontsize=9)
        read = None if observed is None else np.where(observed[i], estimate.contacts.depths[i], 0.0)
        top = 1000 * max(float(predicted[i].max()), 0.0 if read is None else float(read.max()), 1e-4)
        if observed is None:
            observed_ax.text(0.5, 0.5, "no image read\n(the method reads none)", ha="center", va="center", fontsize=8)
        else:
            observed_ax.imshow(1000 * read, cmap="viridis", vmin=0, vmax=top)
            observed_ax.set_title("press read (mm)", fontsize=9)
        shown = predicted_ax.imshow(1000 * predicted[i], cmap="viridis", vmin=0, vmax=top)
        agreement = "" if ious is None else f", IoU {ious[i]:.2f}"
        predicted_ax.set_title(f"at the best pose{agreement}", fontsize=9)
        fig.colorbar(shown, ax=predicted_ax, fraction=0.046, pad=0.04, label="press (mm)")
        for ax in (image_ax, observed_ax, predicted_ax):
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig
