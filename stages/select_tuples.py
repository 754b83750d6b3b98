"""Stage select_tuples: candidate tuples of database points for every scene of a scene set (tactile and distance selection; the baseline skips the tactile part).

Reads ``artifacts/scenes/<set>.h5``, each scene object's ``surfaces/<obj>.h5`` and, for method ``ours``,
its ``latents/<obj>.h5``, the autoencoder checkpoint, the no-contact background (``render.background``)
and, for ``select.contacts=patch``, the patch calibration (``artifacts/patch/model.npz``); config section
``select``. Writes ``artifacts/runs/<set>/<method>/tuples.h5``: per scene the tuples and their distance
errors (stacked, with offsets), the selection diagnostics, the sensor poses and the sensors' contacts
(so the later stages need not read the scenes again), seconds spent encoding and selecting, and why a
scene failed ('' when it did not).
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tqdm import tqdm

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import NoMatch, exit_on_error
from tactile6d.core.settings import METHODS, SelectSettings, SensorSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.data.object_artifacts import load_database_angles, load_surface_normals, load_surface_points
from tactile6d.estimation.run_storage import stack_contacts, stack_ragged
from tactile6d.estimation.select import select
from tactile6d.perception.autoencoder import load_checkpoint
from tactile6d.perception.encode import (
    LatentAngleEncoder,
    align_light,
    load_background,
    load_patch_model,
    read_angles,
    read_contacts,
)
from tactile6d.perception.inputs import check_images, check_sensor_poses
from tactile6d.runtime.stage_args import median_or_nan, parse_run_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.scenes import scene_set_from_artifact


class Database:
    """What selection reads of each object: its points and latent angles (``data.object_artifacts``, which
    reads each file once), and the autoencoder, loaded once (method ours)."""

    def __init__(self, cfg, ours: bool, normals: bool = False):
        self.artifacts = cfg.paths.artifacts_dir
        self.ours = ours
        self.normals = normals
        if ours:
            self.model, self.norm, _ = load_checkpoint(layout.ae_checkpoint(self.artifacts))
            self.background = load_background(cfg)

    def __getitem__(self, name: str):
        """-> (points (M, 3), database angles (M,) or None, encoder or None, normals (M, 3) or None)."""
        points = load_surface_points(self.artifacts, name)
        normals = load_surface_normals(self.artifacts, name) if self.normals else None
        if not self.ours:
            return points, None, None, normals
        angles, latent_nc = load_database_angles(self.artifacts, name)
        return points, angles, LatentAngleEncoder(self.model, self.norm, self.background, latent_nc), normals


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_run_stage_args(argv, __doc__.splitlines()[0], METHODS)
    settings = SelectSettings.from_cfg(cfg.select)
    sensors = SensorSettings.from_cfg(cfg.sensors)
    artifacts = cfg.paths.artifacts_dir
    scenes = scene_set_from_artifact(read_artifact(layout.scenes_file(artifacts, args.scene_set), "scenes"))
    n_scenes, n_sensors = scenes.T_world_sensors.shape[:2]
    database = Database(cfg, settings.method == "ours", settings.uses_normals)
    patch_model = load_patch_model(artifacts) if settings.reads_patches else None
    # The no-contact image every sensor is read against, unless the set carries each sensor's own.
    no_contact = database.background if settings.method == "ours" else None

    tuples, errors, contacts = [], [], []
    angles = np.full((n_scenes, n_sensors), np.nan)
    omega_sizes = np.zeros((n_scenes, n_sensors), dtype=np.int64)
    delta_h = np.full((n_scenes, n_sensors), np.nan)
    widened = np.zeros((n_scenes, n_sensors), dtype=bool)
    delta_d = np.full(n_scenes, np.nan)
    capped = np.zeros(n_scenes, dtype=bool)
    seconds = np.zeros((n_scenes, 2))
    failure = [""] * n_scenes
    for s in tqdm(range(n_scenes), desc=f"select_tuples {args.scene_set}/{args.method}", unit="scene"):
        points, db_angles, encoder, normals = database[str(scenes.objects[s])]
        T = check_sensor_poses(scenes.T_world_sensors[s])
        t0 = time.perf_counter()
        images = check_images(scenes.images[s], n_sensors) if encoder is not None else None
        own = scenes.backgrounds_of(s) if encoder is not None else None
        scene_no_contact = no_contact if own is None else own
        images, _ = align_light(settings, images, scene_no_contact)
        contacts.append(read_contacts(settings, T, images, scene_no_contact, patch_model))
        if encoder is not None:
            angles[s] = read_angles(encoder, settings, images, contacts[s], T, scene_no_contact, own)
        t1 = time.perf_counter()
        seconds[s, 0] = t1 - t0
        try:
            chosen = select(points, db_angles, contacts[s], angles[s], settings, normals, sensors=sensors)
        except NoMatch as exc:
            # A scene that matches nothing is a failed estimate, not a failed pipeline; bad input stops it.
            failure[s] = str(exc)
            tuples.append(np.zeros((0, n_sensors)))
            errors.append(np.zeros(0))
            continue
        seconds[s, 1] = time.perf_counter() - t1
        tuples.append(chosen.tuples)
        errors.append(chosen.errors)
        omega_sizes[s], delta_h[s], widened[s] = chosen.omega_sizes, chosen.delta_h, chosen.widened
        delta_d[s], capped[s] = chosen.delta_d, chosen.capped

    stacked, offsets = stack_ragged(tuples, (n_sensors,), np.int32)
    stacked_errors, _ = stack_ragged(errors, (), np.float32)
    n_failed = sum(bool(f) for f in failure)
    print(f"{args.scene_set}/{args.method}: {n_scenes} scenes, median {median_or_nan(np.diff(offsets)):.0f} "
          f"tuples, {int(widened.any(axis=1).sum())} with a widened delta_h, {n_failed} failed")
    write_artifact(
        layout.run_dir(artifacts, args.scene_set, args.method) / "tuples.h5",
        "tuples",
        {
            "names": np.asarray(scenes.names, dtype=str), "objects": np.asarray(scenes.objects, dtype=str),
            "T_world_sensors": scenes.T_world_sensors,
            "tuples": stacked, "errors": stacked_errors, "offsets": offsets, "angles": angles,
            "omega_sizes": omega_sizes, "delta_h": delta_h, "widened": widened, "delta_d": delta_d,
            "capped": capped, "seconds_encode": seconds[:, 0], "seconds_select": seconds[:, 1],
            "failure": np.asarray(failure, dtype=str), **stack_contacts(contacts, n_sensors),
        },
        attrs={"scene_set": args.scene_set, "method": args.method},
        config={"select": section_to_dict(cfg, "select"), "sensors": section_to_dict(cfg, "sensors"),
                "render": {"background": cfg.render.background}},
        compression="lzf",
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
