"""Sets of simulated tactile images stored compactly: an object's surface database and the AE training set.

Both artifacts (schemas ``database``, stage render_database, and ``training_set``, stage
make_training_set) keep their images the same way, because 2000 raw images of 320 x 240 x 3 bytes per
object would take 460 MB, and sensor noise does not compress:

- ``background`` (H, W, 3) uint8 RGB: the no-contact image the renderer adds imprints to, stored once;
- ``noise_std`` (scalar, grey levels) and ``noise_seeds`` (n,) int64: the sensor noise of each image;
- ``images/data`` + ``images/offsets`` (n + 1,): image i is the bytes ``data[offsets[i]:offsets[i+1]]``,
  the zlib-compressed *noise-free* difference ``clean_i - background`` in planar (3, H, W) order, as
  uint8 ``difference + 128`` when every value lies in [-128, 127] (always, with TACTO's
  ``diff_scale`` 0.5: the blurred half-difference stays within +-127.5), else as little-endian int16.
  The decompressed length tells the two apart. It is zero outside the blurred imprint, and smooth
  inside, so it compresses well (sizes: docs/simulator.md);
- ``masks/data`` + ``masks/offsets``: image i's contact mask (H, W) bool (the renderer's ``depth > 0``),
  bit-packed (``np.packbits`` of the row-major mask), then zlib-compressed;
- ``mask_pixels`` (n,) int: how many pixels each mask has, to filter without decoding;
- ``no_contact`` (H, W, 3) uint8 RGB: a noisy no-contact image (the background plus noise);
- ``T_object_sensor`` (n, 4, 4), ``depths`` (n,) metres the gel apex is pressed in, ``rolls`` (n,) radians.

A database also holds ``points`` and ``normals`` (M, 3) (copied from the surface artifact: image i shows
the sensor touching point i); a training set ``shape_index`` (n,), ``axes`` (n, 3) semi-axes a, b, c in
metres, ``exponents`` (n, 2) e1, e2, and ``kinds`` (n,) uint8 (0 surface, 1 edge, 2 corner; root
attribute ``kind_names``).

``database_images`` rebuilds the images exactly: ``add_noise(background + difference, noise_std, seed)``
is bit for bit what ``DigitRenderer.render`` returns for the same pose and noise seed, because the
renderer itself computes ``add_noise(truncate(background + blurred imprint), noise_std, seed)`` and the
difference stored is that truncated image minus the background. The same OpenCV build is needed for the
noise (``tactile6d.render.add_noise``). ``StoredImages`` wraps it as a lazily decoded (n, H, W, 3)
array for code that slices image arrays (the autoencoder's training and encoding).

Sensors across sharp edges or concave parts can have the object inside their body, where the renderer's
strict mode raises. Both sets are rendered non-strict, as TACTO would render them, and flag those
images in ``body_contact`` (n,) bool: some mesh vertex lies in the body prism behind the gel
(``render.inside_body``).
"""

from __future__ import annotations

import concurrent.futures
import os
import zlib
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from tactile6d.core import sensor
from tactile6d.core.errors import ConfigError
from tactile6d.core.geometry import invert_pose
from tactile6d.data.hdf5 import Artifact
from tactile6d.sim.render import DigitRenderer, MeshArrays, add_noise, inside_body

_ZLIB_LEVEL = 5  # half the time of level 6 for 6 % more bytes, smaller than level 1 (docs/simulator.md, Databases)
_RENDER_BATCH = 128  # poses per render_many call: bounds the uint8 images held at once (30 MB)
# Threads that decode a batch of stored images (database_images): the cores this process may use.
_DECODE_THREADS = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


# --- placing sensors ---------------------------------------------------------------------------------


def object_rng(name: str) -> np.random.Generator:
    """The random generator of an object's database (rolls, then noise seeds): seeded by the object name
    (CRC-32 of its UTF-8 bytes), so each object's database is reproducible and independent of the others."""
    return np.random.default_rng(zlib.crc32(name.encode("utf-8")))


def sensor_rolls(rule: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) radians: the roll of each database sensor about its +x axis (config ``render.roll``).

    ``random``: uniform in [-pi, pi), drawn from ``rng``; ``zero``: all 0 (the sensor's z axis is the
    object's z made orthogonal to the normal, see ``sensor.sensor_poses_touching``).
    """
    if rule == "random":
        return rng.uniform(-np.pi, np.pi, n)
    if rule == "zero":
        return np.zeros(n)
    raise ConfigError(f"render.roll must be 'random' or 'zero', got {rule!r}")


def body_contacts(vertices: np.ndarray, T_object_sensors: np.ndarray) -> np.ndarray:
    """Which sensors have the object inside their body: (n,) bool.

    vertices (V, 3) in the object frame (metres); T_object_sensors (n, 4, 4). True when some vertex lies
    in the prism behind the gel (``render.inside_body``), the check that makes strict rendering raise.
    Only the vertices within reach of each sensor's origin (found with a k-d tree) are transformed, so
    it stays cheap on meshes of 10^5 vertices.
    """
    from scipy.spatial import cKDTree

    vertices = np.asarray(vertices, dtype=np.float64)
    T = np.asarray(T_object_sensors, dtype=np.float64).reshape(-1, 4, 4)
    reach = float(np.linalg.norm(np.abs(sensor.BOX_CENTER) + sensor.BOX_HALF_EXTENTS))  # encloses the prism
    near = cKDTree(vertices).query_ball_point(T[:, :3, 3], reach)
    out = np.zeros(len(T), dtype=bool)
    for i, T_sensor_object in enumerate(invert_pose(T)):
        if near[i]:
            local = vertices[near[i]] @ T_sensor_object[:3, :3].T + T_sensor_object[:3, 3]
            out[i] = bool(np.any(inside_body(local)))
    return out


# --- encoding one image ---------------------------------------------------------------------------


def encode_difference(difference: np.ndarray) -> bytes:
    """(H, W, 3) integer ``clean image - background`` -> zlib bytes (8-bit when it fits, else 16-bit)."""
    planar = np.ascontiguousarray(np.moveaxis(np.asarray(difference, dtype=np.int16), -1, 0))
    if planar.min() >= -128 and planar.max() <= 127:
        raw = (planar + 128).astype(np.uint8).tobytes()
    else:
        raw = planar.astype("<i2").tobytes()
    return zlib.compress(raw, _ZLIB_LEVEL)


def decode_difference(blob: bytes | np.ndarray, height: int, width: int) -> np.ndarray:
    """zlib bytes of ``encode_difference`` -> (height, width, 3) int16."""
    raw = zlib.decompress(bytes(blob) if isinstance(blob, np.ndarray) else blob)
    size = 3 * height * width
    if len(raw) == size:
        planar = np.frombuffer(raw, dtype=np.uint8).astype(np.int16) - 128
    elif len(raw) == 2 * size:
        planar = np.frombuffer(raw, dtype="<i2").astype(np.int16)
    else:
        raise ValueError(f"an image difference of {len(raw)} bytes does not fit {height}x{width}x3")
    return np.moveaxis(planar.reshape(3, height, width), 0, -1)


def encode_mask(mask: np.ndarray) -> bytes:
    """(H, W) bool -> zlib bytes of its row-major bit-packing."""
    return zlib.compress(np.packbits(np.asarray(mask, dtype=bool).ravel()).tobytes(), _ZLIB_LEVEL)


def decode_mask(blob: bytes | np.ndarray, height: int, width: int) -> np.ndarray:
    """zlib bytes of ``encode_mask`` -> (height, width) bool."""
    raw = zlib.decompress(bytes(blob) if isinstance(blob, np.ndarray) else blob)
    bits = np.unpackbits(np.frombuffer(raw, dtype=np.uint8), count=height * width)
    return bits.reshape(height, width).astype(bool)


def pack_blobs(blobs: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Byte strings -> concatenated data (N,) uint8 and offsets (n + 1,) int64 (blob i = data[o[i]:o[i+1]])."""
    offsets = np.zeros(len(blobs) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(b) for b in blobs])
    data = np.frombuffer(b"".join(blobs), dtype=np.uint8) if blobs else np.zeros(0, dtype=np.uint8)
    return data, offsets


# --- rendering a set ------------------------------------------------------------------------------------


class EncodedImages(NamedTuple):
    """Some images of a set, encoded as ``CompactImages`` keeps them, in order: image_blobs and
    mask_blobs (k,) bytes (``encode_difference``, ``encode_mask``), mask_pixels (k,) ints. Small enough to
    send back from a worker process (about 20 KB per image instead of 300 KB raw)."""

    image_blobs: list[bytes]
    mask_blobs: list[bytes]
    mask_pixels: list[int]


class CompactImages:
    """Encoded images and masks of a set being rendered, in order; ``datasets`` gives the artifact's part."""

    def __init__(self, background_rgb: np.ndarray):
        self.background = np.asarray(background_rgb, dtype=np.uint8)
        self.image_blobs: list[bytes] = []
        self.mask_blobs: list[bytes] = []
        self.mask_pixels: list[int] = []

    def add(self, clean_images: np.ndarray, masks: np.ndarray) -> None:
        """Encode noise-free images (k, H, W, 3) uint8 RGB over this background and masks (k, H, W) bool."""
        for image, mask in zip(clean_images, masks):
            self.image_blobs.append(encode_difference(image.astype(np.int16) - self.background))
            self.mask_blobs.append(encode_mask(mask))
            self.mask_pixels.append(int(np.count_nonzero(mask)))

    def extend(self, part: EncodedImages) -> None:
        """Append images encoded elsewhere over the same background (``render_encoded``)."""
        self.image_blobs.extend(part.image_blobs)
        self.mask_blobs.extend(part.mask_blobs)
        self.mask_pixels.extend(part.mask_pixels)

    def datasets(self, noise_std: float, noise_seeds: np.ndarray) -> dict[str, np.ndarray]:
        """The image datasets of a database or training-set artifact (all but ``body_contact``)."""
        if len(noise_seeds) != len(self.image_blobs):
            raise ValueError(f"{len(noise_seeds)} noise seeds for {len(self.image_blobs)} images")
        image_data, image_offsets = pack_blobs(self.image_blobs)
        mask_data, mask_offsets = pack_blobs(self.mask_blobs)
        return {
            "background": self.background,
            "noise_std": np.float64(noise_std),
            "noise_seeds": np.asarray(noise_seeds, dtype=np.int64),
            "images/data": image_data,
            "images/offsets": image_offsets,
            "masks/data": mask_data,
            "masks/offsets": mask_offsets,
            "mask_pixels": np.asarray(self.mask_pixels, dtype=np.int32),
        }


def render_compact(
    renderer: DigitRenderer,
    mesh: MeshArrays,
    T_object_sensors: np.ndarray,
    out: CompactImages,
    progress: Callable[[int], object] | None = None,
) -> None:
    """Render sensors at T_object_sensors (n, 4, 4) on ``mesh`` (its frame as the world) into ``out``.

    renderer: noise-free (``noise_std=0``), typically with ``workers`` processes and ``strict=False``.
    Renders in batches of ``_RENDER_BATCH`` poses, and encodes one batch in this process while the
    renderer's workers render the next, so both cores stay busy and memory stays bounded.
    progress: optional callable(k) told each time k more images are rendered (e.g. tqdm.update).
    """
    if renderer.noise_std > 0:  # the sets store noise as seeds, not as pixels
        raise ValueError(f"render_compact needs a noise-free renderer (noise_std=0), not {renderer.noise_std}")
    T = np.asarray(T_object_sensors, dtype=np.float64).reshape(-1, 4, 4)
    batches = [T[a : a + _RENDER_BATCH] for a in range(0, len(T), _RENDER_BATCH)]
    if not batches:
        return
    # One thread drives render_many (it only waits on the worker processes); this one encodes.
    with concurrent.futures.ThreadPoolExecutor(max_workers=1) as driver:
        pending = driver.submit(renderer.render_many, mesh, batches[0], 0, progress)
        for k in range(len(batches)):
            images, masks = pending.result()
            if k + 1 < len(batches):
                pending = driver.submit(renderer.render_many, mesh, batches[k + 1], 0, progress)
            out.add(images, masks)


def render_encoded(renderer: DigitRenderer, mesh: MeshArrays, T_object_sensors: np.ndarray) -> EncodedImages:
    """Render sensors at T_object_sensors (k, 4, 4) on ``mesh`` (its frame as the world) and encode them,
    all in this process: one task of a stage that spreads a set's poses over worker processes. The
    blobs are those ``render_compact`` stores for the same poses, so the parts of a set rendered this
    way, appended in order (``CompactImages.extend``), give the same artifact byte for byte.

    renderer: noise-free (``noise_std=0``) with ``workers=1`` (this is already a worker); keep k small
    (tens of poses): the k uint8 images are held at once.
    """
    if renderer.noise_std > 0:  # the sets store noise as seeds, not as pixels
        raise ValueError(f"render_encoded needs a noise-free renderer (noise_std=0), not {renderer.noise_std}")
    out = CompactImages(renderer.background)
    out.add(*renderer.render_many(mesh, T_object_sensors, 0))
    return EncodedImages(out.image_blobs, out.mask_blobs, out.mask_pixels)


# --- reading a set ---------------------------------------------------------------------------------


def image_count(artifact: Artifact) -> int:
    """How many images a database or training-set artifact holds."""
    return len(artifact["images/offsets"]) - 1


def _indices(artifact: Artifact, indices) -> np.ndarray:
    n = image_count(artifact)
    if isinstance(indices, slice):
        return np.arange(n)[indices]
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    if np.any((idx < -n) | (idx >= n)):
        raise IndexError(f"image index out of range for {n} images")
    return idx % n if n else idx


def database_images(artifact: Artifact, indices, noise: bool = True) -> np.ndarray:
    """Images of a database or training-set artifact -> (k, H, W, 3) uint8 RGB.

    indices: ints, an int array or a slice. With ``noise`` (the default) they equal, bit for bit, what
    ``DigitRenderer.render`` gives for the same sensor pose with the image's noise seed
    (``noise_seeds[i]``); without, the noise-free images.
    """
    idx = _indices(artifact, indices)
    background = artifact["background"]
    height, width = background.shape[:2]
    data, offsets, seeds = artifact["images/data"], artifact["images/offsets"], artifact["noise_seeds"]
    noise_std = float(artifact["noise_std"]) if noise else 0.0
    out = np.empty((len(idx), height, width, 3), dtype=np.uint8)

    def decode(k: int) -> None:
        i = idx[k]
        difference = decode_difference(data[offsets[i] : offsets[i + 1]], height, width)
        clean = (background + difference).astype(np.uint8)  # in 0..255 by construction
        out[k] = add_noise(clean, noise_std, int(seeds[i]))

    # zlib, NumPy and OpenCV release the GIL, and OpenCV's noise generator is per thread (add_noise seeds it
    # in the thread that draws), so threads decode images independently and to the same bits.
    threads = min(_DECODE_THREADS, len(idx) // 16)
    if threads > 1:
        with concurrent.futures.ThreadPoolExecutor(threads) as pool:
            for _ in pool.map(decode, range(len(idx))):
                pass
    else:
        for k in range(len(idx)):
            decode(k)
    return out


def database_masks(artifact: Artifact, indices) -> np.ndarray:
    """Contact masks of a database or training-set artifact -> (k, H, W) bool (indices as ``database_images``)."""
    idx = _indices(artifact, indices)
    height, width = artifact["background"].shape[:2]
    data, offsets = artifact["masks/data"], artifact["masks/offsets"]
    out = np.empty((len(idx), height, width), dtype=bool)
    for k, i in enumerate(idx):
        out[k] = decode_mask(data[offsets[i] : offsets[i + 1]], height, width)
    return out


class StoredImages:
    """The images of a database or training-set artifact as a lazily decoded (n, H, W, 3) uint8 array.

    Supports ``shape``, ``ndim``, ``len`` and indexing by an int, a slice or an index array (only the
    images asked for are decoded), which is what the autoencoder's ``train`` and ``encode`` read.
    """

    def __init__(self, artifact: Artifact, noise: bool = True):
        self.artifact = artifact
        self.noise = noise
        self.shape = (image_count(artifact), *artifact["background"].shape)
        self.ndim = 4
        self.dtype = np.dtype(np.uint8)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        if isinstance(key, (int, np.integer)):
            return database_images(self.artifact, [key], self.noise)[0]
        return database_images(self.artifact, key, self.noise)
