"""A scene set rendered again by TACTO itself, the simulator the paper rendered with: scenes of another tool.

    make tacto-env                                   # .venv-tacto: TACTO 0.0.3, pyrender, EGL (no display needed)
    .venv-tacto/bin/python scripts/tacto_scenes.py --artifacts artifacts --scenes validation offaxis --out ART

Runs in its own environment (``make tacto-env``), not the project's: TACTO pins an old PyOpenGL and imports
urdfpy, and neither is needed anywhere else. It imports nothing of ``tactile6d``.

For each scene of ``<artifacts>/scenes/<set>.h5`` (made by ``make_scenes``) it places the set's object, without
its texture, at the scene's true pose and renders every sensor at its true pose with TACTO's ``Renderer`` and
its shipped DIGIT configuration (``digit/tacto/config_digit.yml`` of the data directory: lights, gel, camera,
noise of 7 grey levels), over the no-contact image the set was rendered over (its config's
``render.background``), at 240 x 320. The object is not pushed by a force: the scene's press (the gel 1-2 mm
into the object) is TACTO's geometry as given. TACTO's noise is drawn from NumPy's global generator, seeded
by ``--seed`` and the scene's index, so a set is rendered again to the same bits on one machine.

Writes ``<out>/scenes/<set>_tacto.h5``: the source file's every dataset and attribute, the images replaced, the
scene set named ``<set>_tacto`` and a ``renderer`` attribute saying how it was made. Everything else the
project's scripts read under ``--out`` (surfaces, databases, the autoencoder) is linked to ``--artifacts``, so
that ``scripts/real_setup_check.py --artifacts <out> --scenes validation_tacto`` estimates the set under a real
set-up's conditions without touching the pipeline's outputs. About 0.1 s an image on the 2-core machine.
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

WIDTH, HEIGHT = 240, 320  # the DIGIT images' size, as the paper rendered them


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


def tacto_renderer(config: Path, background_file: Path):
    """TACTO's ``Renderer`` for DIGIT images of 240 x 320 over that no-contact image (imported here: only the
    TACTO environment has it)."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless: Mesa's EGL, no display
    if not hasattr(np, "float"):
        np.float = float  # TACTO 0.0.3 still uses the alias NumPy 1.24 removed
    from tacto.renderer import Renderer

    # TACTO's examples read the no-contact image with OpenCV (BGR) and its Renderer turns it to RGB.
    return Renderer(width=WIDTH, height=HEIGHT, background=cv2.imread(str(background_file)), config_path=str(config))


def read_set(source: Path) -> tuple[dict, dict]:
    """A scene set file's datasets and root attributes, if its images are renders at the poses it gives."""
    with h5py.File(source, "r") as f:
        datasets = {name: f[name][()] for name in f}
        attrs = dict(f.attrs)
    # kinematic's T_world_sensors are the poses reported, not those rendered at; variation's images are
    # perturbed after rendering, over no-contact images of their own. scripts/real_setup_check.py applies
    # both to a set rendered here (conditions kinematic, light).
    altered = sorted(k for k in datasets if k.startswith("pose_error") or k == "backgrounds")
    if altered:
        raise SystemExit(f"{source}: its images are not plain renders at its sensor poses ({', '.join(altered)}); "
                         "render a set such as validation or offaxis and perturb it with real_setup_check.py")
    return datasets, attrs


def render_set(source: Path, target: Path, data: Path, config: Path, seed: int) -> dict:
    datasets, attrs = read_set(source)
    scene_config = json.loads(attrs["config"])
    renderer = tacto_renderer(config, data / scene_config["render"]["background"])
    objects = [o.decode() if isinstance(o, bytes) else str(o) for o in datasets["objects"]]
    meshes = {o: untextured(data / "ycb" / o / "textured_simple.obj") for o in sorted(set(objects))}
    images = np.empty_like(datasets["images"])
    start = time.time()
    for i, obj in enumerate(objects):
        position, orientation = euler_xyz(datasets["T_world_object"][i])
        renderer.add_object(meshes[obj], "object", position=position, orientation=orientation)
        for s, T_sensor in enumerate(datasets["T_world_sensors"][i]):
            renderer.update_camera_pose(*euler_xyz(T_sensor))
            np.random.seed([seed, i, s])  # TACTO draws its noise from the global generator
            colors, _ = renderer.render()
            images[i, s] = colors[0]
        renderer.scene.remove_node(renderer.object_nodes.pop("object"))
        renderer.current_object_nodes.pop("object")
    seconds = time.time() - start
    note = {"tool": "tacto 0.0.3 Renderer", "config": str(config.relative_to(data)),
            "background": scene_config["render"]["background"], "seed": seed,
            "object": "untextured mesh at the scene's true pose, no force"}
    name = write_images_as_set(datasets, attrs, images, target, "tacto", note)
    return {"scene_set": name, "scenes": len(objects), "images": int(images.shape[0] * images.shape[1]),
            "seconds": round(seconds, 1), "file": str(target)}


def write_images_as_set(datasets: dict, attrs: dict, images: np.ndarray, target: Path, suffix: str,
                        note: dict) -> str:
    """Write a scene set's datasets and attributes (as read from its file) to ``target`` with ``images``
    (N, L, 320, 240, 3) uint8 in place of its own, named ``<set>_<suffix>``, ``note`` in its ``renderer``
    attribute. Returns the new set's name."""
    if images.shape != datasets["images"].shape or images.dtype != np.uint8:
        raise ValueError(f"images {images.shape} {images.dtype}, the set's are {datasets['images'].shape} uint8")
    attrs = dict(attrs)
    name = f"{json.loads(attrs['scene_set'])}_{suffix}"
    attrs["scene_set"] = json.dumps(name)
    attrs["renderer"] = json.dumps(note)
    target.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(target, "w") as f:
        for key, value in datasets.items():
            value = images if key == "images" else value
            if value.dtype == object:
                f.create_dataset(key, data=value, dtype=h5py.string_dtype())
            else:
                f.create_dataset(key, data=value, compression="gzip" if key == "images" else None)
        f.attrs.update(attrs)
    return name


def link_artifacts(artifacts: Path, out: Path) -> None:
    """Make ``out`` read as ``artifacts`` (each entry linked) but for its own ``scenes/`` folder, which links
    the source's scene files beside the ones written here."""
    out.mkdir(parents=True, exist_ok=True)
    for entry in artifacts.iterdir():
        link = out / entry.name
        if entry.name != "scenes" and not link.exists():
            link.symlink_to(entry.resolve())
    (out / "scenes").mkdir(exist_ok=True)
    for scene_file in (artifacts / "scenes").iterdir():
        link = out / "scenes" / scene_file.name
        if not link.exists():
            link.symlink_to(scene_file.resolve())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", type=Path, default=Path("artifacts"))
    parser.add_argument("--scenes", nargs="+", default=["validation"], help="scene sets under <artifacts>/scenes")
    parser.add_argument("--out", type=Path, required=True, help="a scratch artifacts folder (linked to --artifacts)")
    parser.add_argument("--seed", type=int, default=0, help="TACTO's camera noise")
    args = parser.parse_args()
    data = data_dir()
    config = data / "digit" / "tacto" / "config_digit.yml"
    if args.out.resolve() == args.artifacts.resolve():
        raise SystemExit("--out must not be --artifacts: the pipeline's outputs are left as DVC made them")
    link_artifacts(args.artifacts, args.out)
    for scene_set in args.scenes:
        source = args.artifacts / "scenes" / f"{scene_set}.h5"
        print(json.dumps(render_set(source, args.out / "scenes" / f"{scene_set}_tacto.h5", data, config, args.seed)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
