"""A scene set rendered again by TACTO itself, the simulator the paper rendered with: scenes of another tool.

    make tacto-env                                   # .venv-tacto: TACTO 0.0.3, pyrender, EGL (no display needed)
    .venv-tacto/bin/python scripts/tacto_scenes.py --artifacts artifacts --scenes validation offaxis --out ART
    .venv-tacto/bin/python scripts/tacto_scenes.py --artifacts artifacts --scenes --sequences --out ART

Runs in its own environment (``make tacto-env``), not the project's: TACTO pins an old PyOpenGL and imports
urdfpy, and neither is needed anywhere else. It imports nothing of ``tactile6d``.

For each scene of ``<artifacts>/scenes/<set>.h5`` (made by ``make_scenes``), or each frame of the tracking
sequences (``make_sequences``, rendered at the true sensor poses its images were made at), it places the object,
without its texture, at its true pose and renders every sensor with TACTO's ``Renderer`` and its shipped DIGIT
configuration (``digit/tacto/config_digit.yml`` of the data directory: lights, gel, camera, noise of 7 grey
levels; ``--config config_digit_shadow.yml`` its variant with other lights, spot lights and shadows), over the
no-contact image the set was rendered over (its config's ``render.background``; ``--background`` another under
the data directory), at 240 x 320 (``--size 120 160``: TACTO's own default, kept at that size).
The object is not pushed by a force: the set's press (the gel 1-2 mm into the object) is TACTO's geometry as
given (``--deeper MM`` first moves every sensor of a scene set that much further in, or out, along its axis).
TACTO's noise is drawn from NumPy's global generator, seeded by ``--seed`` and the image's place, so a set is
rendered again to the same bits on one machine.

Writes ``<out>/scenes/<set>_tacto.h5``, and with ``--sequences`` ``<out>/sequences/tracking.h5`` (the name stage
``evaluate_tracking`` reads): the source file's every dataset and attribute, the images replaced, the set named
``<set>_tacto`` and a ``renderer`` attribute saying how it was made. Everything else under ``--out`` is linked to
``--artifacts`` (surfaces, databases, the autoencoder), but for ``metrics/`` and ``times/``, which start empty
there: ``scripts/real_setup_check.py --artifacts <out> --scenes validation_tacto`` and ``python -m
stages.evaluate_tracking --params params.yaml paths.artifacts_dir=<out>`` then run on TACTO's images and write
nothing into the pipeline's outputs. About 0.1 s an image on the 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from pathlib import Path

import cv2
import h5py
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

SIZE = (240, 320)  # width, height: the DIGIT images' size, as the paper rendered them (TACTO's default: 120, 160)


def data_dir() -> Path:
    path = os.environ.get("TACTILE6D_DATA")
    if not path:
        raise SystemExit("set TACTILE6D_DATA to the data directory (the layout of ../shared/data)")
    return Path(path)


def euler_xyz(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) pose -> (position (3,), TACTO's orientation: extrinsic xyz Euler angles in radians (3,))."""
    with warnings.catch_warnings():  # at gimbal lock SciPy warns, and its angles still give the rotation back
        warnings.filterwarnings("ignore", "Gimbal lock", UserWarning)
        return T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_euler("xyz")


def untextured(path: Path) -> trimesh.Trimesh:
    """The object's mesh without its texture: TACTO shades the object's colour, and the databases' and the
    paper's presses show the gel's shading only."""
    mesh = trimesh.load(path, force="mesh")
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def tacto_renderer(config: Path, background_file: Path, size: tuple[int, int] = SIZE):
    """TACTO's ``Renderer`` for DIGIT images of ``size`` (width, height) over that no-contact image, which TACTO
    resizes to it (imported here: only the TACTO environment has it)."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless: Mesa's EGL, no display
    if not hasattr(np, "float"):
        np.float = float  # TACTO 0.0.3 still uses the alias NumPy 1.24 removed
    if not hasattr(np, "infty"):
        np.infty = np.inf  # and pyrender 0.1.45's spot lights (config_digit_shadow.yml) the one NumPy 2 removed
    from tacto.renderer import Renderer

    # TACTO's examples read the no-contact image with OpenCV (BGR) and its Renderer turns it to RGB.
    if not background_file.is_file():
        raise SystemExit(f"no-contact image {background_file} not found")
    return Renderer(width=size[0], height=size[1], background=cv2.imread(str(background_file)),
                    config_path=str(config))


def read_set(source: Path) -> tuple[dict, dict]:
    """A scene or sequence set file's datasets and root attributes, if its images are renders at its poses."""
    with h5py.File(source, "r") as f:
        datasets = {name: f[name][()] for name in f}
        attrs = dict(f.attrs)
    # kinematic's T_world_sensors are the poses reported, not those rendered at; variation's images are
    # perturbed after rendering, over no-contact images of their own. scripts/real_setup_check.py applies
    # both to a set rendered here (conditions kinematic, light). A sequence set keeps the poses its images were
    # rendered at beside the reported ones (T_world_sensors_true).
    altered = sorted(k for k in datasets if k.startswith("pose_error") or k == "backgrounds")
    if altered:
        raise SystemExit(f"{source}: its images are not plain renders at its sensor poses ({', '.join(altered)}); "
                         "render a set such as validation or offaxis and perturb it with real_setup_check.py")
    return datasets, attrs


def rendered_poses(datasets: dict) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Where a set's images were rendered: (T_world_object (N, 4, 4), T_world_sensors (N, L, 4, 4), the images'
    leading shape), N the scenes, or the sequences' frames one after the other."""
    sensors = datasets.get("T_world_sensors_true", datasets["T_world_sensors"])
    lead = datasets["images"].shape[: sensors.ndim - 2]  # (N, L) for scenes, (S, F, L) for sequences
    return (datasets["T_world_object"].reshape(-1, 4, 4), sensors.reshape(-1, lead[-1], 4, 4), lead)


def pressed_further(T_world_sensors: np.ndarray, distance: float) -> np.ndarray:
    """(..., 4, 4) sensor poses -> the same poses moved ``distance`` m along each sensor's +x axis, the way its
    camera looks and its gel faces: a press that much deeper (shallower if negative)."""
    moved = np.array(T_world_sensors, dtype=np.float64, copy=True)
    moved[..., :3, 3] += distance * moved[..., :3, 0]
    return moved


def render_set(source: Path, target: Path, data: Path, config: Path, seed: int, deeper: float = 0.0,
               size: tuple[int, int] = SIZE, background: str | None = None) -> dict:
    """Render ``source``'s set with TACTO into ``target`` (module docstring); ``deeper`` (m): every sensor
    pressed that much further than the set's press, its poses in the file moved alike (not for sequences);
    size: the images' (width, height); background: the no-contact image under the data directory (default: the
    one the set was rendered over)."""
    datasets, attrs = read_set(source)
    if deeper:
        if "T_world_sensors_true" in datasets:
            raise SystemExit("--deeper applies to scene sets, not to sequences")
        datasets["T_world_sensors"] = pressed_further(datasets["T_world_sensors"], deeper)
    scene_config = json.loads(attrs["config"])
    background = background or scene_config["render"]["background"]
    renderer = tacto_renderer(config, data / background, size)
    objects = [o.decode() if isinstance(o, bytes) else str(o) for o in datasets["objects"]]
    meshes = {o: untextured(data / "ycb" / o / "textured_simple.obj") for o in sorted(set(objects))}
    T_objects, T_sensors, lead = rendered_poses(datasets)
    per_object = len(T_objects) // len(objects)  # a sequence's frames share its object
    images = np.empty((len(T_objects), lead[-1], size[1], size[0], 3), np.uint8)
    start = time.time()
    for i, (T_object, T_frame) in enumerate(zip(T_objects, T_sensors)):
        renderer.add_object(meshes[objects[i // per_object]], "object", *euler_xyz(T_object))
        for k, T_sensor in enumerate(T_frame):
            renderer.update_camera_pose(*euler_xyz(T_sensor))
            np.random.seed([seed, i, k])  # TACTO draws its noise from the global generator
            colors, _ = renderer.render()
            images[i, k] = colors[0]
        renderer.scene.remove_node(renderer.object_nodes.pop("object"))
        renderer.current_object_nodes.pop("object")
    seconds = time.time() - start
    note = {"tool": "tacto 0.0.3 Renderer", "config": str(config.relative_to(data)),
            "background": background, "seed": seed, "size": list(size),
            "object": "untextured mesh at the true pose, no force", "deeper_m": deeper}
    images = images.reshape(lead + images.shape[2:])
    name = write_images_as_set(datasets, attrs, images, target, "tacto", note)
    return {"set": name, "images": int(np.prod(images.shape[:-3])), "seconds": round(seconds, 1),
            "file": str(target)}


def write_images_as_set(datasets: dict, attrs: dict, images: np.ndarray, target: Path, suffix: str,
                        note: dict) -> str:
    """Write a scene or sequence set's datasets and attributes (as read from its file) to ``target`` with
    ``images`` (..., L, H, W, 3) uint8 in place of its own (the same scenes and sensors; another size than the
    set's is passed on as it is, as a camera at that size gives it), named ``<set>_<suffix>`` (attribute
    ``scene_set`` or ``sequence_set``), ``note`` in its ``renderer`` attribute. Returns the new set's name."""
    if images.shape[:-3] != datasets["images"].shape[:-3] or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ValueError(f"images {images.shape} {images.dtype}, the set's are {datasets['images'].shape} uint8")
    attrs = dict(attrs)
    key = "scene_set" if "scene_set" in attrs else "sequence_set"
    name = f"{json.loads(attrs[key])}_{suffix}"
    attrs[key] = json.dumps(name)
    attrs["renderer"] = json.dumps(note)
    target.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(target, "w") as f:
        for dataset, value in datasets.items():
            value = images if dataset == "images" else value
            if value.dtype == object:
                f.create_dataset(dataset, data=value, dtype=h5py.string_dtype())
            else:
                f.create_dataset(dataset, data=value, compression="gzip" if dataset == "images" else None)
        f.attrs.update(attrs)
    return name


# The scratch folder's own folders: the sets rendered here (beside links to the source's) and what a stage or
# script run on the scratch folder writes (metrics/, times/), which must not reach the pipeline's outputs.
OWN_FOLDERS = ("scenes", "sequences", "metrics", "times")
LINKED_FILES = ("scenes", "sequences")


def link_artifacts(artifacts: Path, out: Path) -> None:
    """Make ``out`` read as ``artifacts``: each entry linked, but for ``OWN_FOLDERS``, folders of its own;
    ``scenes/`` and ``sequences/`` hold links to the source's files, ``metrics/`` and ``times/`` start empty."""
    out.mkdir(parents=True, exist_ok=True)
    for entry in artifacts.iterdir():
        link = out / entry.name
        if entry.name not in OWN_FOLDERS and not link.exists():
            link.symlink_to(entry.resolve())
    for folder in OWN_FOLDERS:
        if (out / folder).is_symlink():  # a folder linked by hand: what is written here would land in the source
            raise SystemExit(f"{out / folder} is a link; --out must have a {folder}/ folder of its own")
        (out / folder).mkdir(exist_ok=True)
    for folder in LINKED_FILES:
        for source in (artifacts / folder).glob("*") if (artifacts / folder).is_dir() else ():
            link = out / folder / source.name
            if not link.exists():
                link.symlink_to(source.resolve())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", type=Path, default=Path("artifacts"))
    parser.add_argument("--scenes", nargs="*", default=["validation"], help="scene sets under <artifacts>/scenes")
    parser.add_argument("--sequences", action="store_true",
                        help="also the tracking sequences (sequences/tracking.h5), written under the same name")
    parser.add_argument("--out", type=Path, required=True, help="a scratch artifacts folder (linked to --artifacts)")
    parser.add_argument("--seed", type=int, default=0, help="TACTO's camera noise")
    parser.add_argument("--deeper", type=float, default=0.0,
                        help="mm: every sensor of the scene sets pressed that much deeper (negative: shallower)")
    parser.add_argument("--size", type=int, nargs=2, default=list(SIZE), metavar=("WIDTH", "HEIGHT"),
                        help="the images' size (TACTO's own default: 120 160)")
    parser.add_argument("--background", help="the no-contact image, under the data directory (default: the set's; "
                                             "TACTO's example unit: digit/tacto/bg_digit_240_320.jpg)")
    parser.add_argument("--config", default="config_digit.yml",
                        help="TACTO's sensor configuration, under the data directory's digit/tacto/ (its variant with "
                             "spot lights and shadows: config_digit_shadow.yml)")
    args = parser.parse_args()
    data = data_dir()
    config = data / "digit" / "tacto" / args.config
    if not config.is_file():
        raise SystemExit(f"no TACTO configuration {config}")
    if args.out.resolve() == args.artifacts.resolve():
        raise SystemExit("--out must not be --artifacts: the pipeline's outputs are left as DVC made them")
    link_artifacts(args.artifacts, args.out)
    for scene_set in args.scenes:
        source = args.artifacts / "scenes" / f"{scene_set}.h5"
        print(json.dumps(render_set(source, args.out / "scenes" / f"{scene_set}_tacto.h5", data, config, args.seed,
                                    args.deeper / 1000, tuple(args.size), args.background)))
    if args.sequences:
        # stage evaluate_tracking reads sequences/tracking.h5: the rendered set takes its place under --out
        target = args.out / "sequences" / "tracking.h5"
        target.unlink(missing_ok=True)  # the link to the pipeline's file
        print(json.dumps(render_set(args.artifacts / "sequences" / "tracking.h5", target, data, config, args.seed,
                                    size=tuple(args.size), background=args.background)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
