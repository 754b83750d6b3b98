"""Comparing simulated DIGIT images with reference ones (the paper's TACTO renders): pure functions.

Both images of a pair are compared through their difference from the same no-contact background, blurred
to average the sensor noise out (N(0, 7) per pixel becomes about N(-0.5, 0.8) after the default 15x15
blur, the -0.5 from TACTO's truncation to integers):

- contact mask: where the blurred difference exceeds ``threshold`` grey levels in any channel;
- IoU of the two contact masks;
- Pearson correlation of the two blurred difference images (all pixels and channels).

Images are (H, W, 3) uint8 or float arrays in the same channel order as the background.
"""

from __future__ import annotations

import cv2
import numpy as np

from tactile6d.sim.gel_press import mask_iou

MASK_BLUR_KSIZE = 15  # Gaussian kernel, pixels (sigma 2.6)
MASK_THRESHOLD = 4.0  # grey levels; ~5 noise std after the blur, so that pure noise trips almost no pixel


def blurred_difference(image: np.ndarray, background: np.ndarray, blur_ksize: int = MASK_BLUR_KSIZE) -> np.ndarray:
    """(H, W, 3) image and background -> (H, W, 3) float32: Gaussian-blurred ``image - background``."""
    diff = np.asarray(image, dtype=np.float32) - np.asarray(background, dtype=np.float32)
    return cv2.GaussianBlur(diff, (blur_ksize, blur_ksize), 0)


def contact_mask(
    image: np.ndarray,
    background: np.ndarray,
    blur_ksize: int = MASK_BLUR_KSIZE,
    threshold: float = MASK_THRESHOLD,
) -> np.ndarray:
    """(H, W) bool: pixels whose blurred difference from the background exceeds ``threshold`` in any channel."""
    return np.abs(blurred_difference(image, background, blur_ksize)).max(axis=-1) > threshold


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two arrays of the same shape, flattened; NaN when either is constant."""
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    if a.shape != b.shape:
        raise ValueError(f"array sizes differ: {a.size} vs {b.size}")
    a, b = a - a.mean(), b - b.mean()
    denominator = np.sqrt(np.dot(a, a) * np.dot(b, b))
    return float("nan") if denominator == 0 else float(np.dot(a, b) / denominator)


def compare(
    reference: np.ndarray,
    simulated: np.ndarray,
    background: np.ndarray,
    blur_ksize: int = MASK_BLUR_KSIZE,
    threshold: float = MASK_THRESHOLD,
) -> dict:
    """IoU of the contact masks and correlation of the blurred differences -> {"iou": float, "corr": float}."""
    pair = compare_imprints(reference, simulated, background, blur_ksize, threshold)
    return {"iou": pair["iou"], "corr": pair["corr"]}


def compare_imprints(
    reference: np.ndarray,
    simulated: np.ndarray,
    background: np.ndarray,
    blur_ksize: int = MASK_BLUR_KSIZE,
    threshold: float = MASK_THRESHOLD,
) -> dict:
    """``compare``'s figures and two more, each blurred difference computed once -> {"iou", "corr", "touched":
    (whether the reference's mask has a pixel, whether the simulated's has), "strength": the simulated image's mean
    absolute blurred difference over both masks against the reference's (NaN where neither shows contact)}. The
    strength tells a press drawn brighter or darker, which IoU and correlation do not see."""
    diff_ref = blurred_difference(reference, background, blur_ksize)
    diff_sim = blurred_difference(simulated, background, blur_ksize)
    mask_ref = np.abs(diff_ref).max(axis=-1) > threshold
    mask_sim = np.abs(diff_sim).max(axis=-1) > threshold
    both = mask_ref | mask_sim
    strength = float(np.abs(diff_sim[both]).mean() / np.abs(diff_ref[both]).mean()) if both.any() else float("nan")
    return {"iou": float(mask_iou(mask_ref, mask_sim)), "corr": pearson(diff_ref, diff_sim),
            "touched": (bool(mask_ref.any()), bool(mask_sim.any())), "strength": strength}


def imprint_view(image: np.ndarray, background: np.ndarray, gain: float = 4.0) -> np.ndarray:
    """(H, W, 3) -> (H, W, 3) uint8: ``128 + gain x`` the blurred difference from the background."""
    return np.clip(128.0 + gain * blurred_difference(image, background), 0, 255).astype(np.uint8)


def montage(rows: list[tuple[str, np.ndarray, np.ndarray]], background: np.ndarray, gain: float = 4.0,
            names: tuple[str, str] = ("paper", "ours")) -> np.ndarray:
    """Side-by-side panels, one row per (label, reference, simulated) -> (n x (H + 20), 3 x W, 3) uint8.

    Panels: reference imprint | simulated imprint | reference - simulated, each shown as 128 + gain x the
    blurred difference, so grey means no difference. Labels are drawn above each row, the panels titled
    by ``names`` (the reference's, the simulated's); the channel order of the output is that of the inputs.
    """
    bands = []
    for label, reference, simulated in rows:
        ref = blurred_difference(reference, background)
        sim = blurred_difference(simulated, background)
        panels = [ref, sim, ref - sim]
        row = np.concatenate([np.clip(128.0 + gain * p, 0, 255).astype(np.uint8) for p in panels], axis=1)
        header = np.full((20, row.shape[1], 3), 255, dtype=np.uint8)
        width = reference.shape[1]
        for k, title in enumerate([f"{label}: {names[0]}", names[1], f"{names[0]} - {names[1]}"]):
            cv2.putText(header, title, (4 + k * width, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        bands.append(np.concatenate([header, row], axis=0))
    return np.concatenate(bands, axis=0)
