"""Keep every numerical library on the AVX2 code path, so that a run gives the same bits on every machine.

x86-64 machines of the same kind differ: some have AVX-512, some AVX2 only. NumPy, OpenBLAS, PyTorch
(ATen's kernels and oneDNN's), MKL and XLA each pick their kernels for the CPU at start-up, and the
AVX-512 kernels round differently: NumPy's float64 ``power``, ``exp``, ``log``, ``tan``, ``arccos``...
(other implementations), OpenBLAS's LAPACK (SVD, solve, eigh), oneDNN's convolutions (other summation
orders). Each variable below caps one library at AVX2, which every machine of this project has, and MKL
at the one branch it keeps on every vendor's CPU (Intel and AMD pick other MKL paths otherwise). Measured
(docs/reproducibility.md, Across machines): with them, the autoencoder's weights after a few training
steps, the renderer's images and the paper's gradient descent equal those of the same libraries forced
onto AVX2 bit for bit, and those of this process disguised as another CPU (AMD Zen 3, or Intel without
AVX-512 and with other cache sizes: ``scripts/cpu_disguise.py``).

The variables take effect only when set before the libraries are imported, so ``pin()`` runs first in
every stage (``stages/__init__.py``) and is inherited by their worker processes; Dask workers on other
machines need the same environment (``python -m tactile6d.runtime.instruction_sets`` prints it as shell
``export`` lines). Nothing here lowers a setting the environment already has: a lower code path stays.
This module must import nothing heavy (it runs before NumPy).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping

# NumPy 2.x dispatch targets above AVX2 (X86_V3); disabling one the CPU lacks is a no-op.
NUMPY_ABOVE_AVX2 = ("X86_V4", "AVX512_ICL", "AVX512_SPR")
# Each library's name for "at most AVX2", and its names of the lower levels that are kept if already set.
ATEN_LEVELS = ("default", "avx2")  # ATEN_CPU_CAPABILITY: PyTorch's vectorised kernels
ONEDNN_LEVELS = ("SSE41", "AVX", "AVX2")  # DNNL_MAX_CPU_ISA: PyTorch's convolutions
XLA_FLAG = "--xla_cpu_max_isa=AVX2"  # JAX's compiled code
# OpenBLAS's kernel: the AVX2 machines here pick Zen, whose results equal Haswell's; AVX-512 ones SkylakeX.
# Set only when the environment has none (some machines set it to work around old OpenBLAS bugs).
OPENBLAS_CORETYPE = "Haswell"
# MKL (PyTorch's BLAS): conditional numerical reproducibility on its COMPATIBLE branch (SSE2, without the
# approximate rcpps/rsqrtps), the only branch MKL keeps on both Intel and AMD CPUs: on AMD it ignores
# every other (AVX2 included) and takes its AUTO path, whose bits differ from Intel's. COMPATIBLE is the
# lowest branch, so it replaces whatever the environment set. It costs nothing measurable here: the
# autoencoder's large products are oneDNN's convolutions, MKL only does its two linear layers.
MKL_CBWR = "COMPATIBLE"

LIBRARIES = ("numpy", "torch", "jax", "cv2", "scipy")


def pinned_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """environ -> a copy with every library capped at AVX2 (pure; see the module docstring).

    A lower level already set is kept; NumPy's disabled features are the union of both lists.
    """
    env = dict(environ)
    disabled = env.get("NPY_DISABLE_CPU_FEATURES", "").replace(",", " ").split()
    env["NPY_DISABLE_CPU_FEATURES"] = " ".join(dict.fromkeys([*disabled, *NUMPY_ABOVE_AVX2]))
    env["ATEN_CPU_CAPABILITY"] = _at_most(env.get("ATEN_CPU_CAPABILITY"), ATEN_LEVELS)
    env["DNNL_MAX_CPU_ISA"] = _at_most(env.get("DNNL_MAX_CPU_ISA"), ONEDNN_LEVELS)
    flags = env.get("XLA_FLAGS", "").split()
    if not any(flag.startswith("--xla_cpu_max_isa") for flag in flags):
        env["XLA_FLAGS"] = " ".join([*flags, XLA_FLAG])
    env.setdefault("OPENBLAS_CORETYPE", OPENBLAS_CORETYPE)
    env["MKL_CBWR"] = MKL_CBWR
    return env


def _at_most(current: str | None, levels: tuple[str, ...]) -> str:
    """The current level if it is one of the lower ``levels`` (case-insensitive), else the highest."""
    lower = {level.lower(): level for level in levels}
    if current is not None and current.lower() in lower:
        return current
    return levels[-1]


def pin(environ: os._Environ | dict | None = None) -> list[str]:
    """Cap this process's libraries at AVX2 by setting ``os.environ`` (or ``environ``) in place.

    -> the names of the libraries already imported, on which the pins cannot take effect any more (then
    nothing is changed: a half-pinned process would be worse than an unpinned one). Empty when it worked.
    """
    loaded = [name for name in LIBRARIES if name in sys.modules]
    if loaded:
        return loaded
    target = os.environ if environ is None else environ
    target.update(pinned_environment(target))
    return []


def exports(environ: Mapping[str, str]) -> str:
    """The pinned variables as shell ``export`` lines (for Dask workers started by hand)."""
    pinned = pinned_environment(environ)
    return "\n".join(f"export {key}='{pinned[key]}'" for key in PINNED_VARIABLES)


PINNED_VARIABLES = ("NPY_DISABLE_CPU_FEATURES", "ATEN_CPU_CAPABILITY", "DNNL_MAX_CPU_ISA", "XLA_FLAGS",
                    "OPENBLAS_CORETYPE", "MKL_CBWR")


if __name__ == "__main__":
    print(exports(os.environ))
