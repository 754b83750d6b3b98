"""Stage make_scenes: one scene set with ground truth (``caddeo2023`` imported; ``validation``, ``offaxis``,
``variation``, ``kinematic``, ``calibration`` and ``confidence`` generated: the last two from
``identify.calibration_scenes`` and ``confidence.scenes``, the scenes the stages calibrate_identify and
calibrate_confidence fit on; ``own`` from ``own_set.scenes`` over the own objects of ``own_set.files``, their
artifacts under ``artifacts/own/``, which stage evaluate_own measures). A generated set's section may add what a real set-up does
to its images or sensor poses (``light``, ``kinematics``: ``tactile6d.sim.perturb``), drawn after the clean
set from a generator of its own, so the set's objects, poses and contacts are those of its clean draw.

Reads the objects' artifacts (meshes for contact types; surface points so validation contacts avoid
database points), the paper's triplets from the data directory, config sections ``scenes`` and
``render``. Writes ``artifacts/scenes/<set>.h5`` (schema ``scenes``).
"""

from __future__ import annotations

import sys
import warnings

import numpy as np
from tqdm import tqdm

from tactile6d.core.config import require_key, section_to_dict
from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_scene_dir, write_artifact
from tactile6d.data.object_artifacts import load_mesh, load_surface_points
from tactile6d.data.third_party import DataStore, group_files, group_names
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import contact_types, perturb, scenes, surface_sampling
from tactile6d.sim.render import DigitRenderer, load_background_bgr

SCENE_SETS = ("caddeo2023", "validation", "offaxis", "variation", "kinematic", "calibration", "confidence", "own")
# The generated sets drawn from a section of their own rather than ``scenes``, so that editing one re-makes
# no set of ``scenes.sets``: the two that fit something (the identification weights, the confidence) and
# the own objects' set.
FIT_SETS = {"calibration": "identify.calibration_scenes", "confidence": "confidence.scenes", "own": "own_set.scenes"}


def import_caddeo2023(object_names: list[str], store: DataStore, artifacts_dir: str) -> scenes.SceneSet:
    """The paper's triplets of the given objects, ground truth T_world_object = (0.1, 0, 0.2), R = I."""
    with_triplets = [g.split(":", 1)[1] for g in group_names() if g.startswith("triplets:")]
    chosen = [o for o in object_names if o in with_triplets]
    if not chosen:
        warnings.warn("none of objects.names has triplets in the paper's set: caddeo2023 is empty", stacklevel=2)
    names, objects, poses, images = [], [], [], []
    for obj in chosen:
        folders = sorted({store.path(r).parent for r in group_files(f"triplets:{obj}")})
        for folder in folders:
            T, imgs = read_scene_dir(folder)
            names.append(f"{obj}/{folder.name}")
            objects.append(obj)
            poses.append(T)
            images.append(imgs)
    surfaces = {obj: surface_sampling.sample_surface(load_mesh(artifacts_dir, obj)) for obj in chosen}
    n = len(names)
    T_world_object = np.broadcast_to(scenes.CADDEO2023_T_WORLD_OBJECT, (n, 4, 4)).copy()
    if n == 0:
        return scenes.SceneSet(np.zeros(0, str), np.zeros(0, str), T_world_object, np.zeros((0, 3, 4, 4)),
                               np.zeros((0, 3, 320, 240, 3), np.uint8), np.zeros((0, 3, 3)), np.zeros((0, 3, 3)),
                               np.zeros((0, 3), np.int64))
    return scenes.scene_set_from_known_sensors(names, objects, T_world_object, np.stack(poses), np.stack(images),
                                               surfaces)


def scene_spec(cfg, scene_set: str):
    """The config section a generated set is drawn from: ``FIT_SETS``'s for the sets that fit the
    identification weights or the confidence, ``scenes.<scene_set>`` otherwise."""
    if scene_set in FIT_SETS:
        return require_key(cfg, FIT_SETS[scene_set])
    return cfg.scenes[scene_set]


def generate(scene_set: str, object_names: list[str], cfg, store: DataStore, artifacts_dir: str) -> scenes.SceneSet:
    """A generated scene set from its config section (``scene_spec``); the objects' artifacts in ``artifacts_dir``."""
    v = scene_spec(cfg, scene_set)
    spec = scenes.ValidationSpec(
        scenes_per_object=int(v.scenes_per_object),
        n_sensors=int(v.n_sensors),
        candidates_per_object=int(v.candidates_per_object),
        depth_range=(float(v.depth_min), float(v.depth_max)),
        translation_range=float(v.translation_range),
        min_database_distance=float(v.min_database_distance),
        tilt_max=float(np.radians(v.tilt_max_deg)),
        gel_offset_max=float(v.gel_offset_max),
    )
    meshes = {o: load_mesh(artifacts_dir, o) for o in object_names}
    surfaces = {o: surface_sampling.sample_surface(m) for o, m in meshes.items()}
    database = {o: load_surface_points(artifacts_dir, o) for o in object_names}
    renderer = DigitRenderer.from_config(cfg.render, load_background_bgr(cfg, store), workers=1)

    def render(obj, T_world_object, T_world_sensors, seed):
        return np.stack([renderer.render(meshes[obj], T_world_object, T, seed + i).image
                         for i, T in enumerate(T_world_sensors)])

    with tqdm(total=len(object_names) * spec.scenes_per_object, desc=f"{scene_set} scenes", unit="scene") as bar:
        out = scenes.generate_validation(object_names, meshes, surfaces, database, render, spec, int(v.seed),
                                         progress=bar.update)
    return real_set_up(out, v, renderer.background.astype(np.uint8))  # RGB, as the scenes' images


def real_set_up(out: scenes.SceneSet, v, background_rgb: np.ndarray) -> scenes.SceneSet:
    """A generated set as a real set-up gives it: its section's ``light`` and ``kinematics``, when it has
    them (``tactile6d.sim.perturb``), each from its own generator seeded by the set's seed."""
    if v.get("light") is not None:
        light = v.light
        out = perturb.drift_light(out, background_rgb, float(light.gain_max),
                                  (float(light.gamma_min), float(light.gamma_max)), float(light.noise_std),
                                  float(light.rerecorded), np.random.default_rng((int(v.seed), 1)))
    if v.get("kinematics") is not None:
        k = v.kinematics
        out = perturb.perturb_sensor_poses(out, 1e-3 * float(k.sigma_mm), np.radians(float(k.sigma_deg)),
                                           np.random.default_rng((int(v.seed), 2)))
    return out


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(
        argv, __doc__.splitlines()[0],
        add_arguments=lambda p: p.add_argument("--scene-set", required=True, choices=SCENE_SETS),
    )
    scene_set = args.scene_set
    artifacts_dir = cfg.paths.artifacts_dir
    store = DataStore(cfg.paths)
    object_names, objects_dir = list(cfg.objects.names), artifacts_dir
    if scene_set == "own":  # the own objects of own_set, whose artifacts live one level down
        object_names, objects_dir = list(cfg.own_set.files), str(layout.own_dir(artifacts_dir))
    if scene_set == "caddeo2023":
        out = import_caddeo2023(object_names, store, objects_dir)
    else:
        out = generate(scene_set, object_names, cfg, store, objects_dir)
    counts = np.bincount(out.contact_types.ravel(), minlength=len(contact_types.CONTACT_TYPES))
    print(f"{scene_set}: {len(out)} scenes; contact types "
          + ", ".join(f"{t} {c}" for t, c in zip(contact_types.CONTACT_TYPES, counts)))
    write_artifact(
        layout.scenes_file(artifacts_dir, scene_set),
        "scenes",
        out.as_datasets(),
        attrs={"scene_set": scene_set, "contact_type_counts": counts.tolist()},
        config={"scenes": section_to_dict(cfg, "scenes"), "render": section_to_dict(cfg, "render"),
                **({FIT_SETS[scene_set]: section_to_dict(cfg, FIT_SETS[scene_set])}
                   if scene_set in FIT_SETS else {}),
                "objects": section_to_dict(cfg, "objects")},
        compression="lzf",
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
