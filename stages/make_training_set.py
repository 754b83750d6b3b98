"""Stage make_training_set: tactile images of contacts with random superquadrics, for the autoencoder.

Reads config sections ``training_set`` (how many images, shapes, sizes, exponents, press depths;
tactile6d.superquadrics.sample_training_contacts) and ``render`` (the simulator and its background, read
from the data directory). Writes ``artifacts/training_set.h5`` (schema ``training_set``,
tactile6d.sim.database): the images and contact masks stored compactly, and per image its sensor pose in
the shape's frame, the shape (``shape_index``, semi-axes, exponents e1 and e2), press depth, roll, contact
kind (``superquadrics.KIND_NAMES``: the kind of the mesh vertex nearest to the contact point), contact type
(``contact_types``: tactile6d.sim.contact_types' classifier, the one that labels the YCB database points, applied
to the shape's mesh; train_ae ranks latent angles by it) and whether the shape enters the sensor body
(``body_contact``, rendered anyway, as TACTO would).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.core.sensor import contact_normals, sensor_poses_to_surface_points
from tactile6d.data import layout
from tactile6d.data.hdf5 import write_artifact
from tactile6d.data.third_party import DataStore
from tactile6d.runtime.executor import executor_from_config
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import contact_types, database
from tactile6d.sim import superquadrics as sq
from tactile6d.sim import surface_sampling
from tactile6d.sim.render import DigitRenderer, add_noise, load_background_bgr, mesh_arrays, task_renderer


def render_shape(settings: dict, background_bgr: np.ndarray, shape: sq.Superquadric, T_object_sensors: np.ndarray,
                 depths: np.ndarray, mesh_max_edge: float, mesh_max_turn: float,
                 sharp_radius: float) -> tuple[database.EncodedImages, np.ndarray, np.ndarray, np.ndarray]:
    """One task: the contacts of one shape, at T_object_sensors (k, 4, 4) pressed ``depths`` (k,) in ->
    (their encoded images, kinds (k,), contact types (k,), body contacts (k,)).

    The shape is meshed here (deterministic from the shape and the mesh settings of section training_set),
    so only the shape's parameters travel; the renderer is built once per process (``render.task_renderer``).
    """
    renderer = task_renderer(settings, background_bgr)
    mesh = sq.superquadric_mesh(shape, mesh_max_edge, mesh_max_turn)
    encoded = database.render_encoded(renderer, mesh_arrays(mesh), T_object_sensors)
    touched = sensor_poses_to_surface_points(T_object_sensors, depths)
    kinds = sq.nearest_vertex_kinds(mesh, touched, sharp_radius)
    types = contact_types.classify_contacts(surface_sampling.sample_surface(mesh), touched,
                                            contact_normals(T_object_sensors))
    return encoded, kinds, types, database.body_contacts(mesh.vertices, T_object_sensors)


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    start = time.perf_counter()
    ts = cfg.training_set
    n = int(ts.n_images)
    if n < 1:
        raise ConfigError(f"training_set.n_images must be positive, got {n}")
    rng = np.random.default_rng(int(ts.seed))
    contacts = sq.sample_training_contacts(n, rng, ts)
    noise_seeds = rng.integers(0, 2**62, size=n + 1)  # one per image, the last for the no-contact image
    poses = np.stack([c.T_object_sensor for c in contacts])
    depths = np.array([c.depth for c in contacts])

    groups = sq.training_contact_groups(contacts)
    kinds = np.empty(n, dtype=np.uint8)
    type_codes = np.empty(n, dtype=np.int8)
    body = np.empty(n, dtype=bool)
    background = load_background_bgr(cfg, DataStore(cfg.paths))
    # This one only gives the settings the tasks rebuild it from and the background they encode over.
    renderer = DigitRenderer.from_config(cfg.render, background, noise_std=0.0, strict=False, workers=1)
    images = database.CompactImages(renderer.background)
    workers = int(cfg.render.workers)
    if workers < 1:
        raise ConfigError(f"render.workers must be >= 1, got {workers}")
    k = len(groups)
    with executor_from_config(cfg, workers) as executor:
        parts = executor.map(
            render_shape, [renderer.settings] * k, [background] * k, [contacts[a].shape for a, _ in groups],
            [poses[a:b] for a, b in groups], [depths[a:b] for a, b in groups],
            [float(ts.mesh_max_edge)] * k, [float(ts.mesh_max_turn)] * k, [float(ts.sharp_radius)] * k,
            desc="make_training_set")
    for (a, b), (encoded, kinds[a:b], type_codes[a:b], body[a:b]) in zip(groups, parts):
        images.extend(encoded)
    shape_index = np.concatenate([np.full(b - a, k) for k, (a, b) in enumerate(groups)])
    no_contact = add_noise(images.background, float(cfg.render.noise_std), int(noise_seeds[-1]))

    path = write_artifact(
        layout.training_set_file(cfg.paths.artifacts_dir),
        "training_set",
        {
            "T_object_sensor": poses,
            "shape_index": shape_index,
            "axes": np.array([c.shape.axes for c in contacts]),
            "exponents": np.array([[c.shape.e1, c.shape.e2] for c in contacts]),
            "depths": depths,
            "rolls": np.array([c.roll for c in contacts]),
            "kinds": kinds,
            "contact_types": type_codes,
            "no_contact": no_contact,
            "body_contact": body,
            **images.datasets(float(cfg.render.noise_std), noise_seeds[:-1]),
        },
        attrs={"kind_names": list(sq.KIND_NAMES), "contact_type_names": list(contact_types.CONTACT_TYPES),
               "n_shapes": len(groups)},
        config={"training_set": section_to_dict(cfg, "training_set"), "render": section_to_dict(cfg, "render")},
    )
    size = path.stat().st_size
    counts = np.bincount(kinds, minlength=len(sq.KIND_NAMES))
    print(
        f"training set: {n} images of {len(groups)} shapes in {time.perf_counter() - start:.1f} s, "
        f"{size / 2**20:.1f} MB ({size / n / 1024:.1f} KB per image); contact in "
        f"{np.count_nonzero(images.mask_pixels)}; kinds "
        + ", ".join(f"{name} {c}" for name, c in zip(sq.KIND_NAMES, counts))
        + "; contact types "
        + ", ".join(f"{name} {int(np.sum(type_codes == code))}" for code, name in enumerate(contact_types.CONTACT_TYPES))
        + f"; shape inside the sensor body in {int(body.sum())}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
