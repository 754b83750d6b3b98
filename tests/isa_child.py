"""Run in a subprocess by tests/test_instruction_sets.py: a little of each library's CPU-dispatched work,
-> one JSON line of digests (SHA-256 of the result bytes, 16 hex digits).

- ``autoencoder``: two epochs of a small autoencoder (PyTorch: ATen's kernels, oneDNN's convolutions, MKL);
- ``gradient_descent``: the paper's gradient descent (``optimize.fit_gd``, JAX/XLA);
- ``numpy_transcendental``: float64 power, exp, log, arccos, tan (NumPy's AVX-512 loops round otherwise);
- ``lapack``: SVDs and a solve (OpenBLAS's kernels);
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

    print(json.dumps({"autoencoder": weights, "gradient_descent": digest(fit.poses),
                      "numpy_transcendental": digest(*numpy_out), "lapack": digest(*lapack),
                      "capability": torch.backends.cpu.get_cpu_capability()}))


if __name__ == "__main__":
    main()
