"""tactile6d.instruction_sets: every library capped at AVX2, so that runs give the same bits on every machine.

The unit tests check the environment it builds; the slow test runs a little of each library's work
(tests/isa_child.py: a few autoencoder training steps, the paper's gradient descent, NumPy's transcendental
functions, LAPACK) in subprocesses, pinned, and pinned with every library also forced onto AVX2 by hand as
an AVX2-only machine would pick: the bits must be equal. On a CPU with AVX-512, that checks that the pin
covers every library these steps use (a missing one takes the AVX-512 path and changes the bits); on an
AVX2-only CPU both runs take the AVX2 path anyway.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactile6d import instruction_sets as isa

HERE = Path(__file__).resolve().parent


def test_a_bare_environment_gets_every_cap():
    env = isa.pinned_environment({})
    assert env == {
        "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
        "ATEN_CPU_CAPABILITY": "avx2",
        "DNNL_MAX_CPU_ISA": "AVX2",
        "XLA_FLAGS": "--xla_cpu_max_isa=AVX2",
        "OPENBLAS_CORETYPE": "Haswell",
        "MKL_CBWR": "AVX2",
    }


def test_lower_levels_and_other_settings_already_there_are_kept():
    env = isa.pinned_environment({
        "NPY_DISABLE_CPU_FEATURES": "X86_V3,AVX512_ICL",
        "ATEN_CPU_CAPABILITY": "default",
        "DNNL_MAX_CPU_ISA": "sse41",
        "XLA_FLAGS": "--xla_cpu_max_isa=AVX --xla_force_host_platform_device_count=2",
        "OPENBLAS_CORETYPE": "Zen",
        "PATH": "/bin",
    })
    assert env["NPY_DISABLE_CPU_FEATURES"] == "X86_V3 AVX512_ICL X86_V4 AVX512_SPR"
    assert env["ATEN_CPU_CAPABILITY"] == "default" and env["DNNL_MAX_CPU_ISA"] == "sse41"
    assert env["XLA_FLAGS"] == "--xla_cpu_max_isa=AVX --xla_force_host_platform_device_count=2"
    assert env["OPENBLAS_CORETYPE"] == "Zen" and env["PATH"] == "/bin"


def test_higher_levels_are_capped_and_other_xla_flags_kept():
    env = isa.pinned_environment({"ATEN_CPU_CAPABILITY": "avx512", "DNNL_MAX_CPU_ISA": "AVX512_CORE",
                                  "XLA_FLAGS": "--xla_force_host_platform_device_count=2"})
    assert env["ATEN_CPU_CAPABILITY"] == "avx2" and env["DNNL_MAX_CPU_ISA"] == "AVX2"
    assert env["XLA_FLAGS"] == "--xla_force_host_platform_device_count=2 --xla_cpu_max_isa=AVX2"


def test_pin_changes_nothing_once_numpy_is_loaded():
    import numpy  # noqa: F401 (loaded, as in any pytest process)

    environ = {}
    assert "numpy" in isa.pin(environ)
    assert environ == {}


def test_exports_print_every_pinned_variable():
    lines = isa.exports({}).splitlines()
    assert [line.split("=")[0] for line in lines] == [f"export {name}" for name in isa.PINNED_VARIABLES]


def _child(extra: dict[str, str]) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    env.update(extra)
    out = subprocess.run([sys.executable, str(HERE / "isa_child.py")], env=isa.pinned_environment(env),
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


# What an AVX2-only machine's libraries would pick, each forced by hand on top of the pin.
AVX2_MACHINE = {
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR AVX512F AVX512_SKX",
    "ATEN_CPU_CAPABILITY": "avx2",
    "DNNL_MAX_CPU_ISA": "AVX2",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    "OPENBLAS_CORETYPE": "Haswell",
    "XLA_FLAGS": "--xla_cpu_max_isa=AVX2",
}


@pytest.mark.slow
def test_pinned_runs_equal_runs_forced_onto_avx2():
    pinned, avx2 = _child({}), _child(AVX2_MACHINE)
    assert pinned["capability"] == "AVX2"
    assert pinned == avx2
