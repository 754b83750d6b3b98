"""How far a sensor image's latent angle lies from that of the database point at its true contact.

The tactile selection keeps a database point for a sensor when their latent angles (to the no-contact
image, ``autoencoder.latent_angles``) differ by less than ``select.delta_h``; the gap at the true
contact point says whether the right point can survive it. The ae_quality stage reports it on
caddeo2023 (docs/autoencoder.md has the study that measured it on the generated sets).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tactile6d.core.geometry import invert_pose, transform_points
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.perception import autoencoder


def triplet_gaps(artifacts: str, angles: dict, points: dict, model, norm, background,
                 scene_set: str = "caddeo2023", prepare=None) -> np.ndarray:
    """|angle(sensor image) - angle(database point nearest the true contact)| per sensor of a scene set,
    sensor by sensor, scene by scene (scenes of objects missing from ``angles`` are skipped).

    artifacts: the artifacts directory (reads the scene set and each object's ``latents``); angles and
    points: per object name, its database points' latent angles (M,) radians and positions (M, 3)
    metres in the object frame; model, norm: ``autoencoder.load_checkpoint``'s; background: the
    no-contact image (320, 240, 3) uint8; prepare: optional ``(images (L, 320, 240, 3), T_world_sensors
    (L, 4, 4)) -> images`` applied before encoding (as ``select.centre_images`` does).
    Returns (n_sensors,) radians.
    """
    scenes = read_artifact(layout.scenes_file(artifacts, scene_set), "scenes")
    gaps = []
    for s, obj in enumerate(scenes["objects"].tolist()):
        if obj not in angles:
            continue
        latent_nc = read_artifact(layout.latents_file(artifacts, obj), "latents")["latent_nc"]
        images = scenes["images"][s]
        if prepare is not None:
            images = prepare(images, scenes["T_world_sensors"][s])
        image_angles = autoencoder.latent_angles(autoencoder.encode(model, norm, images, background), latent_nc)
        local = transform_points(invert_pose(scenes["T_world_object"][s]), scenes["contact_points"][s])
        _, nearest = cKDTree(points[obj]).query(local)
        gaps.extend(np.abs(image_angles - angles[obj][nearest]).tolist())
    return np.asarray(gaps)
