"""DigitRenderer's images under other CPU code paths, each forced in a subprocess (scripts/render_reproducibility.py).

A database rendered on another x86-64 machine must equal this one's (docs/reproducibility.md, "Across
machines"). Every child runs capped at AVX2 as the pipeline's stages are (tactile6d.runtime.instruction_sets), and
each setting forces one library onto another code path, the way a CPU with other instruction-set
extensions would: every Embree intersector this CPU offers (SSE2 to AVX-512), NumPy's and OpenCV's lowest
SIMD paths, OpenBLAS's oldest kernel. The renderer lets Embree only pick the triangle and shades with
correctly rounded arithmetic, so the images are bit-identical under all of them; OpenBLAS's kernel still
changes the sensor poses in their last bits (the pin keeps it on one kernel for every machine here).
"""

from pathlib import Path

import numpy as np
import pytest

from script_loader import load_script

pytestmark = pytest.mark.slow  # end-to-end: excluded from the quick subset (-m 'not slow')

REPO = Path(__file__).resolve().parent.parent

# 12 database-style contacts on the sugar box: before the renderer recomputed Embree's
# hits, two of them (5 and 9) landed on Embree's rounding differences.
OBJECTS = ("004_sugar_box",)
CONTACTS = 12
KEYS = ("grid", "images", "masks", "noisy", "poses")
# OpenBLAS's Prescott kernel (no FMA) against Haswell's (FMA): pose entries differ by at most 1 ulp of 1.
POSE_MAX_DIFFERENCE = 2.3e-16


rr = load_script("render_reproducibility")


@pytest.fixture(scope="module")
def render(data_dir, tmp_path_factory):
    """render(setting) -> the arrays of the fixed set rendered in a subprocess under that setting (cached)."""
    folder = tmp_path_factory.mktemp("render_reproducibility")
    shim = rr.build_shim(folder)
    cache = {}

    def run(name):
        if name not in cache:
            if "EMBREE_CONFIG" in rr.SETTINGS[name][0] and shim is None:
                pytest.skip("no C compiler for the Embree config shim")
            cache[name] = rr.run_setting(name, folder / f"{name}.npz", shim, CONTACTS, OBJECTS, False, data_dir)
        return cache[name]

    return run


def _assert_same(other, default, keys=KEYS):
    for key in keys:
        np.testing.assert_array_equal(other[key], default[key], err_msg=key)


def test_numpy_and_opencv_code_paths_leave_images_identical(render):
    """NumPy without its AVX2/FMA (X86_V3) loops, OpenCV without optimisations, SIMD or threads: same bits.

    The shading is +, -, *, / and sqrt only (no ``power``: its AVX-512 loop rounds otherwise), correctly
    rounded on every SIMD path; OpenCV's resize, blur and noise take the same arithmetic order in their
    SIMD and scalar code.
    """
    _assert_same(render("numpy-opencv-low"), render("default"))


@pytest.mark.parametrize("isa", rr.embree_isas_here())
def test_every_embree_intersector_gives_the_same_images(render, isa):
    """Embree only picks the triangle; the hit distance and barycentric weights are recomputed in float64
    (``render.ray_triangle_hits``), so its ISA-specific float32 rounding no longer reaches the pixels.
    (Before, SSE2 against this CPU's default moved 15 pixels of 24 images (these 12 and 12 on a superquadric) by one level.)"""
    _assert_same(render(f"embree-{isa}"), render("default"))


def test_the_renderer_itself_needs_no_pin(render):
    """Without the AVX2 cap, NumPy and OpenBLAS take this CPU's own paths (AVX-512 where it has it): the
    images stay the same bits, only the sensor poses may move in their last bit (OpenBLAS's kernel)."""
    default, unpinned = render("default"), render("unpinned")
    _assert_same(unpinned, default, ("grid", "images", "masks", "noisy"))
    assert np.abs(unpinned["poses"] - default["poses"]).max() <= POSE_MAX_DIFFERENCE


def test_openblas_kernel_changes_poses_in_last_bits_only(render):
    """OpenBLAS's oldest kernel (Prescott, no FMA) changes the 3x3 products of ``sensor_poses_touching``.

    The poses (stored in each database as ``T_object_sensor``) then differ in their last bit, which is
    enough to change a database's hash; the pin keeps every machine here on the Haswell kernel. The float32
    geometry Embree traces absorbs it in these images (asserted equal because measured so; a vertex that
    rounds to float32 the other way could move a pixel).
    """
    default, prescott = render("default"), render("openblas-prescott")
    assert np.abs(prescott["poses"] - default["poses"]).max() <= POSE_MAX_DIFFERENCE
    _assert_same(prescott, default, ("images", "masks", "noisy"))
