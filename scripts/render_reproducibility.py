"""Do DigitRenderer's images depend on the CPU's instruction set? Render a fixed set under several settings.

Each setting is a set of environment variables (and a few in-process switches) that force one library
onto another code path, the way a CPU with other instruction-set extensions would: Embree's ISA
(``isa=...`` in its device config), NumPy's SIMD dispatch (``NPY_DISABLE_CPU_FEATURES``), OpenCV's
(``OPENCV_CPU_DISABLE``, ``cv2.setUseOptimized(False)``), OpenBLAS's kernel (``OPENBLAS_CORETYPE``), and
thread and worker counts. Every setting renders the same images in a fresh subprocess (dispatch is fixed
at import), and each is compared with the default: how many pixels differ and by how many grey levels,
at each step of the renderer (ray grid before the blur, the stored noise-free image, the noise).

embreex creates its Embree device with ``rtcNewDevice(NULL)`` and Embree 4 reads no config file, so the
ISA is chosen through a small LD_PRELOAD shim (compiled here with the system C compiler) that passes
``$EMBREE_CONFIG`` to ``rtcNewDevice`` instead.

    python scripts/render_reproducibility.py                 # all settings, a table of differences
    python scripts/render_reproducibility.py --settings default embree-sse2 --keep /tmp/out
    python scripts/render_reproducibility.py render OUT.npz  # one render in this process (what each child runs)
    eval "$(python scripts/render_reproducibility.py env avx2)"  # this shell on Embree's AVX2 intersector

The data directory is $TACTILE6D_DATA (or ../shared/data beside the repository).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from tactile6d.runtime.instruction_sets import (  # noqa: E402 (imports nothing heavy)
    PINNED_VARIABLES,
    pinned_environment,
)

# The database images: two YCB objects prepared as prepare_object does, and a superquadric like the
# training set's. Per mesh, this many evenly spread surface points (sample_surface's sampler), each with
# a random roll and the database's press depth.
YCB_OBJECTS = ("004_sugar_box", "011_banana")
SUPERQUADRIC = (0.02, 0.015, 0.012, 0.3, 0.7)  # a, b, c (m), e1, e2: a rounded box, edges and corners
CONTACTS_PER_MESH = 12
SEED = 20261122

# name -> (environment variables, in-process switches). "low" values are the oldest code paths that
# x86-64 machines all have; the Embree names are its config strings.
SETTINGS: dict[str, tuple[dict[str, str], dict[str, object]]] = {
    "default": ({}, {}),
    "repeat": ({}, {}),  # the default again: the run-to-run noise floor (should be none)
    "unpinned": ({}, {"unpinned": True}),  # without tactile6d.runtime.instruction_sets: each library's own pick
    "workers-2": ({}, {"workers": 2}),
    "embree-sse2": ({"EMBREE_CONFIG": "isa=sse2"}, {}),
    "embree-sse4.2": ({"EMBREE_CONFIG": "isa=sse4.2"}, {}),
    "embree-avx": ({"EMBREE_CONFIG": "isa=avx"}, {}),
    "embree-avx2": ({"EMBREE_CONFIG": "isa=avx2"}, {}),
    "embree-avx512": ({"EMBREE_CONFIG": "isa=avx512"}, {}),  # only on a CPU with AVX-512
    "embree-threads-1": ({"EMBREE_CONFIG": "threads=1"}, {}),
    "numpy-no-x86v3": ({"NPY_DISABLE_CPU_FEATURES": "X86_V3"}, {}),
    "opencv-no-avx": ({"OPENCV_CPU_DISABLE": "AVX2,FP16,FMA3,AVX"}, {}),
    "opencv-sse3": ({"OPENCV_CPU_DISABLE": "AVX2,FP16,FMA3,AVX,POPCNT,SSSE3"}, {}),
    "opencv-unoptimized": ({}, {"cv_optimized": False}),
    "opencv-threads-1": ({}, {"cv_threads": 1}),
    "openblas-prescott": ({"OPENBLAS_CORETYPE": "Prescott"}, {}),
    "openblas-sandybridge": ({"OPENBLAS_CORETYPE": "Sandybridge"}, {}),
    "openblas-threads-2": ({"OPENBLAS_NUM_THREADS": "2"}, {}),
    "numpy-opencv-low": (  # NumPy and OpenCV on their lowest paths together (the test's setting)
        {"NPY_DISABLE_CPU_FEATURES": "X86_V3", "OPENCV_CPU_DISABLE": "AVX2,FP16,FMA3,AVX,POPCNT,SSSE3"},
        {"cv_optimized": False, "cv_threads": 1},
    ),
    "all-low": (
        {
            "EMBREE_CONFIG": "isa=sse2",
            "NPY_DISABLE_CPU_FEATURES": "X86_V3",
            "OPENCV_CPU_DISABLE": "AVX2,FP16,FMA3,AVX,POPCNT,SSSE3",
            "OPENBLAS_CORETYPE": "Prescott",
        },
        {"cv_optimized": False},
    ),
}
# Embree's ISA names, lowest first, and the CPU flag (/proc/cpuinfo) each needs.
EMBREE_ISAS = {"sse2": "sse2", "sse4.2": "sse4_2", "avx": "avx", "avx2": "avx2", "avx512": "avx512vl"}

_SHIM_SOURCE = r"""
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdlib.h>
void *rtcNewDevice(const char *cfg) {
  static void *(*real)(const char *);
  if (!real) {  /* embree is dlopen'ed locally by embreex, so RTLD_NEXT would not find it */
    void *lib = dlopen(getenv("EMBREE_LIBRARY"), RTLD_NOW | RTLD_NOLOAD);
    real = (void *(*)(const char *))dlsym(lib, "rtcNewDevice");
  }
  const char *e = getenv("EMBREE_CONFIG");
  return real(e && *e ? e : cfg);
}
"""


# --- the images ------------------------------------------------------------------------------------


def data_dir() -> Path:
    """$TACTILE6D_DATA, else ../shared/data beside the repository."""
    env = os.environ.get("TACTILE6D_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def render_config() -> dict:
    """The ``render`` section of params.yaml (what render_database reads)."""
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(REPO / "params.yaml")["render"])


def meshes(data: Path, objects=YCB_OBJECTS, superquadric=SUPERQUADRIC) -> dict:
    """name -> trimesh: the YCB objects cleaned as prepare_object cleans them, and the superquadric."""
    from tactile6d.sim import meshes as tm
    from tactile6d.sim.superquadrics import Superquadric, superquadric_mesh

    out = {}
    for name in objects:
        mesh, _ = tm.clean_mesh(tm.load_mesh_file(data / "ycb" / name / "textured_simple.obj"))
        out[name] = mesh
    if superquadric is not None:
        out["superquadric"] = superquadric_mesh(Superquadric(*superquadric))
    return out


def contact_poses(mesh, n: int, rng: np.random.Generator, press_depth: float) -> np.ndarray:
    """(n, 4, 4) database-style sensor poses: evenly spread points, random rolls, the database's press."""
    from tactile6d.core.sensor import sensor_poses_touching
    from tactile6d.sim.surface_sampling import sample_surface_even

    points, normals, _ = sample_surface_even(mesh, n, rng)
    rolls = rng.uniform(-np.pi, np.pi, n)
    return sensor_poses_touching(points, normals, rolls, press_depth)


def render_set(data: Path, contacts: int = CONTACTS_PER_MESH, objects=YCB_OBJECTS, superquadric=SUPERQUADRIC,
               workers: int = 1) -> dict[str, np.ndarray]:
    """Render the fixed set as render_database does -> arrays to compare.

    images (n, H, W, 3) uint8: the noise-free images the database stores (render_many, noise_std 0,
    non-strict) and masks (n, H, W) bool; grid (n, h, w, 3) float32: the ray-grid difference before upsampling and blur
    (``contact``: Embree hits and NumPy shading only); poses (n, 4, 4); noisy (2, H, W, 3) uint8: ``add_noise`` (OpenCV's
    RNG) of the background and of the first image, as database_images and the no-contact image do.
    """
    import cv2

    from tactile6d.core.geometry import invert_pose
    from tactile6d.sim.render import DigitRenderer, add_noise, mesh_arrays

    cfg = render_config()
    background = cv2.imread(str(data / cfg["background"]), cv2.IMREAD_COLOR)
    rng = np.random.default_rng(SEED)
    images, masks, grids, all_poses = [], [], [], []
    with DigitRenderer.from_config(cfg, background, noise_std=0.0, strict=False, workers=workers) as renderer:
        for mesh in meshes(data, objects, superquadric).values():
            arrays = mesh_arrays(mesh)
            poses = contact_poses(mesh, contacts, rng, float(cfg["press_depth"]))
            batch, batch_masks = renderer.render_many(arrays, poses, 0)
            images.append(batch)
            masks.append(batch_masks)
            all_poses.append(poses)
            for T in poses:  # as DigitRenderer.render computes it for render_many (the mesh frame as world)
                grids.append(renderer.contact(arrays, invert_pose(T) @ np.eye(4))[0])
        bg = renderer.background.astype(np.uint8)
    images = np.concatenate(images)
    noisy = np.stack([add_noise(bg, float(cfg["noise_std"]), 7), add_noise(images[0], float(cfg["noise_std"]), 8)])
    return {"images": images, "masks": np.concatenate(masks), "grid": np.stack(grids), "noisy": noisy,
            "poses": np.concatenate(all_poses)}


def apply_switches(switches: dict) -> None:
    """In-process settings that have no environment variable (OpenCV's optimisation switch, its threads)."""
    import cv2

    if "cv_optimized" in switches:
        cv2.setUseOptimized(bool(switches["cv_optimized"]))
    if "cv_threads" in switches:
        cv2.setNumThreads(int(switches["cv_threads"]))


# --- running settings in subprocesses -------------------------------------------------------------------


def cpu_flags() -> set[str]:
    """This CPU's feature flags (/proc/cpuinfo; empty where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    return {flag for line in text.splitlines() if line.startswith("flags") for flag in line.split(":", 1)[1].split()}


def embree_isas_here() -> list[str]:
    """Embree's ISA names this CPU can run, lowest first."""
    flags = cpu_flags()
    return [isa for isa, flag in EMBREE_ISAS.items() if flag in flags]


def embree_library() -> Path:
    """The Embree shared library that embreex loads."""
    import embreex

    libs = Path(embreex.__file__).resolve().parent.parent / "embreex.libs"
    found = sorted(libs.glob("libembree4*.so*"))
    if not found:
        raise FileNotFoundError(f"no libembree4 in {libs}")
    return found[0]


def build_shim(directory: Path) -> Path | None:
    """Compile the rtcNewDevice shim into ``directory`` -> its path, or None without a C compiler."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    source, library = directory / "embree_config_shim.c", directory / "embree_config_shim.so"
    source.write_text(_SHIM_SOURCE)
    subprocess.run([cc, "-shared", "-fPIC", "-O2", "-o", str(library), str(source), "-ldl"], check=True)
    return library


def setting_environment(name: str, shim: Path | None, data: Path | None = None) -> dict[str, str]:
    """The environment a setting's child runs in: this one, with the setting's variables, then capped at
    AVX2 as the pipeline's stages are (``tactile6d.runtime.instruction_sets``; a setting's lower level stays)."""
    env_vars, switches = SETTINGS[name]
    env = dict(os.environ)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    if data is not None:
        env["TACTILE6D_DATA"] = str(data)
    env.update(env_vars)
    if not switches.get("unpinned"):
        env = pinned_environment(env)
    if "EMBREE_CONFIG" in env_vars:
        if shim is None:
            raise RuntimeError(f"setting {name} needs a C compiler for the Embree shim")
        env["LD_PRELOAD"] = str(shim)
        env["EMBREE_LIBRARY"] = str(embree_library())
    return env


def run_setting(name: str, out: Path, shim: Path | None, contacts: int = CONTACTS_PER_MESH,
                objects=YCB_OBJECTS, superquadric=True, data: Path | None = None) -> dict[str, np.ndarray]:
    """Render the set in a fresh subprocess under setting ``name``; -> its arrays (also saved to ``out``)."""
    _, switches = SETTINGS[name]
    cmd = [sys.executable, str(Path(__file__).resolve()), "render", str(out), "--contacts", str(contacts),
           "--switches", json.dumps(switches), "--objects", *objects]
    if not superquadric:
        cmd.append("--no-superquadric")
    subprocess.run(cmd, env=setting_environment(name, shim, data), check=True)
    with np.load(out) as f:
        return dict(f)


def compare(reference: np.ndarray, other: np.ndarray) -> dict:
    """Differences of two arrays of images (n, ...): values differing, images differing, largest difference."""
    delta = np.abs(reference.astype(np.float64) - other.astype(np.float64))
    per_image = delta.reshape(len(delta), -1).max(axis=1)
    return {
        "values": int(np.count_nonzero(delta)),
        "pixels": int(np.count_nonzero(delta.reshape(*delta.shape[:3], -1).max(axis=-1))),
        "images": int(np.count_nonzero(per_image)),
        "max": float(delta.max()),
    }


def digest(array: np.ndarray) -> str:
    """Short SHA-256 of an array's bytes."""
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()[:12]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", nargs="?", default="compare", choices=("compare", "render", "env"))
    parser.add_argument("out", nargs="?", help="render mode: the .npz to write; env mode: Embree's ISA (sse2, "
                                               "sse4.2, avx, avx2, avx512)")
    parser.add_argument("--settings", nargs="*", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--contacts", type=int, default=CONTACTS_PER_MESH, help="contacts per mesh")
    parser.add_argument("--objects", nargs="*", default=list(YCB_OBJECTS))
    parser.add_argument("--no-superquadric", action="store_true")
    parser.add_argument("--switches", default="{}", help="render mode: in-process switches (JSON)")
    parser.add_argument("--reference", default="default", choices=list(SETTINGS),
                        help="the setting the others are compared with")
    parser.add_argument("--keep", help="compare mode: keep each setting's .npz in this directory")
    args = parser.parse_args(argv)
    superquadric = None if args.no_superquadric else SUPERQUADRIC

    if args.mode == "env":
        # Shell exports that put any program (a pipeline stage, scripts/verify_lock.py) on Embree's
        # intersector ``out`` and every other library's AVX2 path: another machine's code paths, here.
        if args.out not in EMBREE_ISAS:
            parser.error(f"env mode takes one of {list(EMBREE_ISAS)}")
        folder = Path(tempfile.mkdtemp(prefix="embree_shim_"))
        shim = build_shim(folder)
        if shim is None:
            parser.error("no C compiler for the Embree config shim")
        env = pinned_environment(os.environ)
        env.update(EMBREE_CONFIG=f"isa={args.out}", LD_PRELOAD=str(shim), EMBREE_LIBRARY=str(embree_library()))
        for key in ("LD_PRELOAD", "EMBREE_LIBRARY", "EMBREE_CONFIG", *PINNED_VARIABLES):
            print(f"export {key}='{env[key]}'")
        return 0

    if args.mode == "render":
        switches = json.loads(args.switches)
        apply_switches(switches)
        arrays = render_set(data_dir(), args.contacts, args.objects, superquadric, int(switches.get("workers", 1)))
        np.savez_compressed(args.out, **arrays)
        return 0

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        shim = build_shim(Path(tmp))
        names = [args.reference] + [s for s in args.settings if s != args.reference]
        results = {}
        for name in names:
            results[name] = run_setting(name, folder / f"{name}.npz", shim, args.contacts, args.objects,
                                        superquadric is not None)
        ref = results[args.reference]
        n = len(ref["images"])
        print(f"{n} images ({', '.join(args.objects)}{', superquadric' if superquadric else ''}; "
              f"{args.contacts} contacts each); differences from {args.reference!r}:")
        print(f"{'setting':26s} {'images sha256':14s} {'grid px':>8s} {'grid max':>9s} "
              f"{'image px':>9s} {'images':>7s} {'max grey':>9s} {'mask px':>8s} {'noise px':>9s}")
        for name, arrays in results.items():
            g, i, m, z = (compare(ref[k], arrays[k]) for k in ("grid", "images", "masks", "noisy"))
            poses = "" if np.array_equal(ref["poses"], arrays["poses"]) else "  (poses differ)"
            print(f"{name:26s} {digest(arrays['images']):14s} {g['pixels']:8d} {g['max']:9.3g} "
                  f"{i['pixels']:9d} {i['images']:4d}/{n:<3d} {i['max']:9.0f} {m['values']:8d} {z['pixels']:9d}{poses}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
