"""Light that drifts: a tactile image's colours brought back to those of its sensor's no-contact image.

The estimator reads contact as ``image - no_contact`` (autoencoder input, contact patch, render-and-compare),
so a global change of light is read as contact everywhere: a DIGIT's LEDs dim and warm with temperature
and age, and exposure changes. Such a change is modelled per colour channel ``c`` as a gain and a gamma
of the 8-bit value (what the no-contact image would look like under today's light):

    recorded_c = 255 * gain_c * (expected_c / 255) ** gamma_c

It is fitted, inverted, as ``expected_c = 255 * exp(a_c) * (recorded_c / 255) ** b_c`` (a straight line in
log values) on pairs of values at the same place in the image and in its no-contact image, both averaged
over blocks of ``BLOCK`` x ``BLOCK`` pixels first (the camera noise, 7 grey levels in the simulator, would
otherwise bias the fitted exponent towards 0: regression dilution). Where the gel is not touched the pairs
lie on that line up to noise; where it is, they scatter off it. A press often covers most of the gel, so
the line is not what most pairs follow but the tightest line that some do: per channel, a search over the
exponent (``EXPONENTS``) for the offsets that many pairs fit within ``TOLERANCE`` (a mode search,
deterministic), keeping the ``CANDIDATES`` densest distinct lines; then the combination of one line per
channel that the most blocks follow in all three channels at once, and iteratively reweighted least squares
(Tukey's biweight) on the blocks near it in all three. An untouched block follows the light in every
channel; a pressed one can fall on a line in one channel (a flat face pressed into most of the gel shifts
its colours almost uniformly), seldom on the same wrong combination in all three, which a search per channel
took for the light when a press left only the gel's corners (docs/real_sensors.md). Where a channel's
no-contact image has too little spread to tell a gamma from a gain (a flat background), the exponent stays
near 1 (ties go to the exponent nearest 1, and a weak prior in the refinement). The fit is applied as one
lookup table per channel.

``LightFit.trustworthy`` says whether the fit can be trusted: a drift far beyond what a unit's LEDs do
(``MAX_DRIFT``) is not, and is more often a press that covers nearly the whole gel, whose colours the
fit took for the light; such a fit is reported (``LightWarning``) and not applied.

Below what the fit can tell from a press, a uniform offset of a grey level or so still changes what the estimator
reads (the contact mask's thresholds sit about 2 grey levels of the smoothed difference above the noise): a no-contact
image recorded a grey level brighter or darker than today's exposure, or one from a camera that rounds its values where
the renderer truncates them. After the fit, the level at which the untouched gel sits against its no-contact image is
measured on the blocks that follow the fit (``untouched_level``); where it is ``LEVEL_TOLERANCE`` or more off the level
of the renderer's own images (``UNTOUCHED_LEVEL``), on which the databases, the autoencoder and the mask's thresholds
were made, the image is shifted onto it (``add_levels``: fractions of a grey level by ordered dithering).

Light that changes across the gel (one of a DIGIT's LEDs, each on its own side, drifting more than the others) is
not one gain per channel: after the fit, a plane of log gain per channel (``expected_c = 255 * exp(a_c + p_c v +
q_c u) * (recorded_c / 255) ** b_c``, v and u the place in the image from -1 to 1) is fitted on the blocks of the
image's rim only (``fit_shading``): a press reaches the rim last, and a plane fitted over the whole image also takes
up a large press's own shading, which a change of light cannot be told from there. It is kept where it is at least
``SHADING_MIN`` steep and makes many more of the image's blocks follow the light than the fit without it
(``SHADING_GAIN``: over a no-contact image whose colours change across the gel, as a unit's do, the exponent and a
plane can trade one for the other), and applied per pixel (``apply_light``).

A no-contact image of another unit than the image's is told by how little of the image follows the fit:
its LEDs light the gel in another pattern, which no change of light per channel maps onto this unit's, so
only scattered blocks agree with it by chance, where an image of the same unit agrees wherever the gel is
not pressed (``LightFit.from_another_unit``, ``unit_problems``; a ``UnitWarning``).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

BLOCK = 4  # pixels averaged per side before the fit
SEARCH_STRIDE = 2  # the mode search uses every 2nd block in each direction (a quarter of them)
EXPONENTS = np.round(np.arange(0.60, 1.6001, 0.04), 2)  # exponents b the mode search tries (the refinement is continuous)
TOLERANCE = 0.02  # log units (2 grey levels at 100): a pair fits a line within this in the mode search
BORDER_WEIGHT = (0.1, 1.0)  # a block's weight in the mode search: 0.1 at the centre, 1.1 mid-edge, 2.1 in a corner
TIE = 0.98  # exponents whose best count is within 2 % of the best are ties, won by the one nearest 1
CANDIDATES = 8  # distinct lines per channel whose combinations the joint search scores (8^3 = 512)
CANDIDATE_POOL = 3000  # the densest windows searched for them first (of about 26 x 1200)
WEIGHT_QUANTUM = 2.0**-20  # unit of the block weights in the joint search's integer counts
ITERATIONS = 10  # reweighting rounds
TUKEY_C = 4.685  # Tukey's biweight constant, in robust standard deviations (95 % efficiency)
MIN_SCALE = 0.005  # floor of the robust standard deviation of log residuals (half a grey level at 100)
PRIOR_WEIGHT = 1e-3  # per block, the weight of (b - 1)^2 beside the squared log residuals
VALID = (8.0, 247.0)  # block means outside this are clipped or nearly so, and not used

# Grey levels: a fit that moves an image by less, on average, is not applied (align_images). Under the no-contact
# image's own light the fit, which a press biases, moves an image by 1.28 grey levels at most on this renderer's
# scene sets and 1.53 on TACTO's (the paper's triplets); a press over most of the gel is taken for a change of
# light at 2.5 or more (real_sensors.md). A light 1.5 % dimmer, or 1.5-2 grey levels darker, moves it by 1.85-2.0:
# below 2.5 it was read as given, and so slight a change the contact mask reads as contact over the whole gel.
MIN_CHANGE = 1.75
# The share of an image's blocks, or of its rim's, that must follow its fit for its no-contact image to be
# taken for its own unit's. Measured on generated sets of two units (docs/real_sensors.md): against their own
# unit's no-contact image, at least 18 % of each image or of its rim follows (also on scenes pressed 2-3 mm
# deep, which leave the gel's corners only); against the other unit's (the paper's DIGIT or TACTO's, also
# mirrored or turned) at most 4.6 % of the image and 5.8 % of the rim: the joint search finds the combination
# of lines that the most blocks follow, and against another unit's pattern a few more happen to. The threshold sits between the two, a factor of
# about 1.7 from each.
MIN_AGREEMENT = 0.10
RIM = 3  # blocks: the image's rim, where a press reaches last (12 pixels)
# Known units fitted per image that disagrees with its no-contact image: the most alike by ``unit_likeness`` (of
# pixels averaged LIKENESS_BLOCK per side). On 480 images of the tuning sets, each sensor moved onto one of six units
# (scripts/real_setup_check.py's drawer), each image's own unit was the most alike of eight; two leave a margin.
SCREENED_UNITS = 2
LIKENESS_BLOCK = 16
# Log gain from the image centre to the middle of an edge: a plane of the light over the gel (fit_shading) at least
# this steep in some channel and direction may be applied. A ramp of +-5 % across the gel gives about 0.05; rendered
# presses over a synthetic no-contact image whose colours change across it, up to 0.024 with no ramp at all. Set on
# validation, offaxis and variation under real_setup_check.py's shading condition, where 0.02 and 0.03 gave the same
# estimates (docs/real_sensors.md).
SHADING_MIN = 0.03
# A plane is applied only where at least SHADING_GAIN times as many blocks follow it within SHADING_CLOSE (log value,
# a grey level at 100) in every channel as follow the fit without it. Under a ramp of +-5 % the fit without it holds
# a band through the centre (rendered presses: 2.0-2.5 times as many follow the plane); a plane traded for the
# exponent (over a no-contact image whose colours change across the gel, under a uniform drift) holds 0.96-1.2 times
# as many, with slopes of 0.05-0.06 (tests/test_photometric.py).
SHADING_GAIN = 1.5
SHADING_CLOSE = 0.01
SHADING_PRIOR = 1e-3  # per block, the weight of p^2 and q^2 (a plane's slopes) beside the squared log residuals
SHADING_ITERATIONS = 15  # reweighting rounds of fit_shading

# Grey levels (R, G, B): where the gel is not touched, how far the renderer's images sit from their no-contact image,
# as ``untouched_level`` measures it. The renderer adds its camera noise and truncates the sum (render.add_noise, as
# TACTO does), which takes half a grey level off every channel; the measure reads green and blue another 0.05-0.15
# lower on the pipeline's scenes. The mean over validation's 120 images (per image, a spread of 0.09 in red and 0.15
# in green and blue; docs/real_sensors.md).
UNTOUCHED_LEVEL = np.array([-0.51, -0.63, -0.65])
# Grey levels, the mean over channels: an image whose untouched level is this far or farther from UNTOUCHED_LEVEL
# is shifted onto it (align_images). The pipeline's scene sets' images under their own light sit within 0.28 of it
# (validation, offaxis, kinematic, calibration), the variation set's after their fit within 0.7, the paper's TACTO
# triplets within 0.4: none of them is shifted. A no-contact image one grey level off moves it by about 1.
LEVEL_TOLERANCE = 0.75
# The ordered-dither thresholds (a 4 x 4 Bayer matrix, in (0, 1)) with which ``add_levels`` rounds a fractional shift:
# over every 4 x 4 block of pixels the shift comes out whole to a 16th of a grey level.
BAYER = (np.array([[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]]) + 0.5) / 16.0

# Beyond these the light is not what a unit's LEDs drift to: its reading cannot be trusted.
MAX_DRIFT = {"gain": (0.67, 1.5), "gamma": (0.67, 1.5)}


@dataclass(frozen=True)
class LightFit:
    """How one image's light differs from its no-contact image's.

    log_gain, exponent: (3,) ``a_c``, ``b_c`` of the module docstring (the image -> no-contact mapping);
    residual: (3,) robust standard deviation, grey levels, of the no-contact image about the fitted
    mapping on the blocks that follow it; outliers: share of the blocks that do not (contact, or a
    no-contact image of another unit); applied: whether the image was changed (``align_images``);
    rim_agreement: share of the blocks within ``RIM`` of the image's edge that follow the fit; inliers:
    (rows, cols) bool, the blocks (``BLOCK`` pixels a side) that follow it; level: (3,) grey levels, the
    untouched gel's level against the no-contact image after the fit (``untouched_level``; None where not
    measured); level_shift: (3,) grey levels added to the image after the fit to bring that level to
    ``UNTOUCHED_LEVEL`` (``add_levels``), None where it was not shifted; shading: (3, 2) per channel the slopes
    (p, q) of the log gain's plane across the image (along its rows' index v and columns' index u, each -1 to 1;
    ``fit_shading``), None where the light is uniform (log_gain is then the same everywhere; with a plane, it is
    the image centre's).
    """

    log_gain: np.ndarray
    exponent: np.ndarray
    residual: np.ndarray
    outliers: float
    applied: bool = True
    rim_agreement: float = 1.0
    inliers: np.ndarray | None = field(default=None, repr=False)
    level: np.ndarray | None = None
    level_shift: np.ndarray | None = None
    shading: np.ndarray | None = None

    @property
    def gain(self) -> np.ndarray:
        """(3,) the drift's gain per channel (recorded = 255 * gain * (expected / 255) ** gamma)."""
        return np.exp(-self.log_gain / self.exponent)

    @property
    def gamma(self) -> np.ndarray:
        """(3,) the drift's gamma per channel."""
        return 1.0 / self.exponent

    @property
    def agreement(self) -> float:
        """The share of the image's blocks that follow the fit: the gel it does not press, when the no-contact
        image is of its own unit."""
        return 1.0 - self.outliers

    @property
    def from_another_unit(self) -> bool:
        """Whether so little of the image, and of its rim, follows the fit (``MIN_AGREEMENT``) that its
        no-contact image is likely another unit's (or the press covers nearly all of the gel, its rim too)."""
        return max(self.agreement, self.rim_agreement) < MIN_AGREEMENT

    @property
    def trustworthy(self) -> bool:
        """Whether the drift is one a unit's light can have (``MAX_DRIFT``)."""
        return not self.problems()

    def problems(self) -> list[str]:
        """What makes the fit untrustworthy, in words (empty when nothing does)."""
        out = []
        for name, values in (("gain", self.gain), ("gamma", self.gamma)):
            low, high = MAX_DRIFT[name]
            if np.any(values < low) or np.any(values > high):
                out.append(f"its light would differ by a {name} of {_rgb(values)} (a unit drifts within "
                           f"{low}-{high}): either the light changed that much, or the press covers so much "
                           "of the gel that it cannot be told from the light")
        return out

    def to_dict(self) -> dict:
        """Plain numbers for JSON output."""
        return {"gain": self.gain.round(4).tolist(), "gamma": self.gamma.round(4).tolist(),
                "residual": self.residual.round(2).tolist(), "outliers": round(float(self.outliers), 4),
                "applied": self.applied, "another_unit": self.from_another_unit,
                "level": None if self.level is None else np.round(self.level, 2).tolist(),
                "level_shift": None if self.level_shift is None else np.round(self.level_shift, 2).tolist(),
                "shading": None if self.shading is None else np.round(self.shading, 4).tolist()}


def _rgb(values: np.ndarray) -> str:
    return "/".join(f"{v:.2f}" for v in values)


IDENTITY = LightFit(np.zeros(3), np.ones(3), np.zeros(3), 0.0)


def block_means(image: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """(H, W, C) -> (H // block, W // block, C) float64 means of block x block pixels (the remainder cut)."""
    image = np.asarray(image)
    rows, cols = image.shape[0] // block, image.shape[1] // block
    x = np.asarray(image[: rows * block, : cols * block], dtype=np.float64)
    exact = image.dtype.kind in "ui" and image.dtype.itemsize <= 2 and block & (block - 1) == 0
    if exact and rows and cols and x.ndim == 3 and x.shape[2] <= 4:
        # The mean of a power of two of whole numbers under 2^16 is exact in float64 in any order of its sum, so
        # OpenCV's area resampling (a sum, then times 1 / block^2) gives NumPy's bits, 15 times faster.
        return cv2.resize(x, (cols, rows), interpolation=cv2.INTER_AREA).reshape(rows, cols, -1)
    return x.reshape(rows, block, cols, block, -1).mean(axis=(1, 3))


def _log_blocks(rec: np.ndarray, exp_: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``block_means`` (rows, cols, 3) of an image (rec) and of its no-contact image (exp_) -> their log values
    x and y (n, 3), ``log(max(value, 0.5) / 255)``, and which blocks are usable in every channel (n,) bool
    (``VALID`` in both)."""
    x = np.log(np.maximum(rec.reshape(-1, 3), 0.5) / 255.0)
    y = np.log(np.maximum(exp_.reshape(-1, 3), 0.5) / 255.0)
    usable = np.all((rec > VALID[0]) & (rec < VALID[1]) & (exp_ > VALID[0]) & (exp_ < VALID[1]), axis=-1).ravel()
    return x, y, usable


def _rim_blocks(shape: tuple[int, int]) -> np.ndarray:
    """(rows, cols) -> bool (rows, cols): the blocks within ``RIM`` of the image's edge."""
    rim = np.ones(shape, dtype=bool)
    rim[RIM:-RIM, RIM:-RIM] = False
    return rim


def line_candidates(x: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None,
                    k: int = CANDIDATES) -> np.ndarray:
    """Up to k distinct lines ``y = a + b x`` (b in ``EXPONENTS``) that many of the points (n,) fit within
    ``TOLERANCE`` (counted with ``weights`` (n,) when given), most first -> (m, 2) rows (a, b), m <= k.

    Row 0 is the line the most points fit (``mode_line``): a is the middle of the densest window of y - b x,
    ties (``TIE``) going to b nearest 1. The others are the next densest windows over all exponents, each
    kept only if it differs from every line kept before by more than ``TOLERANCE`` somewhere over the
    points' range (the windows next to a dense one hold nearly the same points: the same line again).
    All exponents at once: each row of residuals sorted, rows kept apart in one flat array by offsets
    larger than any residual's range."""
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64)
    residuals = y[None, :] - EXPONENTS[:, None] * x[None, :]  # (B, n)
    # Stable sorts throughout: equal values keep their order on every CPU (NumPy's default sort may be a SIMD
    # one that orders ties otherwise), so the sums below add the same weights in the same order.
    order = np.argsort(residuals, axis=1, kind="stable")
    r = np.take_along_axis(residuals, order, axis=1)
    span = float(r[:, -1].max() - r[:, 0].min()) + 2.0 * TOLERANCE
    flat = (r + span * np.arange(len(EXPONENTS))[:, None]).ravel()
    cumulative = np.concatenate([[0.0], np.cumsum(w[order].ravel())])
    end = np.searchsorted(flat, flat + TOLERANCE, side="right")
    inside = (cumulative[end] - cumulative[:-1]).reshape(r.shape)  # weight in [r, r + TOLERANCE] of each start
    best = np.argmax(inside, axis=1)
    counts = inside[np.arange(len(EXPONENTS)), best]
    ties = np.flatnonzero(counts >= TIE * counts.max())
    first = int(ties[np.argmin(np.abs(EXPONENTS[ties] - 1.0))])
    ends = (x.min(), float(np.median(x)), x.max())
    # The densest windows, behind the mode. Neighbouring starts and exponents repeat a line, so the next
    # distinct one may lie far down the order: the densest CANDIDATE_POOL first, all of them if too few.
    for pool in (CANDIDATE_POOL, inside.size):
        if pool < inside.size:  # every window at least as dense as the pool-th densest, in index order
            top = np.flatnonzero(inside.ravel() >= np.partition(inside.ravel(), inside.size - pool)[inside.size - pool])
        else:
            top = np.arange(inside.size)
        top = top[np.argsort(-inside.ravel()[top], kind="stable")]
        rows, starts = np.divmod(top, r.shape[1])
        rows, starts = np.concatenate([[first], rows]), np.concatenate([[best[first]], starts])
        lines = np.stack([r[rows, starts] + TOLERANCE / 2.0, EXPONENTS[rows]], axis=1)
        values = [lines[:, 0] + lines[:, 1] * e for e in ends]  # each line at the ends and middle of the range
        left = np.arange(len(lines))  # the lines neither kept nor repeating a kept one, densest first
        kept = []
        while len(left) and len(kept) < k:
            q = left[0]
            kept.append(q)
            far = np.abs(values[0][left] - values[0][q]) > TOLERANCE
            for v in values[1:]:
                far |= np.abs(v[left] - v[q]) > TOLERANCE
            left = left[far]
        if len(kept) == k or pool >= inside.size:
            break
    return lines[kept]


def mode_line(x: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> tuple[float, float]:
    """The line ``y = a + b x`` (b in ``EXPONENTS``) that the most of the points (n,) fit within
    ``TOLERANCE`` (counted with ``weights`` (n,) when given); a is the middle of the densest window of
    y - b x. Ties (``TIE``) go to b nearest 1 (``line_candidates``' first)."""
    a, b = line_candidates(x, y, weights, k=1)[0]
    return float(a), float(b)


def joint_lines(x: np.ndarray, y: np.ndarray, candidates: list[np.ndarray], weights: np.ndarray) -> np.ndarray:
    """The combination of one candidate line per channel that the most blocks follow in every channel at once.

    x, y: (n, C) log values of the image and of its no-contact image; candidates: C arrays (m_c, 2) of lines
    (a, b) (``line_candidates``); weights: (n,) each block's count. Returns (C, 2). An untouched block
    follows the light's line in all three channels at once; a pressed one may fall on some line in one
    channel, seldom on the same wrong combination in all three. Ties go to the earlier candidates."""
    # Counted in integers (weights in units of WEIGHT_QUANTUM): a float sum's order, and so its last bits and
    # which of two equal counts wins, would follow the BLAS kernel of the CPU (AVX2 or AVX-512).
    w = np.rint(np.asarray(weights, dtype=np.float64) / WEIGHT_QUANTUM).astype(np.int64)
    masks = [(np.abs(y[:, c][None, :] - lines[:, :1] - lines[:, 1:] * x[:, c][None, :]) <= TOLERANCE / 2.0).astype(np.int64)
             for c, lines in enumerate(candidates)]  # C arrays (m_c, n)
    follows = masks[0]  # (m_0 * ... * m_c, n): whether each block follows each combination of the channels so far
    for mask in masks[1:-1]:
        follows = (follows[:, None, :] * mask[None, :, :]).reshape(-1, mask.shape[1])
    count = (follows @ (masks[-1] * w).T).reshape([len(m) for m in masks])
    choice = np.unravel_index(int(np.argmax(count)), count.shape)
    return np.stack([lines[i] for lines, i in zip(candidates, choice)])


def refine_lines(x: np.ndarray, y: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Iteratively reweighted least squares (Tukey's biweight) of each channel's line, from ``lines`` (C, 2),
    on the blocks near the lines in every channel at once -> (lines (C, 2), those blocks (n,) bool).

    x, y: (n, C) log values of the image and of its no-contact image. A block counts only where it is near
    in all channels (a block off in one channel is pressed, whatever the others say). The scale is fixed:
    one estimated from the residuals would grow with every contact block let in."""
    scale = TOLERANCE / 2.0
    lines = np.array(lines, dtype=np.float64)
    # The channels side by side, each a contiguous row: each sum is the pairwise sum of one channel's row, the same
    # bits as fitting the channels one by one, at a tenth of the calls.
    xc, yc = np.ascontiguousarray(x.T), np.ascontiguousarray(y.T)  # (C, n)
    for _ in range(ITERATIONS):
        u = (yc - lines[:, :1] - lines[:, 1:] * xc) / (TUKEY_C * scale)  # (C, n)
        near = np.all(np.abs(u) < 1.0, axis=0)
        w = np.where(near[None, :], (1.0 - u**2) ** 2, 0.0)
        lines = _weighted_lines(xc, yc, w, PRIOR_WEIGHT * np.count_nonzero(w, axis=1))
    near = np.all(np.abs(y - lines[:, 0] - lines[:, 1] * x) < TUKEY_C * scale, axis=1)
    return lines, near


def border_weights(shape: tuple[int, int]) -> np.ndarray:
    """(rows, cols) how much a block counts in the mode search: ``BORDER_WEIGHT[0] + BORDER_WEIGHT[1] r^2``,
    r the block's distance from the image centre in half-sizes (1 at the middle of an edge). A press
    lights up a blob; the gel's border is the last place it reaches, so there the untouched gel is most
    often seen (a flat face pressed into the gel shifts its middle's colours almost uniformly, which a
    count over all blocks could take for the light)."""
    v, u = centred_coordinates(shape)
    return BORDER_WEIGHT[0] + BORDER_WEIGHT[1] * (v[:, None] ** 2 + u[None, :] ** 2)


def centred_coordinates(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) -> v (rows,), u (cols,): each row's and column's centre from -1 (first edge) to 1 (last);
    of blocks and of the pixels they average alike (a block's centre is its pixels' centre)."""
    rows, cols = shape
    return (np.arange(rows) + 0.5) / rows * 2.0 - 1.0, (np.arange(cols) + 0.5) / cols * 2.0 - 1.0


def _weighted_lines(x: np.ndarray, y: np.ndarray, w: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Per row c of x, y, w (C, n) and prior (C,), argmin over (a, b) of sum w (y - a - b x)^2 + prior_c (b - 1)^2
    -> (C, 2) rows (a, b); (0, 1) where that has no single answer."""
    wx = w * x
    sw, sx, sy = w.sum(axis=1), wx.sum(axis=1), (w * y).sum(axis=1)
    sxx, sxy = (wx * x).sum(axis=1) + prior, (wx * y).sum(axis=1) + prior
    det = sw * sxx - sx * sx
    ok = (sw > 0) & (det > 0)
    safe = np.where(ok, det, 1.0)
    return np.stack([np.where(ok, (sxx * sy - sx * sxy) / safe, 0.0), np.where(ok, (sw * sxy - sx * sy) / safe, 1.0)], axis=1)


def fit_light(image: np.ndarray, background: np.ndarray) -> LightFit:
    """How image (H, W, 3) uint8's light differs from its no-contact image background (H, W, 3) uint8
    (``fit_light_on_blocks`` of their ``block_means``)."""
    return fit_light_on_blocks(block_means(image), block_means(background))


def fit_light_on_blocks(rec: np.ndarray, exp_: np.ndarray) -> LightFit:
    """``fit_light`` from the ``block_means`` (rows, cols, 3) of the image (rec) and of its no-contact image (exp_).

    On blocks usable in every channel (``VALID``), each weighed by ``border_weights``: each channel's
    ``line_candidates`` from a quarter of them (``SEARCH_STRIDE``), the combination that the most of all of
    them follow in every channel at once (``joint_lines``), refined on the blocks near it (``refine_lines``).
    Fewer than 10 usable blocks: no change (gain and gamma 1), every block counted outside the fit."""
    shape = rec.shape[:2]
    x, y, usable = _log_blocks(rec, exp_)
    search = np.zeros(shape, dtype=bool)
    search[::SEARCH_STRIDE, ::SEARCH_STRIDE] = True
    searched = usable & search.ravel()
    if np.count_nonzero(searched) < 10:
        return LightFit(np.zeros(3), np.ones(3), np.zeros(3), 1.0, rim_agreement=0.0)
    weights = border_weights(shape).ravel()
    candidates = [line_candidates(x[searched, c], y[searched, c], weights[searched]) for c in range(3)]
    chosen = joint_lines(x[usable], y[usable], candidates, weights[usable])
    lines, near = refine_lines(x[usable], y[usable], chosen)
    inliers = np.zeros(usable.shape, dtype=bool)
    inliers[usable] = near
    r = y[usable][near] - lines[:, 0] - lines[:, 1] * x[usable][near]
    # The log spread in grey levels at the channel's median no-contact value.
    spread = np.maximum(1.4826 * np.median(np.abs(r), axis=0), MIN_SCALE) if near.any() else np.zeros(3)
    residual = spread * np.median(exp_.reshape(-1, 3), axis=0)
    outlier = ~inliers.reshape(shape)
    rim = _rim_blocks(shape)
    return LightFit(lines[:, 0].copy(), lines[:, 1].copy(), residual, float(outlier.mean()),
                    rim_agreement=float(1.0 - outlier[rim].mean()), inliers=inliers.reshape(shape))


def lookup_tables(fit: LightFit) -> np.ndarray:
    """(3, 256) uint8: per channel, each recorded value mapped to the no-contact image's light."""
    values = np.arange(256, dtype=np.float64)
    recorded = np.maximum(values, 0.5) / 255.0
    out = 255.0 * np.exp(fit.log_gain[:, None] + fit.exponent[:, None] * np.log(recorded)[None, :])
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def apply_light(image: np.ndarray, fit: LightFit) -> np.ndarray:
    """image (H, W, 3) uint8 -> the same under its no-contact image's light (``lookup_tables``; with a plane of
    the light, ``fit.shading``, each pixel's log gain from its place, rounded as the tables round)."""
    out = np.empty_like(image)
    if fit.shading is None:
        tables = lookup_tables(fit)
        for c in range(3):
            out[..., c] = tables[c][image[..., c]]
        return out
    v, u = centred_coordinates(image.shape[:2])
    log_recorded = np.log(np.maximum(np.arange(256, dtype=np.float64), 0.5) / 255.0)
    for c in range(3):
        p, q = fit.shading[c]
        log_values = (fit.log_gain[c] + fit.exponent[c] * log_recorded)[image[..., c]] + (p * v[:, None] + q * u[None, :])
        out[..., c] = np.clip(np.rint(255.0 * np.exp(log_values)), 0, 255).astype(np.uint8)
    return out


def fit_shading(rec: np.ndarray, exp_: np.ndarray, fit: LightFit) -> LightFit | None:
    """``fit`` with a plane of log gain per channel across the image (module docstring), from the ``block_means``
    (rows, cols, 3) of the image (rec) and of its no-contact image (exp_) -> the fit with ``shading``, its lines
    refitted beside the plane and its ``inliers`` and ``outliers`` those of the plane over the whole image; None
    where the plane is flatter than ``SHADING_MIN`` in every channel, fewer than 10 rim blocks follow it, or it does
    not make ``SHADING_GAIN`` times as many blocks follow the light within ``SHADING_CLOSE`` as the fit without it.

    Each channel ``y = a + b x + p v + q u`` (x, y the log values, v and u the block's place) from the fit's line
    and no plane, refined by Tukey's biweight as ``refine_lines`` refines the lines (the same scale; a block counted
    where near in all channels; the same prior on b, ``SHADING_PRIOR`` on p and q) on the rim's usable blocks
    (``RIM``, ``VALID``), ``SHADING_ITERATIONS`` rounds."""
    shape = rec.shape[:2]
    x, y, usable = _log_blocks(rec, exp_)
    rim = _rim_blocks(shape)
    v, u = (a.ravel() for a in np.meshgrid(*centred_coordinates(shape), indexing="ij"))
    on_rim = usable & rim.ravel()
    # Channels side by side as contiguous (C, n) rows; the normal equations' sums of products of [1, x, v, u] and y,
    # each product made once and weighed anew each round (elementwise sums, no BLAS: the same bits on every CPU).
    xr, yr = np.ascontiguousarray(x[on_rim].T), np.ascontiguousarray(y[on_rim].T)
    vr, ur = np.broadcast_to(v[on_rim], xr.shape), np.broadcast_to(u[on_rim], xr.shape)
    terms = [np.ones_like(xr), xr, vr, ur]
    pairs = [(i, j) for i in range(4) for j in range(i, 4)]
    products = np.stack([terms[i] * terms[j] for i, j in pairs] + [t * yr for t in terms], axis=1)  # (C, 14, n)
    params = np.stack([fit.log_gain, fit.exponent, np.zeros(3), np.zeros(3)], axis=1)  # (3, 4): a, b, p, q
    scale = TOLERANCE / 2.0
    rows, cols = np.array(pairs).T
    for _ in range(SHADING_ITERATIONS):
        predicted = params[:, :1] + params[:, 1:2] * xr + params[:, 2:3] * vr + params[:, 3:] * ur
        z = (yr - predicted) / (TUKEY_C * scale)
        near = np.all(np.abs(z) < 1.0, axis=0)
        if np.count_nonzero(near) < 10:
            return None
        w = np.where(near[None, :], (1.0 - z**2) ** 2, 0.0)
        sums = (products * w[:, None, :]).sum(axis=2)  # (C, 14)
        normal = np.zeros((3, 4, 4))
        normal[:, rows, cols] = normal[:, cols, rows] = sums[:, :len(pairs)]
        n = np.count_nonzero(w, axis=1)
        # The priors: b towards 1 (PRIOR_WEIGHT), the slopes towards 0 (SHADING_PRIOR), each per block weighed.
        prior = np.stack([np.zeros(3), PRIOR_WEIGHT * n, SHADING_PRIOR * n, SHADING_PRIOR * n], axis=1)
        normal[:, np.arange(4), np.arange(4)] += prior
        rhs = sums[:, len(pairs):] + prior * np.array([0.0, 1.0, 0.0, 0.0])
        params = np.linalg.solve(normal, rhs[..., None])[..., 0]
    if np.abs(params[:, 2:]).max() < SHADING_MIN:
        return None
    residuals = y - params[:, 0] - params[:, 1] * x - params[:, 2] * v[:, None] - params[:, 3] * u[:, None]
    inliers = usable & np.all(np.abs(residuals) < TUKEY_C * scale, axis=1)
    # Accepted only where the plane makes many more of the image's blocks follow the light closely than the fit
    # without it: a plane traded for the exponent (over a no-contact image whose colours change across the gel)
    # holds about as many as that fit; a real change of light across the gel holds far more.
    flat = y - fit.log_gain - fit.exponent * x
    follow_plane = np.count_nonzero(usable & np.all(np.abs(residuals) < SHADING_CLOSE, axis=1))
    follow_flat = np.count_nonzero(usable & np.all(np.abs(flat) < SHADING_CLOSE, axis=1))
    if follow_plane < SHADING_GAIN * follow_flat:
        return None
    return replace(fit, log_gain=params[:, 0].copy(), exponent=params[:, 1].copy(), shading=params[:, 2:].copy(),
                   inliers=inliers.reshape(shape), outliers=float(1.0 - inliers.mean()))


def untouched_level(image: np.ndarray, background: np.ndarray, inliers: np.ndarray) -> np.ndarray | None:
    """(3,) grey levels: per channel, the median over the blocks ``inliers`` (rows, cols) bool (a fit's, the gel
    it does not press) of image (H, W, 3) uint8 - background (H, W, 3) uint8, each block's mean first (``BLOCK``).
    None when fewer than 10 blocks are given."""
    return untouched_level_on_blocks(block_means(image), block_means(background), inliers)


def untouched_level_on_blocks(image_blocks: np.ndarray, background_blocks: np.ndarray,
                              inliers: np.ndarray) -> np.ndarray | None:
    """``untouched_level`` from the ``block_means`` (rows, cols, 3) of the image and of its no-contact image."""
    if np.count_nonzero(inliers) < 10:
        return None
    return np.median((image_blocks - background_blocks)[inliers], axis=0)


def add_levels(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """image (H, W, 3) uint8 + shift (3,) grey levels per channel -> uint8, clipped to 0..255. A fraction of a
    grey level is rounded by ordered dithering (``BAYER``): up at that share of the pixels, spread evenly, so that
    any 4 x 4 block of pixels moves by the shift to a 16th of a grey level; a whole shift moves every pixel by it."""
    h, w = image.shape[:2]
    thresholds = np.tile(BAYER, (h // 4 + 1, w // 4 + 1))[:h, :w, None]
    shifted = np.floor(image + np.asarray(shift, dtype=np.float64)[None, None, :] + thresholds)
    return np.clip(shifted, 0, 255).astype(np.uint8)


def apply_fit(image: np.ndarray, fit: LightFit) -> np.ndarray:
    """image (H, W, 3) uint8 -> what ``align_images`` made of it with this fit: brought to the no-contact image's
    light where the fit was applied (``apply_light``), then shifted by its ``level_shift`` where it has one. For
    images of the same unit after the one fitted (a stream's next frames)."""
    out = apply_light(image, fit) if fit.applied else image
    return out if fit.level_shift is None else add_levels(out, fit.level_shift)


def shift_to_untouched_level(image: np.ndarray, background_blocks: np.ndarray, fit: LightFit,
                             image_blocks: np.ndarray | None = None) -> tuple[np.ndarray, LightFit]:
    """An image (H, W, 3) uint8 after its fit (as ``align_images`` leaves it) and its no-contact image's
    ``block_means`` (rows, cols, 3) -> (the image, shifted onto ``UNTOUCHED_LEVEL`` where its ``untouched_level`` is
    ``LEVEL_TOLERANCE`` or more off it on average over channels; the fit with its ``level`` and ``level_shift``).
    image_blocks: the image's ``block_means`` where already made (the fit's own, when it was not applied). Left as it
    is: an image whose fit is not trustworthy or whose no-contact image looks like another unit's (its blocks that
    follow the fit are then not the untouched gel)."""
    if fit.inliers is None or not fit.trustworthy or fit.from_another_unit:
        return image, fit
    if image_blocks is None:
        image_blocks = block_means(image)
    level = untouched_level_on_blocks(image_blocks, background_blocks, fit.inliers)
    if level is None:
        return image, fit
    shift = UNTOUCHED_LEVEL - level
    if abs(float(shift.mean())) < LEVEL_TOLERANCE:
        return image, replace(fit, level=level)
    return add_levels(image, shift), replace(fit, level=level, level_shift=shift)


def align_images(images: np.ndarray, backgrounds: np.ndarray) -> tuple[np.ndarray, list[LightFit]]:
    """Each image (L, H, W, 3) uint8 brought to its own no-contact image's light (backgrounds (L, H, W, 3)
    uint8, one per image) -> (aligned images (L, H, W, 3) uint8, each image's ``LightFit``). Left as it
    is (``applied`` False): an image whose fit is not trustworthy, and one the fit would change by less
    than ``MIN_CHANGE`` grey levels on average: on images under their no-contact image's own light the
    fit, which a large press biases, moves them by about 1 grey level, and reading them so cost accuracy
    (docs/real_sensors.md). Light that changes across the gel is fitted as a plane per channel where it does
    (``fit_shading``). Then each is shifted onto the renderer's untouched level where it is far off it
    (``shift_to_untouched_level``)."""
    out, fits = [], []
    for image, background in zip(images, backgrounds):
        # Each image's and no-contact image's block means are made once, for the fit and the untouched level.
        image_blocks, background_blocks = block_means(image), block_means(background)
        fit = fit_light_on_blocks(image_blocks, background_blocks)
        if fit.trustworthy and not fit.from_another_unit:
            fit = fit_shading(image_blocks, background_blocks, fit) or fit
        aligned = apply_light(image, fit)
        if not fit.trustworthy or np.abs(aligned.astype(np.int16) - image).mean() < MIN_CHANGE:
            aligned, fit = image, replace(fit, applied=False)
        else:
            image_blocks = None  # the image changed: its level is read on the aligned image's blocks
        aligned, fit = shift_to_untouched_level(aligned, background_blocks, fit, image_blocks)
        out.append(aligned)
        fits.append(fit)
    return np.stack(out), fits


class LightWarning(UserWarning):
    """An image's light differs from its no-contact image's more than a unit's drift (``LightFit.problems``)."""


def unit_problems(images: np.ndarray, backgrounds: np.ndarray, fits: list[LightFit]) -> list[str | None]:
    """Per image (L, H, W, 3) uint8, a sentence when its no-contact image (backgrounds (L, H, W, 3) uint8, one
    per image) looks like another unit's (``LightFit.from_another_unit`` of its fit, fits as ``align_images``
    returned them), else None. When the image agrees instead with another sensor's no-contact image given,
    the sentence names it: no-contact images passed in another order than the sensors."""
    out = []
    for i, fit in enumerate(fits):
        if not fit.from_another_unit:
            out.append(None)
            continue
        text = (f"image {i}: its no-contact image looks like another DIGIT unit's: under any change of light only "
                f"{100 * fit.agreement:.1f} % of the image and {100 * fit.rim_agreement:.1f} % of its rim agree with "
                f"it, where an image of the same unit agrees on {100 * MIN_AGREEMENT:.0f} % or more of one of them "
                "unless pressed over all of the gel; read against it, contacts come out millimetres to centimetres off")
        others = [j for j in range(len(backgrounds)) if not np.array_equal(backgrounds[j], backgrounds[i])]
        matches = [(f.agreement, j) for j in others if not (f := fit_light(images[i], backgrounds[j])).from_another_unit]
        if matches:
            agreement, j = max(matches)
            text += (f"; it agrees with sensor {j}'s no-contact image on {100 * agreement:.0f} %: were the "
                     "no-contact images given in another order than the sensors?")
        else:
            text += ("; record this unit's no-contact image (a frame with nothing touching) and pass it, or "
                     "estimate it from several scenes (--background from-scenes)")
        out.append(text)
    return out


class UnitWarning(LightWarning):
    """An image's no-contact image looks like another unit's (``unit_problems``)."""


def from_another_unit(fits: list[LightFit] | None) -> tuple[int, ...]:
    """The images whose no-contact image looks like another unit's (``LightFit.from_another_unit``), by index in
    fits as ``align_images`` returned them; none for None (the light not aligned)."""
    return tuple(i for i, fit in enumerate(fits or ()) if fit.from_another_unit)


class KnownUnitWarning(UnitWarning):
    """An image whose no-contact image looked like another unit's was read against a known unit's that it agrees
    with (``known_units_agreeing``)."""


def unit_likeness(image: np.ndarray, units: Mapping[str, np.ndarray],
                  ranks: Mapping[str, np.ndarray] | None = None) -> dict[str, float]:
    """How alike an image (H, W, 3) uint8 and each unit's no-contact image (units: name -> (H, W, 3) uint8) are under
    any change of light that keeps the order of brightness in each channel (a gain and a gamma): the rank correlation
    (Spearman's) of their ``block_means`` of ``LIKENESS_BLOCK`` pixels, the least over the three channels; name ->
    [-1, 1]. A press changes the order only where it is, so an image of the unit stays near 1 where another unit's
    LEDs, laid out otherwise, give far less: over the 480 images of scripts/real_setup_check.py's drawer on the four
    tuning sets, at least 0.76 against their own unit and at most 0.59 against the seven others. ranks: the units'
    ``unit_ranks``, when a caller compares several images with the same units (made here when None)."""
    ranks = unit_ranks(units) if ranks is None else ranks
    mine = _standard_ranks(block_means(image, LIKENESS_BLOCK))
    return {name: float(np.min(np.sum(mine * ranked, axis=0))) for name, ranked in ranks.items()}


def unit_ranks(units: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Units' no-contact images (name -> (H, W, 3) uint8) -> name -> the ranks ``unit_likeness`` compares an image's
    with (``_standard_ranks`` of their ``block_means``), made once for all the images of a call."""
    return {name: _standard_ranks(block_means(background, LIKENESS_BLOCK)) for name, background in units.items()}


def _standard_ranks(blocks: np.ndarray) -> np.ndarray:
    """Block means (rows, cols, 3) -> their ranks within each channel (n, 3), centred and scaled to unit norm, so
    that the dot product of two is their rank correlation (ties ranked in the blocks' order)."""
    ranks = np.argsort(np.argsort(blocks.reshape(-1, blocks.shape[-1]), axis=0, kind="stable"), axis=0,
                       kind="stable").astype(np.float64)
    ranks -= ranks.mean(axis=0)
    return ranks / np.maximum(np.linalg.norm(ranks, axis=0), 1e-12)


def known_units_agreeing(images: np.ndarray, fits: list[LightFit], units: Mapping[str, np.ndarray]
                         ) -> dict[int, tuple[str, LightFit]]:
    """For each image (L, H, W, 3) uint8 whose fit against its no-contact image (fits as ``align_images`` returned
    them) takes that no-contact image for another unit's (``LightFit.from_another_unit``), the known unit whose
    no-contact image it agrees with most (``LightFit.agreement``) among those it does not take for another unit's:
    {image index: (the unit's name, the image's fit against it)}. units: name -> no-contact image (H, W, 3) uint8.
    Images that agree with no known unit, and those that agreed with their own, are left out. Each image is fitted
    against the ``SCREENED_UNITS`` units most alike it (``unit_likeness``) only: a fit takes 16-20 ms, a lab's
    drawer of units would cost a second an estimate."""
    out, ranks = {}, None
    for i, fit in enumerate(fits):
        if not fit.from_another_unit:
            continue
        ranks = unit_ranks(units) if ranks is None else ranks
        likeness = unit_likeness(images[i], units, ranks)
        screened = sorted(units, key=lambda name: -likeness[name])[:SCREENED_UNITS]
        agreeing = [(f.agreement, name, f) for name in screened
                    if not (f := fit_light(images[i], units[name])).from_another_unit]
        if agreeing:
            _, name, f = max(agreeing, key=lambda a: a[0])
            out[i] = (name, f)
    return out


def warn_about_known_units(found: Mapping[int, tuple[str, LightFit]], stacklevel: int = 4) -> None:
    """A ``KnownUnitWarning`` per image read against a known unit's no-contact image (``known_units_agreeing``'s
    answer), naming the unit. stacklevel: as ``warnings.warn``'s."""
    for i, (name, fit) in sorted(found.items()):
        warnings.warn(f"image {i}: its no-contact image looked like another DIGIT unit's, and the image agrees with "
                      f"{name}'s on {100 * fit.agreement:.0f} % of its blocks: read against that one. Pass this "
                      "unit's own no-contact image (a frame with nothing touching) for the best reading",
                      KnownUnitWarning, stacklevel=stacklevel)


def warn_about_light(images: np.ndarray, backgrounds: np.ndarray, fits: list[LightFit], stacklevel: int = 4) -> None:
    """What cannot be trusted in reading each image (L, H, W, 3) against its no-contact image (backgrounds (L,
    H, W, 3)), fits as ``align_images`` returned them, naming the image (sensor order): a ``UnitWarning`` where
    the no-contact image looks like another unit's (``unit_problems``; its fit's drift then says nothing of
    the light), else a ``LightWarning`` per problem of its fit (``LightFit.problems``). stacklevel: as
    ``warnings.warn``'s; 4 names the line that called ``Estimator.estimate``."""
    for i, (fit, unit) in enumerate(zip(fits, unit_problems(images, backgrounds, fits))):
        if unit is not None:
            warnings.warn(unit, UnitWarning, stacklevel=stacklevel)
            continue
        for problem in fit.problems():
            warnings.warn(f"image {i}: {problem}; read as given, without aligning its light (if the light did "
                          "change, record its no-contact image again)", LightWarning, stacklevel=stacklevel)


def background_from_images(images: np.ndarray, min_images: int = 5) -> np.ndarray | None:
    """A unit's no-contact image (H, W, 3) uint8 estimated from several of its images (n, H, W, 3) uint8 that
    touch in different places: each pixel's median over them. None for fewer than ``min_images`` (a pixel
    touched in half of the images or more would take the contact's colour)."""
    images = np.asarray(images)
    if len(images) < min_images:
        return None
    return np.median(images, axis=0).round().astype(np.uint8)
