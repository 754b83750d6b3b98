"""This machine's digests of the CPU-dispatched work the tests check, to compare two machines line by line.

    python scripts/cpu_digests.py

Runs ``tests/isa_child.py`` (two epochs of a small autoencoder, the paper's gradient descent, NumPy's
transcendental loops, LAPACK) and one epoch of the pipeline's own autoencoder (conf/ae/cpu.yaml: its layers, two
threads, on 128 blob images; ``pipeline_autoencoder``) in subprocesses under the pipeline's pinned environment
(``tactile6d.runtime.instruction_sets``), once as the stages run them and once with PyTorch's oneDNN turned off
(convolutions then go through ATen and MKL), and prints one JSON line each with the CPU's name, vendor,
family, model, threads per core and data caches (size / processors sharing it). Two machines whose lines differ would not make the same bits in ``train_ae``; which
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
    flags = ""
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        key, _, value = line.partition(":")
        name = keys.get(key.strip())
        if name and name not in out:
            out[name] = value.strip()
        elif key.strip() == "flags" and not flags:
            flags = value
    out["avx512f"] = str("avx512f" in flags.split())
    out.update(cpu_topology())
    return out


def _cpu_count(cpu_list: str) -> int:
    """How many processors a Linux CPU list such as ``0-1,4`` names."""
    count = 0
    for part in cpu_list.strip().split(","):
        first, _, last = part.partition("-")
        count += int(last or first) - int(first) + 1
    return count


def cpu_topology(sysfs: Path = Path("/sys/devices/system/cpu/cpu0")) -> dict[str, str]:
    """The first processor's threads per core and data caches as the kernel reads them from CPUID:
    ``{"threads_per_core": "1", "caches": "L1 32K/1 L2 512K/1 L3 32768K/2"}``, each cache's size over the
    processors that share it. Libraries size their blocking by the cache per core (oneDNN: size / sharing),
    which the CPU disguise (scripts/cpu_disguise.py) does not mimic from a real machine's answers; empty
    values where the kernel exposes no such files."""
    try:
        threads = str(_cpu_count((sysfs / "topology" / "thread_siblings_list").read_text()))
    except OSError:
        threads = ""
    caches = []
    for index in sorted(sysfs.glob("cache/index*")):
        try:
            if (index / "type").read_text().strip() == "Instruction":
                continue
            caches.append(f"L{(index / 'level').read_text().strip()} {(index / 'size').read_text().strip()}/"
                          f"{_cpu_count((index / 'shared_cpu_list').read_text())}")
        except OSError:
            continue
    return {"threads_per_core": threads, "caches": " ".join(caches)}


def pipeline_autoencoder_digest() -> str:
    """One epoch of the pipeline's autoencoder (conf/ae/cpu.yaml, reconstruction loss) on 128 blob images ->
    the digest of its weights. Run in the child, where the environment is pinned."""
    import hashlib

    import numpy as np
    from omegaconf import OmegaConf

    sys.path.insert(0, str(ROOT / "tests"))
    from test_autoencoder import background, blob_images

    from tactile6d.perception import autoencoder as ae

    cfg = dict(OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "ae" / "cpu.yaml")))
    cfg.update(epochs=1, rank_weight=0.0, device="cpu")
    bg = background()
    model, _, _ = ae.train(blob_images(128, np.random.default_rng(0), bg), bg, cfg, seed=0, progress=False)
    h = hashlib.sha256()
    for value in model.state_dict().values():
        h.update(np.ascontiguousarray(value.numpy()).tobytes())
    return h.hexdigest()[:16]


def run_child(prelude: str | None) -> dict:
    """tests/isa_child.py and ``pipeline_autoencoder_digest`` under the pinned environment, after ``prelude``
    (Python) when given -> their digests."""
    env = instruction_sets.pinned_environment(dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    start = "" if prelude is None else prelude + "; "
    children = (
        f"import runpy; runpy.run_path({str(CHILD)!r}, run_name='__main__')",
        (f"import json, runpy; f = runpy.run_path({__file__!r})['pipeline_autoencoder_digest']; "
         "print(json.dumps({'pipeline_autoencoder': f()}))"),
    )
    out: dict = {}
    for code in children:
        done = subprocess.run([sys.executable, "-c", start + code], env=env, capture_output=True, text=True, check=True,
                              cwd=ROOT)
        out.update(json.loads(done.stdout.strip().splitlines()[-1]))
    return out


def main() -> int:
    identity = cpu_identity()
    for name, prelude in VARIANTS.items():
        print(json.dumps({"variant": name, **identity, **run_child(prelude)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
