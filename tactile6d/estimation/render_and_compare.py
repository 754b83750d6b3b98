"""Render-and-compare: how well each pose hypothesis explains the contact patches the sensors see.

Each sensor's image gives an observed contact patch, a mask and a press depth on the gel; each pose
hypothesis gives predicted press depths on the same ray grid (``gel_press.poses_to_gel_depths``).
Three terms compare them, per hypothesis and sensor:

- mask overlap: intersection over union of the observed and predicted masks (1 is perfect);
- depth residual: mean absolute difference of the depths over the union of the masks (m), each depth
  read as 0 outside its own mask, so a cell that only one side presses counts its full depth;
- free-space violation: the predicted press where the image shows none, as the share of grid cells
  (``free_space_area``) and as the deepest such press (``free_space_depth``, m). A hypothesis that
  pushes the object into gel the image shows untouched cannot be right, however well it fits elsewhere.

``agreement_to_cost`` weighs them into one cost per hypothesis (lower is better), averaged over sensors.
Pose-to-point losses cannot tell apart poses that put the same contact points on surface of the same
shape (a box shifted along an edge, a cylinder along its axis); the patches' shape and place on the gel
can.
"""

from __future__ import annotations

import numpy as np
import trimesh

from tactile6d.core.errors import InputError
from tactile6d.sim import gel_press
from tactile6d.sim.render import MeshArrays

TERMS = ("iou", "depth_residual", "free_space_area", "free_space_depth")


def image_to_grid(values: np.ndarray, step: int) -> np.ndarray:
    """A full-resolution array (..., H, W) -> its means over ``step`` x ``step`` blocks (..., H/step, W/step).

    For an observed depth (m) on the image's pixels; a mask becomes the share of pressed pixels per
    block (threshold it, e.g. at 0.5, to get a grid mask). ``step`` must divide H and W.
    """
    values = np.asarray(values)
    H, W = values.shape[-2:]
    if step < 1 or H % step or W % step:
        raise InputError(f"step {step} must divide the image size {W}x{H}")
    blocks = values.reshape(*values.shape[:-2], H // step, step, W // step, step).astype(np.float64)
    return blocks.mean(axis=(-3, -1))


def depths_to_agreement(
    observed_mask: np.ndarray, observed_depth: np.ndarray, predicted_depth: np.ndarray, free_margin: float = 0.0
) -> dict[str, np.ndarray]:
    """The agreement terms of P hypotheses with the observed patches.

    observed_mask (L, h, w) bool and observed_depth (L, h, w) m on the ray grid of the predictions;
    predicted_depth (P, L, h, w) m, 0 where not pressed (``gel_press.poses_to_gel_depths``).
    -> dict of (P, L) float64 arrays, keys ``TERMS``:
    ``iou`` (1 when both masks are empty), ``depth_residual`` m (0 when both are empty),
    ``free_space_area`` (share of the grid's cells), ``free_space_depth`` m.

    free_margin (m): predicted presses up to this deep do not count as free-space violations, nor does
    that much of a deeper one. A mask taken from an image misses the faintest rim of a patch; set it to
    the depth below which the image's mask leaves contact out.
    """
    obs_mask = np.asarray(observed_mask, dtype=bool)
    obs_depth = np.where(obs_mask, np.asarray(observed_depth, dtype=np.float64), 0.0)
    pred_depth = np.asarray(predicted_depth, dtype=np.float64)
    if pred_depth.ndim != 4 or pred_depth.shape[1:] != obs_mask.shape or obs_depth.shape != obs_mask.shape:
        raise InputError(f"need observed (L, h, w) and predicted (P, L, h, w) arrays on one grid, got "
                         f"{obs_mask.shape}, {np.shape(observed_depth)} and {pred_depth.shape}")
    pred_mask = pred_depth > 0
    union = pred_mask | obs_mask[None]
    n_union = np.count_nonzero(union, axis=(-2, -1))
    residual = np.where(union, np.abs(pred_depth - obs_depth[None]), 0.0).sum(axis=(-2, -1))
    free = (pred_depth > free_margin) & ~obs_mask[None]
    h, w = obs_mask.shape[-2:]
    return {
        "iou": gel_press.mask_iou(pred_mask, obs_mask[None]),
        "depth_residual": residual / np.maximum(n_union, 1),
        "free_space_area": np.count_nonzero(free, axis=(-2, -1)) / float(h * w),
        "free_space_depth": np.where(free, pred_depth - free_margin, 0.0).max(axis=(-2, -1)),
    }


def agreement_to_cost(
    terms: dict[str, np.ndarray],
    mask_weight: float = 1.0,
    depth_weight: float = 1000.0,
    free_area_weight: float = 0.0,
    free_depth_weight: float = 1000.0,
) -> np.ndarray:
    """One cost per hypothesis, lower is better: (P,) from ``depths_to_agreement``'s (P, L) terms.

    cost = mean over sensors of ``mask_weight (1 - iou) + depth_weight depth_residual +
    free_area_weight free_space_area + free_depth_weight free_space_depth``. The depth weights are per
    metre: the defaults count a millimetre of depth error or of press into free gel as much as masks
    that do not overlap at all.
    """
    per_sensor = (
        mask_weight * (1.0 - terms["iou"])
        + depth_weight * terms["depth_residual"]
        + free_area_weight * terms["free_space_area"]
        + free_depth_weight * terms["free_space_depth"]
    )
    return per_sensor.mean(axis=-1)


def poses_to_agreement(
    mesh: trimesh.Trimesh | MeshArrays,
    T_world_object: np.ndarray,
    T_world_sensors: np.ndarray,
    observed_mask: np.ndarray,
    observed_depth: np.ndarray,
    step: int,
    free_margin: float = 0.0,
) -> dict[str, np.ndarray]:
    """Render-and-compare P hypotheses T_world_object (P, 4, 4) against the observed patches.

    T_world_sensors (L, 4, 4); observed_mask (L, h, w) bool and observed_depth (L, h, w) m on the ray
    grid of ``step`` ((h, w) = (320, 240) / step; ``image_to_grid`` brings full-resolution arrays there);
    free_margin: see ``depths_to_agreement``.
    -> the (P, L) terms of ``depths_to_agreement`` plus ``predicted_depth`` (P, L, h, w) float32 m.
    """
    predicted = gel_press.poses_to_gel_depths(mesh, T_world_object, T_world_sensors, step)
    terms = depths_to_agreement(observed_mask, observed_depth, predicted, free_margin)
    return {**terms, "predicted_depth": predicted}
