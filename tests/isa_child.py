"""Run in a subprocess by tests/test_instruction_sets.py: a little of each library's CPU-dispatched work,
-> one JSON line of digests (SHA-256 of the result bytes, 16 hex digits).

- ``autoencoder``: two epochs of a small autoencoder (PyTorch: ATen's kernels, oneDNN's convolutions, MKL);
- ``gradient_descent``: the paper's gradient descent (``optimize.fit_gd``, JAX/XLA);
- ``numpy_transcendental``: float64 power, exp, log, arccos, tan (NumPy's AVX-512 loops round otherwise);
- ``lapack``: SVDs and a solve (OpenBLAS's kernels);
- ``light_fit``: the light's fit (``photometric.fit_light``: sorts with tied values, the joint search's counts)
  on drifted images of a synthetic unit, pressed over half of the gel;
- ``capability``: the ATen capability PyTorch runs with (not a digest).
"""

import hashlib
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]

import numpy as np  # noqa: E402 (after the path; the environment is set by the parent)
import torch  # noqa: E402
from test_autoencoder import background, blob_images, small_cfg  # noqa: E402

from tactile6d.core import geometry  # noqa: E402
from tactile6d.estimation import optimize
from tactile6d.perception import autoencoder as ae  # noqa: E402
from tactile6d.perception import photometric  # noqa: E402
from tactile6d.sim import perturb  # noqa: E402


def digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    rng = np.random.default_rng(0)
    bg = background(64, 48)
    model, _, _ = ae.train(blob_images(32, rng, bg), bg, small_cfg(epochs=2), seed=0, progress=False)
    weights = digest(*(v.numpy() for v in model.state_dict().values()))

    p, s = rng.normal(0, 0.03, (100, 3, 3)), rng.normal(0, 0.03, (3, 3))
    fit = optimize.fit_gd(p, s, geometry.random_rotations(100, rng), optimize.initial_translations(s, 0.2), 100, 0.01, 1.0)

    x = rng.uniform(0.01, 0.99, 100_000)
    numpy_out = (np.power(x, 1 / 2.2), np.exp(x), np.log(x), np.arccos(x), np.tan(x))
    m = rng.normal(size=(200, 3, 3))
    lapack = (*np.linalg.svd(m), np.linalg.solve(m[0] @ m[0].T + np.eye(3), m[1]))

    rows, cols = np.mgrid[0:320, 0:240]
    unit = np.stack([60 + cols // 3, 70 + rows // 4, 170 - (rows + cols) // 5], axis=-1).astype(np.uint8)
    blob = np.sqrt(np.clip(1.0 - ((rows - 150) / 135.0) ** 2 - ((cols - 120) / 100.0) ** 2, 0.0, None))
    pressed = np.clip(unit + blob[..., None] * np.array([40.0, 25.0, 30.0]), 0, 255).astype(np.uint8)
    fits = [photometric.fit_light(perturb.drift_image_light(pressed, gain, gamma), unit)
            for gain, gamma in (([1.1, 0.92, 1.0], [0.85, 1.15, 1.05]), ([0.9, 1.08, 1.06], [1.2, 0.9, 0.83]))]
    light = digest(*(np.concatenate([f.log_gain, f.exponent, f.residual, [f.outliers, f.rim_agreement]]) for f in fits))

    print(json.dumps({"autoencoder": weights, "gradient_descent": digest(fit.poses),
                      "numpy_transcendental": digest(*numpy_out), "lapack": digest(*lapack), "light_fit": light,
                      "capability": torch.backends.cpu.get_cpu_capability()}))


if __name__ == "__main__":
    main()
