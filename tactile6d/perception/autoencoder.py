"""The object-agnostic tactile autoencoder (docs/design.md, The method; the paper's Sec. III-A, after
Sundermeyer et al.'s augmented autoencoder).

Architecture: 4 convolutions (kernel 5, stride 2, ReLU) and a linear layer to a 128-d latent ``h``; the
decoder mirrors it (linear + ReLU, then 4 blocks of nearest 2x upsampling and a kernel-5 convolution, ReLU
on all but the last, which outputs the 3 colour channels with no activation because its target is signed).
Loss: bootstrapped L2, the mean of the largest ``bootstrap_fraction`` of each image's per-pixel squared
errors (summed over colour channels), so that the small contact patch is not drowned by the flat rest.

What the model sees. The tactile signal is the change from the no-contact image, so the model is fed
``(image - background)``, averaged over blocks down to ``input_height x input_width`` (area
interpolation, which also averages the sensor noise away), optionally divided by its own peak
(``peak_floor``) plus a constant (``input_offset``), both off by default (below), and divided per colour
channel by its RMS over the training split. The no-contact image therefore maps to the same uniform
input (zero by default) whatever background the images were rendered over, and the same model serves
databases and real images rendered over different backgrounds. What defines this (input size, peak
floor, offset, per-channel scale) forms ``Normalisation`` and is saved with the checkpoint.

Peak normalisation (``peak_floor``; null turns it off, as in the paper). Each image's difference is
divided by its peak, the largest colour-summed ``|difference|`` over its pixels, or by ``peak_floor``
where the peak is smaller (so that the sensor noise of a no-contact image stays near zero instead of
being blown up). The model then sees the imprint's shape at unit contrast, not how hard the gel was
pressed: the ratio of changed area to peak tells edge from corner contacts apart better than the
changed area alone.

Input offset (``input_offset``; 0 turns it off). A uniform level added to every input pixel, a synthetic
background in units of the peak. Without it the no-contact input is all zeros, so ``h_nc`` =
encoder(0) is set by the biases alone; the latents of contacts then point past perpendicular to it and
the angle saturates. With it the no-contact input is the level on which every training imprint sits, and
the angle grows with the imprint over a wider range.

Both transforms stay off by default: they raised the AUROCs a little but not the pose accuracy on the
validation scenes (docs/autoencoder.md).

Angle ranking (``rank_weight``, ``rank_margin``; weight 0 turns it off, as in the paper). Reconstruction
alone does not make the angle to no contact mean anything in particular; selection relies on it telling
contact types apart. The training images carry contact types from the classifier that labels the YCB
database points (tactile6d.sim.contact_types, applied to the superquadric mesh by make_training_set), so the loss
adds ``rank_weight`` times a hinge on the cosine to the no-contact latent (``angle_ranking_loss``): within
each batch a corner should sit at least ``rank_margin`` closer in cosine to no contact than an edge, an
edge than a flat patch; curved contacts are not ranked. The no-contact latent is re-encoded with every
batch. The model still never sees an object image; the AUROCs in docs/autoencoder.md measure how far an
ordering learnt on superquadrics carries over to the YCB objects under the same labelling rule.

Arrays: images are uint8 ``(n, 320, 240, 3)`` (rows along the sensor's z axis, 240 columns along y; the
colour order is whatever the caller uses, consistently); a background is ``(320, 240, 3)`` (``encode``
also takes ``(n, 320, 240, 3)``, one per image). Model tensors are float32 ``(n, 3, input_height,
input_width)``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from tactile6d.core.errors import ArtifactError, ConfigError, InputError

CHECKPOINT_FORMAT = "tactile6d-autoencoder-v1"

_CHECKPOINT_KEYS = ("format", "state_dict", "norm", "cfg", "history")
# Images preprocessed at once: bounds the float32 copy of full-size images (about 0.9 MB each).
_PREPROCESS_CHUNK = 256
# Full-size images turned into float differences at once (about 0.9 MB each): small enough for the buffer to
# be reused from memory already mapped (see _resized_difference).
_DIFFERENCE_CHUNK = 8


@dataclass(frozen=True)
class AEConfig:
    """The ``ae`` config section (``conf/ae/*.yaml``), validated."""

    input_height: int
    input_width: int
    channels: tuple[int, int, int, int]
    kernel_size: int
    latent_dim: int
    bootstrap_fraction: float
    epochs: int
    batch_size: int
    learning_rate: float
    val_fraction: float
    threads: int
    device: str
    peak_floor: float | None
    input_offset: float
    rank_weight: float
    rank_margin: float

    @classmethod
    def from_cfg(cls, cfg: Mapping | AEConfig) -> AEConfig:
        """Read the fields from a mapping (dict or DictConfig); extra keys (``seed``) are ignored."""
        if isinstance(cfg, AEConfig):
            return cfg
        missing = [name for name in cls.__dataclass_fields__ if name not in cfg]
        if missing:
            raise ConfigError(f"ae config lacks keys {missing}")
        channels = tuple(int(c) for c in cfg["channels"])
        out = cls(
            input_height=int(cfg["input_height"]),
            input_width=int(cfg["input_width"]),
            channels=channels,
            kernel_size=int(cfg["kernel_size"]),
            latent_dim=int(cfg["latent_dim"]),
            bootstrap_fraction=float(cfg["bootstrap_fraction"]),
            epochs=int(cfg["epochs"]),
            batch_size=int(cfg["batch_size"]),
            learning_rate=float(cfg["learning_rate"]),
            val_fraction=float(cfg["val_fraction"]),
            threads=int(cfg["threads"]),
            device=str(cfg["device"]),
            peak_floor=None if cfg["peak_floor"] is None else float(cfg["peak_floor"]),
            input_offset=float(cfg["input_offset"]),
            rank_weight=float(cfg["rank_weight"]),
            rank_margin=float(cfg["rank_margin"]),
        )
        if len(channels) != 4 or min(channels) < 1:
            raise ConfigError(f"ae.channels must be 4 positive integers, got {list(channels)}")
        if out.kernel_size % 2 != 1:
            raise ConfigError(f"ae.kernel_size must be odd, got {out.kernel_size}")
        if not 0.0 < out.bootstrap_fraction <= 1.0:
            raise ConfigError(f"ae.bootstrap_fraction must be in (0, 1], got {out.bootstrap_fraction}")
        if not 0.0 <= out.val_fraction < 1.0:
            raise ConfigError(f"ae.val_fraction must be in [0, 1), got {out.val_fraction}")
        if out.device not in ("auto", "cpu", "cuda"):
            raise ConfigError(f"ae.device must be auto, cpu or cuda, got {out.device!r}")
        if not np.isfinite(out.input_offset):
            raise ConfigError(f"ae.input_offset must be a finite number, got {out.input_offset}")
        if not (np.isfinite(out.rank_weight) and out.rank_weight >= 0.0):
            raise ConfigError(f"ae.rank_weight must be >= 0 (0: reconstruction loss only), got {out.rank_weight}")
        if not (np.isfinite(out.rank_margin) and 0.0 <= out.rank_margin <= 2.0):
            raise ConfigError(f"ae.rank_margin must be in [0, 2] (a difference of cosines), got {out.rank_margin}")
        if out.peak_floor is not None and not out.peak_floor > 0:
            raise ConfigError(f"ae.peak_floor must be null (off) or > 0, got {out.peak_floor}")
        if min(out.input_height, out.input_width, out.latent_dim, out.epochs, out.batch_size, out.threads) < 1:
            raise ConfigError("ae sizes, epochs, batch_size and threads must be positive")
        return out


@dataclass(frozen=True)
class Normalisation:
    """How images become model input: ``(image - background)`` area-resized to (height, width), divided by
    its peak floored at ``peak_floor`` (None: not), plus ``offset``, then / scale.

    ``scale`` (3,) is the per-channel RMS of that input before the division, over the training split.
    """

    height: int
    width: int
    scale: tuple[float, float, float]
    peak_floor: float | None
    offset: float

    def to_dict(self) -> dict:
        return {"height": self.height, "width": self.width, "scale": list(self.scale), "peak_floor": self.peak_floor,
                "offset": self.offset}

    @classmethod
    def from_dict(cls, d: Mapping) -> Normalisation:
        scale = tuple(float(s) for s in d["scale"])
        if len(scale) != 3 or not all(np.isfinite(scale)) or min(scale) <= 0.0:
            raise ValueError(f"scale must be 3 positive numbers, got {scale}")
        floor = d["peak_floor"]
        if floor is not None and not float(floor) > 0.0:
            raise ValueError(f"peak_floor must be None or > 0, got {floor}")
        return cls(height=int(d["height"]), width=int(d["width"]), scale=scale,
                   peak_floor=None if floor is None else float(floor), offset=float(d["offset"]))


# --- the network -------------------------------------------------------------------------------------


def _halved(size: int) -> int:
    """Output length of a stride-2 convolution with 'same' padding: ceil(size / 2)."""
    return (size + 1) // 2


def _upsample2(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Nearest 2x upsampling, cropped to ``size`` (odd encoder sizes round up).

    Written with expand/reshape, whose backward is a plain sum, because CUDA's nearest-upsample backward
    is non-deterministic.
    """
    n, c, h, w = x.shape
    up = x[:, :, :, None, :, None].expand(n, c, h, 2, w, 2).reshape(n, c, 2 * h, 2 * w)
    return up[:, :, : size[0], : size[1]]


class TactileAutoencoder(nn.Module):
    """Conv autoencoder: ``encode`` (n, 3, H, W) -> (n, latent_dim); ``decode`` back; ``forward`` both."""

    def __init__(self, height: int, width: int, channels: tuple[int, ...], latent_dim: int, kernel_size: int):
        super().__init__()
        pad = kernel_size // 2
        # Spatial size at each encoder level; the decoder upsamples back through the same sizes.
        self.sizes = [(height, width)]
        for _ in channels:
            h, w = self.sizes[-1]
            self.sizes.append((_halved(h), _halved(w)))
        ins = (3, *channels[:-1])
        self.encoder_convs = nn.ModuleList(
            nn.Conv2d(i, o, kernel_size, stride=2, padding=pad) for i, o in zip(ins, channels)
        )
        self.bottleneck = (channels[-1], *self.sizes[-1])
        flat = int(np.prod(self.bottleneck))
        self.to_latent = nn.Linear(flat, latent_dim)
        self.from_latent = nn.Linear(latent_dim, flat)
        outs = (*reversed(channels[:-1]), 3)
        self.decoder_convs = nn.ModuleList(
            nn.Conv2d(i, o, kernel_size, stride=1, padding=pad) for i, o in zip(reversed(channels), outs)
        )

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """(n, 3, H, W) -> (n, latent_dim)."""
        for conv in self.encoder_convs:
            x = F.relu(conv(x))
        return self.to_latent(x.flatten(1))

    def decode(self, h: torch.Tensor) -> torch.Tensor:
        """(n, latent_dim) -> (n, 3, H, W)."""
        x = F.relu(self.from_latent(h)).view(-1, *self.bottleneck)
        last = len(self.decoder_convs) - 1
        for k, conv in enumerate(self.decoder_convs):
            x = conv(_upsample2(x, self.sizes[last - k]))
            if k < last:
                x = F.relu(x)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))


def build_model(cfg: Mapping | AEConfig) -> TactileAutoencoder:
    """A freshly initialised model (torch's default init, from the global RNG) for an ``ae`` config."""
    c = AEConfig.from_cfg(cfg)
    return TactileAutoencoder(c.input_height, c.input_width, c.channels, c.latent_dim, c.kernel_size)


def bootstrapped_l2(recon: torch.Tensor, target: torch.Tensor, fraction: float) -> torch.Tensor:
    """(n, 3, H, W) x2 -> scalar: mean over images of the mean of the top ``fraction`` per-pixel errors."""
    err = ((recon - target) ** 2).sum(dim=1).flatten(1)
    k = max(1, round(fraction * err.shape[1]))
    return err.topk(k, dim=1, sorted=False).values.mean()


def angle_ranking_loss(cos_nc: torch.Tensor, sharpness: torch.Tensor, margin: float) -> torch.Tensor:
    """Hinge loss that orders latent angles by how sharp the contact is (module docstring).

    cos_nc (n,): cosine similarity of each image's latent to the no-contact latent, i.e. cos(angle);
    sharpness (n,) int: a rank (0 flat, 1 edge, 2 corner) or -1 for images left out (curved contacts).
    For every pair (i, j) with sharpness[i] > sharpness[j] >= 0, the sharper contact i should lie closer
    to no contact: ``max(0, margin - (cos_nc[i] - cos_nc[j]))``. Returns the mean over those pairs, or 0
    when the batch has none.
    """
    ordered = (sharpness[:, None] > sharpness[None, :]) & (sharpness[None, :] >= 0)
    if not bool(ordered.any()):
        return cos_nc.new_zeros(())
    return torch.relu(margin - (cos_nc[:, None] - cos_nc[None, :]))[ordered].mean()


# --- input preprocessing -----------------------------------------------------------------------------


def _check_images(images, background) -> None:
    """images (n, rows, cols, 3) with one background (rows, cols, 3) for all or (n, rows, cols, 3), one each."""
    if images.ndim != 4 or images.shape[-1] != 3:
        raise InputError(f"tactile images must be (n, rows, cols, 3), got shape {tuple(images.shape)}")
    bg_shape = tuple(np.shape(background))
    if bg_shape != tuple(images.shape[1:]) and bg_shape != tuple(images.shape):
        raise InputError(f"background shape {bg_shape} does not match image shape {tuple(images.shape[1:])} "
                         f"(one for all) nor {tuple(images.shape)} (one per image)")


def _backgrounds_of(background, sl: slice):
    """The background(s) of the images in slice ``sl``: the one for all, or theirs of one per image."""
    return background[sl] if np.ndim(background) == 4 else background


def _resized_difference(images: np.ndarray, background: np.ndarray, height: int, width: int) -> torch.Tensor:
    """uint8 (n, R, C, 3), (R, C, 3) or (n, R, C, 3) -> float32 (n, 3, height, width): area-resized
    ``image - background``.

    The full-size float differences go through one small buffer, _DIFFERENCE_CHUNK images at a time: a
    fresh (n, R, C, 3) float array per call costs more in page faults than the arithmetic itself (1.5 s
    against 0.15 s for 256 images on a 2-core VM). The values are exact integers and each output pixel
    sums its own window in a fixed order, so the bits do not depend on the chunking.
    """
    images = np.asarray(images)
    per_image = np.ndim(background) == 4
    background_f = torch.from_numpy(np.asarray(background, dtype=np.float32))
    n = images.shape[0]
    out = torch.empty((n, 3, height, width), dtype=torch.float32)
    buffer = torch.empty((min(n, _DIFFERENCE_CHUNK), *images.shape[1:]), dtype=torch.float32)
    for sl in _chunks(n, _DIFFERENCE_CHUNK):
        diff = buffer[: sl.stop - sl.start]
        diff.copy_(torch.from_numpy(np.ascontiguousarray(images[sl])))
        diff.sub_(background_f[sl] if per_image else background_f)
        # permute gives the channels-last strides the (n, R, C, 3) images have, as before the buffer was used
        out[sl] = F.interpolate(diff.permute(0, 3, 1, 2), size=(height, width), mode="area")
    return out


def divide_by_peak(diffs: torch.Tensor, floor: float | None) -> torch.Tensor:
    """Resized differences (n, 3, H, W) -> each divided by max(its peak, floor), the peak being the largest
    colour-summed |difference| over its pixels (module docstring); unchanged when floor is None."""
    if floor is None:
        return diffs
    peak = diffs.abs().sum(dim=1).amax(dim=(1, 2)).clamp(min=float(floor))
    return diffs / peak[:, None, None, None]


def _unscaled_input(images, background, height: int, width: int, peak_floor: float | None, offset: float):
    """uint8 (n, R, C, 3), (R, C, 3) -> float32 (n, 3, height, width): the model input before the per-channel
    scale, i.e. the resized difference, peak-normalised (``peak_floor``) and offset. Shared by training
    (which fits the scale on it) and ``preprocess``."""
    return divide_by_peak(_resized_difference(images, background, height, width), peak_floor) + offset


def _chunks(n: int, size: int) -> Iterator[slice]:
    for start in range(0, n, size):
        yield slice(start, min(start + size, n))


def preprocess(images, background: np.ndarray, norm: Normalisation) -> torch.Tensor:
    """Images uint8 (n, 320, 240, 3) (a NumPy array or anything sliceable, e.g. an h5py dataset) and the
    no-contact background (320, 240, 3), or (n, 320, 240, 3) one per image -> model input float32
    (n, 3, norm.height, norm.width).

    Converted in chunks, so a large h5py dataset is never held as float in memory at full size.
    """
    _check_images(images, background)
    scale = torch.tensor(norm.scale, dtype=torch.float32)[None, :, None, None]
    out = torch.empty((images.shape[0], 3, norm.height, norm.width), dtype=torch.float32)
    for sl in _chunks(images.shape[0], _PREPROCESS_CHUNK):
        out[sl] = _unscaled_input(images[sl], _backgrounds_of(background, sl), norm.height, norm.width,
                                  norm.peak_floor, norm.offset) / scale
    return out


def fit_normalisation(
    diffs: torch.Tensor, height: int, width: int, peak_floor: float | None = None, offset: float = 0.0
) -> Normalisation:
    """Resized differences (n, 3, H, W) of the training split, already peak-normalised with ``peak_floor``
    and offset by ``offset`` -> Normalisation with their per-channel RMS (and those two settings).

    A channel that never changes (RMS 0) keeps scale 1 rather than dividing by zero. Accumulated in
    float64 chunk by chunk, so no full-size float64 copy is made.
    """
    sum_sq = torch.zeros(3, dtype=torch.float64)
    for sl in _chunks(diffs.shape[0], _PREPROCESS_CHUNK):
        sum_sq += diffs[sl].double().pow(2).sum(dim=(0, 2, 3))
    # NumPy's sqrt, IEEE's correctly rounded one: torch's goes through MKL's vector math (VML, 1 ulp), which
    # starts from the CPU's rsqrt approximation, and that differs between Intel and AMD CPUs.
    rms = torch.from_numpy(np.sqrt((sum_sq / max(1, diffs.shape[0] * diffs.shape[2] * diffs.shape[3])).numpy()))
    rms = torch.where(rms > 1e-6, rms, torch.ones_like(rms))
    return Normalisation(height=height, width=width, scale=tuple(float(s) for s in rms), peak_floor=peak_floor,
                         offset=offset)


# --- training ----------------------------------------------------------------------------------------


def _device(name: str) -> torch.device:
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise ConfigError("ae.device is cuda but torch sees no CUDA device")
        return torch.device("cuda")
    return torch.device("cpu")


@contextlib.contextmanager
def _deterministic(seed: int, threads: int, device: torch.device):
    """Seed torch, fix the CPU thread count and require deterministic kernels; restore all on exit.

    The thread count is fixed because a CPU convolution's summation order, and so its last bits,
    depend on how the work is split between threads.
    """
    old_threads = torch.get_num_threads()
    old_det = torch.are_deterministic_algorithms_enabled()
    if device.type == "cuda":
        # cuBLAS needs a fixed workspace to be deterministic; it reads this when its handle is created.
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    fork_devices = [device.index or 0] if device.type == "cuda" else []
    try:
        with torch.random.fork_rng(devices=fork_devices):
            torch.manual_seed(seed)
            torch.set_num_threads(threads)
            torch.use_deterministic_algorithms(True)
            yield
    finally:
        torch.set_num_threads(old_threads)
        torch.use_deterministic_algorithms(old_det)


def split_indices(n: int, val_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A seeded random split of range(n) into (train, val) sorted index arrays; val has
    round(n * val_fraction) items, at least 1 when the fraction is positive and n > 1."""
    n_val = int(round(n * val_fraction))
    if val_fraction > 0.0 and n > 1:
        n_val = max(1, n_val)
    n_val = min(n_val, n - 1)
    perm = np.random.default_rng(seed).permutation(n)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def _mean_loss(model: nn.Module, x: torch.Tensor, batch_size: int, fraction: float, device) -> float:
    """Mean bootstrapped L2 over x (n, 3, H, W), batch by batch, without gradients."""
    model.eval()
    total = 0.0
    with torch.no_grad():
        for sl in _chunks(x.shape[0], batch_size):
            xb = x[sl].to(device)
            total += float(bootstrapped_l2(model(xb), xb, fraction)) * xb.shape[0]
    return total / max(1, x.shape[0])


def train(
    images,
    background: np.ndarray,
    cfg: Mapping | AEConfig,
    seed: int,
    progress: bool = True,
    val_fraction: float | None = None,
    sharpness: np.ndarray | None = None,
    no_contact: np.ndarray | None = None,
) -> tuple[TactileAutoencoder, Normalisation, dict]:
    """Train an autoencoder to reconstruct tactile images.

    images: uint8 (n, 320, 240, 3), a NumPy array or an h5py dataset; background: (320, 240, 3), the
    no-contact image they were rendered over; cfg: the ``ae`` section; val_fraction overrides
    ``cfg.val_fraction``. Adam, shuffled mini-batches; the same inputs, config and seed give the same
    weights bit for bit on the same machine and thread count.

    With ``cfg.rank_weight`` > 0 the loss adds ``rank_weight * angle_ranking_loss`` over each batch, which
    needs ``sharpness`` (n,) int (see ``angle_ranking_loss``) and ``no_contact`` (320, 240, 3), the
    no-contact image whose latent the angles are measured from (noise included, as the databases have it).

    Returns the model (eval mode, on the training device), its Normalisation, and a history dict:
    ``train_loss``, ``val_loss`` (reconstruction only; NaN when there is no validation split),
    ``rank_loss`` (the ranking term's mean over batches, 0 when it is off), ``seconds`` (wall clock) and
    ``cpu_seconds`` (this process, all threads; on a shared machine their ratio shows the contention),
    per-epoch lists; ``preprocess_seconds``, ``n_train``, ``n_val``, ``seed``, ``device``.
    """
    c = AEConfig.from_cfg(cfg)
    vf = c.val_fraction if val_fraction is None else float(val_fraction)
    device = _device(c.device)
    _check_images(images, background)
    n = images.shape[0]
    if n < 2 and vf > 0.0:
        raise InputError(f"need at least 2 images to train with a validation split, got {n}")
    ranking = c.rank_weight > 0.0
    if ranking:
        if sharpness is None or no_contact is None:
            raise InputError("ae.rank_weight > 0 needs each training image's sharpness and the no-contact image")
        sharpness = np.asarray(sharpness)
        if sharpness.shape != (n,):
            raise InputError(f"sharpness must have shape ({n},), got {sharpness.shape}")
        _check_images(np.asarray(no_contact)[None], background)
    with _deterministic(seed, c.threads, device):
        t0 = time.perf_counter()
        x = torch.empty((n, 3, c.input_height, c.input_width), dtype=torch.float32)
        for sl in _chunks(n, _PREPROCESS_CHUNK):
            x[sl] = _unscaled_input(images[sl], background, c.input_height, c.input_width, c.peak_floor,
                                    c.input_offset)
        train_idx, val_idx = split_indices(n, vf, seed)
        x_train, x_val = x[torch.from_numpy(train_idx)], x[torch.from_numpy(val_idx)]
        del x
        norm = fit_normalisation(x_train, c.input_height, c.input_width, c.peak_floor, c.input_offset)
        scale = torch.tensor(norm.scale, dtype=torch.float32)[None, :, None, None]
        x_train /= scale
        x_val /= scale
        if ranking:
            sharp_train = torch.from_numpy(sharpness.astype(np.int64)[train_idx])
            x_nc = (_unscaled_input(np.asarray(no_contact)[None], background, c.input_height, c.input_width,
                                    c.peak_floor, c.input_offset) / scale).to(device)
        history = {
            "train_loss": [],
            "val_loss": [],
            "rank_loss": [],
            "seconds": [],
            "cpu_seconds": [],
            "preprocess_seconds": time.perf_counter() - t0,
            "n_train": len(train_idx),
            "n_val": len(val_idx),
            "seed": int(seed),
            "device": device.type,
        }

        model = build_model(c).to(device)
        # The fused kernel takes its square roots with the CPU's exact sqrt instruction; the default one calls
        # torch.sqrt, i.e. MKL's VML, whose last bit depends on the CPU's vendor (see fit_normalisation).
        optimiser = torch.optim.Adam(model.parameters(), lr=c.learning_rate, fused=True)
        shuffler = torch.Generator().manual_seed(seed)
        epochs = range(c.epochs)
        if progress:
            from tqdm import tqdm

            epochs = tqdm(epochs, desc="train_ae", unit="epoch")
        for _ in epochs:
            t_epoch, cpu_epoch = time.perf_counter(), time.process_time()
            model.train()
            order = torch.randperm(x_train.shape[0], generator=shuffler)
            total, total_rank, batches = 0.0, 0.0, 0
            for sl in _chunks(x_train.shape[0], c.batch_size):
                xb = x_train[order[sl]].to(device)
                if ranking:
                    # The no-contact input rides along in the batch, so its latent moves with the weights.
                    h = model.encode(torch.cat([xb, x_nc]))
                    h, h_nc = h[:-1], h[-1:]
                    loss = bootstrapped_l2(model.decode(h), xb, c.bootstrap_fraction)
                    rank = angle_ranking_loss(F.cosine_similarity(h, h_nc, dim=1),
                                              sharp_train[order[sl]].to(device), c.rank_margin)
                    total_rank += rank.item()
                    objective = loss + c.rank_weight * rank
                else:
                    loss = bootstrapped_l2(model(xb), xb, c.bootstrap_fraction)
                    objective = loss
                optimiser.zero_grad(set_to_none=True)
                objective.backward()
                optimiser.step()
                total += loss.item() * xb.shape[0]
                batches += 1
            history["train_loss"].append(total / x_train.shape[0])
            history["rank_loss"].append(total_rank / max(1, batches))
            history["val_loss"].append(
                _mean_loss(model, x_val, c.batch_size, c.bootstrap_fraction, device) if len(val_idx) else float("nan")
            )
            history["seconds"].append(time.perf_counter() - t_epoch)
            history["cpu_seconds"].append(time.process_time() - cpu_epoch)
            if progress:
                epochs.set_postfix(train=f"{history['train_loss'][-1]:.4g}", val=f"{history['val_loss'][-1]:.4g}")
    model.eval()
    return model, norm, history


# --- using a trained model ---------------------------------------------------------------------------


def encode(
    model: TactileAutoencoder, norm: Normalisation, images, background: np.ndarray, batch_size: int = 256
) -> np.ndarray:
    """Images uint8 (n, 320, 240, 3) -> latents float32 (n, latent_dim), on the model's device; background
    (320, 240, 3) for all, or (n, 320, 240, 3) one per image (several sensors, each with its own).

    Deterministic for a given batch_size and torch thread count (another batch split or thread count
    may change the last bits). Encode the background itself (``images = background[None]``) to get ``h_nc``.
    """
    _check_images(images, background)
    device = next(model.parameters()).device
    model.eval()
    out = np.empty((images.shape[0], model.to_latent.out_features), dtype=np.float32)
    with torch.no_grad():
        for sl in _chunks(images.shape[0], batch_size):
            x = preprocess(images[sl], _backgrounds_of(background, sl), norm).to(device)
            out[sl] = model.encode(x).cpu().numpy()
    return out


def latent_angles(h: np.ndarray, h_nc: np.ndarray) -> np.ndarray:
    """h (n, d), h_nc (d,) -> (n,) float64 radians in [0, pi]: ``arccos(cos_sim(h, h_nc))``.

    The cosine is clipped to [-1, 1] against rounding; a zero vector has cosine 0, i.e. angle pi/2.
    """
    h = np.asarray(h, dtype=np.float64)
    h_nc = np.asarray(h_nc, dtype=np.float64)
    norms = np.linalg.norm(h, axis=-1) * np.linalg.norm(h_nc)
    dots = h @ h_nc
    cos = np.divide(dots, norms, out=np.zeros_like(dots), where=norms > 0.0)
    return np.arccos(np.clip(cos, -1.0, 1.0))


# --- checkpoints -------------------------------------------------------------------------------------


def _checkpoint_error(path: Path, what: str) -> ArtifactError:
    what = " ".join(what.split())
    return ArtifactError(
        f"autoencoder checkpoint {path}: {what}; stage train_ae makes it (run `dvc repro train_ae`)"
    )


def _plain(value):
    """NumPy scalars and arrays inside dicts and lists -> Python numbers and lists, which torch.load
    accepts with ``weights_only=True`` (it refuses NumPy objects)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    return value


def save_checkpoint(
    path: str | Path, model: TactileAutoencoder, norm: Normalisation, cfg: Mapping | AEConfig, history: dict
) -> None:
    """Write model weights, normalisation, config and history to ``path`` atomically (a temporary file
    in the same folder, then ``os.replace``), so a crash never leaves a half-written checkpoint."""
    path = Path(path)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "norm": norm.to_dict(),
        "cfg": asdict(AEConfig.from_cfg(cfg)),
        "history": _plain(history),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_checkpoint(path: str | Path) -> tuple[TactileAutoencoder, Normalisation, dict]:
    """Read a checkpoint written by ``save_checkpoint`` -> (model on CPU in eval mode, Normalisation, the
    ``ae`` config as a plain dict). Raises ArtifactError naming the file and what is wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise _checkpoint_error(path, "missing")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for foreign or truncated files
        raise _checkpoint_error(path, f"not a readable torch checkpoint ({type(exc).__name__})") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise _checkpoint_error(path, f"not a {CHECKPOINT_FORMAT} checkpoint")
    missing = [k for k in _CHECKPOINT_KEYS if k not in payload]
    if missing:
        raise _checkpoint_error(path, f"lacks keys {missing}")
    try:
        cfg = AEConfig.from_cfg(payload["cfg"])
        norm = Normalisation.from_dict(payload["norm"])
    except (ConfigError, KeyError, TypeError, ValueError) as exc:
        raise _checkpoint_error(path, f"bad config or normalisation ({exc})") from exc
    if (norm.height, norm.width) != (cfg.input_height, cfg.input_width):
        raise _checkpoint_error(path, "normalisation size differs from the model's input size")
    model = build_model(cfg)
    try:
        model.load_state_dict(payload["state_dict"], strict=True)
    except (RuntimeError, TypeError, AttributeError) as exc:
        detail = " ".join(str(exc).split())[:300]
        raise _checkpoint_error(path, f"weights do not fit its config ({detail})") from exc
    model.eval()
    return model, norm, asdict(cfg)
