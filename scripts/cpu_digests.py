"""This machine's digests of the CPU-dispatched work the tests check, to compare two machines line by line.

    python scripts/cpu_digests.py

Runs ``tests/isa_child.py`` (two epochs of a small autoencoder, the paper's gradient descent, NumPy's
transcendental loops, LAPACK) in a subprocess under the pipeline's pinned environment
(``tactile6d.runtime.instruction_sets``), once as the stages run it and once with PyTorch's oneDNN turned off
(convolutions then go through ATen and MKL), and prints one JSON line each with the CPU's name, vendor,
family and model. Two machines whose lines differ would not make the same bits in ``train_ae``; which
digest differs says which library. The lines measured so far are in docs/reproducibility.md (Across machines).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tactile6d.runtime import instruction_sets  # noqa: E402  (imports nothing heavy)

CHILD = ROOT / "tests" / "isa_child.py"
VARIANTS = {
    "pinned": None,
    "pinned, oneDNN off": "import torch; torch.backends.mkldnn.enabled = False",
}


def cpu_identity() -> dict[str, str]:
    """The first processor's name, vendor, family and model as /proc/cpuinfo gives them."""
    keys = {"model name": "cpu", "vendor_id": "vendor", "cpu family": "family", "model": "model"}
    out: dict[str, str] = {}
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        key, _, value = line.partition(":")
        name = keys.get(key.strip())
        if name and name not in out:
            out[name] = value.strip()
    flags = next((ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags")), "")
    out["avx512f"] = str(" avx512f" in flags)
    return out


def run_child(prelude: str | None) -> dict:
    """tests/isa_child.py under the pinned environment, after ``prelude`` (Python) when given -> its digests."""
    env = instruction_sets.pinned_environment(dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    if prelude is None:
        command = [sys.executable, str(CHILD)]
    else:
        command = [sys.executable, "-c", f"{prelude}; import runpy; runpy.run_path({str(CHILD)!r}, run_name='__main__')"]
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> int:
    identity = cpu_identity()
    for name, prelude in VARIANTS.items():
        print(json.dumps({"variant": name, **identity, **run_child(prelude)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
