"""scripts/approx_instructions.py: the probe sees an approximate instruction run, and the autoencoder's
training and encoding run none of MKL's vector math (whose sqrt starts from the CPU's own rsqrt)."""

import shutil
import subprocess
from pathlib import Path

import pytest

from script_loader import load_script

approx = load_script("approx_instructions")

TOOLS = all(shutil.which(tool) for tool in ("gdb", "objdump", "nm", "cc"))
needs_tools = pytest.mark.skipif(not TOOLS, reason="needs gdb, objdump, nm and cc")


def test_the_approximate_instructions_are_found_in_a_disassembly():
    text = """
  401000:	vrsqrtps %ymm1,%ymm0
  401004:	vsqrtps %ymm1,%ymm0
  401008:	rcpss  %xmm1,%xmm0
  40100c:	vrcp14pd %zmm1,%zmm0
  401012:	vdivps %ymm1,%ymm2,%ymm0
  401016:	call   401000 <rcpps_wrapper>
"""
    assert approx.instruction_sites(text) == [0x401000, 0x401008, 0x40100C]


@pytest.fixture(scope="module")
def reciprocal_library(tmp_path_factory) -> Path:
    """A library with one exported function that runs rcpps (the positive control) and one that does not."""
    directory = tmp_path_factory.mktemp("approx")
    source = directory / "approx_demo.c"
    source.write_text(
        "#include <immintrin.h>\n"
        "float approx_demo_reciprocal(float x) { return _mm_cvtss_f32(_mm_rcp_ps(_mm_set1_ps(x))); }\n"
        "float approx_demo_exact(float x) { return 1.0f / x; }\n")
    library = directory / "libapprox_demo.so"
    subprocess.run(["cc", "-O1", "-shared", "-fPIC", "-o", str(library), str(source)], check=True)
    return library


def load(library: Path, call: str) -> tuple[str, str]:
    setup = f"import ctypes; lib = ctypes.CDLL({str(library)!r}); lib.{call}.restype = ctypes.c_float"
    return setup, f"lib.{call}(ctypes.c_float(3.0))"


@pytest.mark.slow
@needs_tools
def test_the_probe_reports_an_approximate_instruction_that_ran_and_none_that_did_not(reciprocal_library):
    setup, code = load(reciprocal_library, "approx_demo_reciprocal")
    ran = approx.probe(code, setup, ("libapprox_demo",), functions="^approx_demo_")
    assert ran["sites"] >= 1
    assert [(h["library"], h["function"]) for h in ran["hits"]] == [("libapprox_demo.so", "approx_demo_reciprocal")]
    setup, code = load(reciprocal_library, "approx_demo_exact")
    assert approx.probe(code, setup, ("libapprox_demo",), functions="^approx_demo_")["hits"] == []


@pytest.mark.slow
@needs_tools
def test_training_and_encoding_run_no_approximate_instruction_of_mkls_vector_math():
    """The autoencoder's training (the pipeline's preset, the rank loss on, one epoch of 64 images) and
    encoding: no approximate instruction of MKL's vector-math kernels runs. ``torch.sqrt``, the default
    Adam's, ran them (``vmsSqrt``), which trained other weights on an AMD CPU than on an Intel one."""
    setup = "\n".join([
        "import sys, numpy as np, torch",
        f"sys.path.insert(0, {str(approx.ROOT / 'tests')!r})",
        "from omegaconf import OmegaConf",
        "from tactile6d.perception import autoencoder as ae",
        "from test_autoencoder import background, blob_images",
        f"cfg = dict(OmegaConf.to_container(OmegaConf.load({str(approx.ROOT / 'conf' / 'ae' / 'cpu.yaml')!r})))",
        "cfg.update(epochs=1, device='cpu')",
        "bg = background(); rng = np.random.default_rng(0)",
        "images = blob_images(64, rng, bg); sharpness = rng.integers(-1, 3, 64)",
    ])
    code = ("model, norm, _ = ae.train(images, bg, cfg, seed=0, progress=False, sharpness=sharpness, no_contact=bg)\n"
            "ae.encode(model, norm, images, bg)")
    assert approx.probe(code, setup, ("libtorch_cpu",), functions="^mkl_vml_kernel_")["hits"] == []
