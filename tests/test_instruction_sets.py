"""tactile6d.runtime.instruction_sets: every library capped at AVX2, so that runs give the same bits on every machine.

The unit tests check the environment it builds; the slow test runs a little of each library's work
(tests/isa_child.py: a few autoencoder training steps, the paper's gradient descent, NumPy's transcendental
functions, LAPACK) in subprocesses, pinned, and pinned with every library also forced onto AVX2 by hand as
an AVX2-only machine would pick: the bits must be equal. On a CPU with AVX-512, that checks that the pin
covers every library these steps use (a missing one takes the AVX-512 path and changes the bits); on an
AVX2-only CPU both runs take the AVX2 path anyway. The disguise tests run the same child with CPUID
answering as another CPU (scripts/cpu_disguise.py: an AMD Zen 3, an AMD with AVX-512, an Intel without
AVX-512 and with other cache sizes, an Intel with AVX-512): the bits must equal this machine's, which is
what "the same bits on every CPU" asks of the stages; they are skipped where the kernel offers no CPUID
faulting.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tactile6d.runtime import instruction_sets as isa
from script_loader import load_script

HERE = Path(__file__).resolve().parent
cpu_disguise = load_script("cpu_disguise")


def test_a_bare_environment_gets_every_cap():
    env = isa.pinned_environment({})
    assert env == {
        "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
        "ATEN_CPU_CAPABILITY": "avx2",
        "DNNL_MAX_CPU_ISA": "AVX2",
        "XLA_FLAGS": "--xla_cpu_max_isa=AVX2",
        "OPENBLAS_CORETYPE": "Haswell",
        "MKL_CBWR": "COMPATIBLE",
    }


def test_lower_levels_and_other_settings_already_there_are_kept():
    env = isa.pinned_environment({
        "NPY_DISABLE_CPU_FEATURES": "X86_V3,AVX512_ICL",
        "ATEN_CPU_CAPABILITY": "default",
        "DNNL_MAX_CPU_ISA": "sse41",
        "XLA_FLAGS": "--xla_cpu_max_isa=AVX --xla_force_host_platform_device_count=2",
        "OPENBLAS_CORETYPE": "Zen",
        "MKL_CBWR": "AVX2",
        "PATH": "/bin",
    })
    assert env["NPY_DISABLE_CPU_FEATURES"] == "X86_V3 AVX512_ICL X86_V4 AVX512_SPR"
    assert env["ATEN_CPU_CAPABILITY"] == "default" and env["DNNL_MAX_CPU_ISA"] == "sse41"
    assert env["XLA_FLAGS"] == "--xla_cpu_max_isa=AVX --xla_force_host_platform_device_count=2"
    assert env["OPENBLAS_CORETYPE"] == "Zen" and env["PATH"] == "/bin"
    # MKL's only branch that holds on AMD CPUs too, and its lowest: it replaces any other.
    assert env["MKL_CBWR"] == "COMPATIBLE"


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


@pytest.mark.slow
def test_run_pinned_starts_an_unpinned_command_again_pinned(tmp_path):
    """A script that imported NumPy before it could pin calls run_pinned() before main(): it is started again
    with every cap, its arguments and the interpreter's own flags kept; an already pinned one runs once."""
    script = tmp_path / "show_env.py"
    script.write_text(
        "import sys, json, os\n"
        "import numpy\n"  # loaded before the pin could take effect, as in the diagnostic scripts
        f"sys.path.insert(0, {str(HERE.parent)!r})\n"
        "from tactile6d.runtime.instruction_sets import PINNED_VARIABLES\n"
        "from tactile6d.runtime.pinned_process import run_pinned\n"
        "print('started', flush=True)\n"
        "run_pinned()\n"
        "print(json.dumps({'argv': sys.argv[1:], 'optimize': sys.flags.optimize,\n"
        "                  'env': {name: os.environ.get(name) for name in PINNED_VARIABLES}}))\n")
    bare = {key: value for key, value in os.environ.items() if key not in isa.PINNED_VARIABLES}
    out = subprocess.run([sys.executable, "-O", str(script), "a", "--b"], env=bare,
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[:2] == ["started", "started"]  # once unpinned, once again pinned
    seen = json.loads(out[2])
    assert seen["argv"] == ["a", "--b"] and seen["optimize"] == 1
    assert seen["env"] == {name: isa.pinned_environment(bare)[name] for name in isa.PINNED_VARIABLES}
    out = subprocess.run([sys.executable, str(script)], env=isa.pinned_environment(bare),
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0] == "started" and len(out) == 2


# Scripts that set each child's environment themselves (pinned, and on purpose unpinned or disguised).
SETS_ITS_CHILDREN = {"cpu_digests.py", "render_reproducibility.py"}


def test_every_script_that_computes_with_the_library_runs_pinned():
    """A diagnostic script's figures are quoted in docs/ and must repeat on every CPU, as the stages' outputs do:
    each script that imports the library's numerical packages starts itself again pinned before main()."""
    unpinned = []
    for path in sorted((HERE.parent / "scripts").glob("*.py")):
        source = path.read_text()
        numerical = any(f"from tactile6d.{package}" in source
                        for package in ("estimation", "evaluation", "perception", "sim"))
        if numerical and path.name not in SETS_ITS_CHILDREN:
            main_block = source.split('if __name__ == "__main__":', 1)[-1]
            if main_block.find("run_pinned()") == -1 or main_block.find("run_pinned()") > main_block.find("main()"):
                unpinned.append(path.name)
    assert unpinned == []


def _child(extra: dict[str, str], after_pin: dict[str, str] | None = None) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    env.update(extra)
    env = isa.pinned_environment(env)
    env.update(after_pin or {})
    out = subprocess.run([sys.executable, str(HERE / "isa_child.py")], env=env,
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


# --- other CPUs, by disguise: scripts/cpu_disguise.py makes CPUID answer as another vendor's CPU ---------


@pytest.fixture(scope="module")
def disguise_shim(tmp_path_factory):
    if not cpu_disguise.supported():
        pytest.skip("no CPUID faulting on this CPU or kernel (cpuid_fault in /proc/cpuinfo)")
    shim = cpu_disguise.build(tmp_path_factory.mktemp("cpu_disguise"))
    if shim is None:
        pytest.skip("no C compiler for scripts/cpu_disguise.c")
    return shim


@pytest.fixture(scope="module")
def native_digests():
    return _child({})


def _disguised(name: str, shim, after_pin: dict[str, str] | None = None) -> dict:
    return _child(cpu_disguise.environment(name, shim, {}), after_pin)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(cpu_disguise.DISGUISES))
def test_the_disguise_is_what_a_process_sees(name, disguise_shim):
    out = subprocess.run(cpu_disguise.probe_command(), env=cpu_disguise.environment(name, disguise_shim, dict(os.environ)),
                         capture_output=True, text=True, check=True)
    seen = json.loads(out.stdout)
    assert seen["vendor"] == ("AuthenticAMD" if name.startswith("amd") else "GenuineIntel")
    assert seen["avx512f"] == (name.endswith("avx512") and cpu_disguise.probe()["avx512f"])


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(cpu_disguise.DISGUISES))
def test_pinned_runs_give_the_same_bits_on_other_cpus(name, disguise_shim, native_digests):
    assert _disguised(name, disguise_shim) == native_digests


@pytest.mark.slow
def test_mkl_avx2_branch_would_give_other_bits_on_amd(disguise_shim):
    """Why MKL_CBWR is COMPATIBLE: MKL ignores its AVX2 branch on AMD CPUs (Intel's documentation), so the
    pin of before gave the autoencoder other weights there. Only an Intel CPU takes that branch: an Intel
    machine compares itself with a disguised AMD, an AMD machine a disguised Intel with itself."""
    avx2_branch = {"MKL_CBWR": "AVX2"}
    if cpu_disguise.probe()["vendor"] == "GenuineIntel":
        intel, amd = _child({}, avx2_branch), _disguised("amd-zen3", disguise_shim, avx2_branch)
    else:
        intel, amd = _disguised("intel-avx2", disguise_shim, avx2_branch), _child({}, avx2_branch)
    assert intel["autoencoder"] != amd["autoencoder"]
