"""Every kind of HDF5 artifact the pipeline writes: its datasets, its format version, the stage that makes it.

Data only: ``tactile6d.data.hdf5`` stamps each artifact with its schema's name and version on writing, and on
reading rejects any other version and any missing dataset, naming the stage to re-run. Bump a schema's
version whenever its format changes (a dataset added, removed, renamed or re-shaped, or its meaning
changed), so that an artifact written by older code is refused with that hint instead of being read
wrongly; readers then need no fallbacks for older formats.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Schema:
    """What an artifact of one kind must hold, and which stage makes it."""

    name: str
    version: int
    stage: str
    datasets: tuple[str, ...]
    groups: tuple[str, ...] = field(default=())


# A set of tactile images stored compactly; tactile6d.sim.database's docstring describes each dataset.
IMAGE_DATASETS = (
    "background",
    "noise_std",
    "noise_seeds",
    "images/data",
    "images/offsets",
    "masks/data",
    "masks/offsets",
    "mask_pixels",
    "body_contact",
)

# A scene set (tactile6d.sim.scenes): per scene its name, object, true pose, sensor poses, images (S, L, H,
# W, 3) and the true contact points, normals and kinds.
SCENE_FIELDS = ("names", "objects", "T_world_object", "T_world_sensors", "images", "contact_points",
                "contact_normals", "contact_types")

# A tracking sequence set (tactile6d.sim.sequences): per sequence its name and object, the frame rate, and per
# frame the object's pose, the sensor poses as reported and true, the images (Q, F, L, H, W, 3), whether each
# sensor touches, its true contact point, normal, press depth and lift, and per sensor the kinematic bias drawn.
SEQUENCE_FIELDS = ("names", "objects", "fps", "T_world_object", "T_world_sensors", "T_world_sensors_true", "images",
                   "touching", "contact_points", "contact_normals", "depths", "lift_weights", "pose_bias_translation",
                   "pose_bias_rotvec")

# The estimation stages (select_tuples, optimize, rank) each carry these from scene to scene...
CARRIED_FIELDS = ("names", "objects", "T_world_sensors", "failure")
# ...the sensors' contacts (tactile6d.perception.contacts), per scene and sensor: points (S, L, 3), normals (S, L, 3),
# from_patch (S, L)...
CONTACT_FIELDS = ("contact_points", "contact_normals", "contact_from_patch")
# ...and the observed patches, mask and depth (S, L, 320, 240), or (S, L, 0, 0) for landmark contacts.
PATCH_FIELDS = ("contact_masks", "contact_depths")

SCHEMAS: dict[str, Schema] = {
    s.name: s
    for s in [
        # A cleaned object: mesh, collision pieces (concatenated, with offsets), metric points.
        Schema("object", 1, "prepare_object",
               ("vertices", "faces", "collision_vertices", "collision_faces", "collision_vertex_offsets",
                "collision_face_offsets", "metric_points")),
        # M surface points with outward unit normals, in the object frame.
        Schema("surface", 1, "sample_surface", ("points", "normals", "face_index")),
        # The surface points, the sensor touching each, and its image.
        Schema("database", 1, "render_database",
               ("points", "normals", "T_object_sensor", "rolls", "depths", "no_contact", *IMAGE_DATASETS)),
        # Contacts with random superquadrics: images, and each image's shape, placement and contact type.
        # Version 2 added contact_types (tactile6d.sim.contact_types), which the autoencoder's ranking loss needs.
        Schema("training_set", 2, "make_training_set",
               ("T_object_sensor", "shape_index", "axes", "exponents", "depths", "rolls", "kinds",
                "contact_types", "no_contact", *IMAGE_DATASETS)),
        # The database latents (M, 128), the no-contact latent (128,), each image's latent angle (M,) rad.
        Schema("latents", 1, "encode_database", ("latents", "latent_nc", "angles")),
        # Version 2: sets may carry each sensor's own no-contact image (backgrounds) and how they were perturbed.
        Schema("scenes", 2, "make_scenes", SCENE_FIELDS),
        # Tracking sequences: an object in a moving grasp, frame by frame.
        Schema("sequences", 1, "make_sequences", SEQUENCE_FIELDS),
        # Candidate tuples per scene, with the selection's diagnostics and timings.
        Schema("tuples", 2, "select_tuples",
               CARRIED_FIELDS + CONTACT_FIELDS + PATCH_FIELDS
               + ("tuples", "errors", "offsets", "angles", "omega_sizes", "delta_h", "widened", "delta_d", "capped",
                  "seconds_encode", "seconds_select")),
        # Optimised poses per tuple and start.
        Schema("hypotheses", 2, "optimize",
               CARRIED_FIELDS + CONTACT_FIELDS + PATCH_FIELDS
               + ("translations", "rotvecs", "losses", "tuple_index", "offsets", "seconds_encode", "seconds_select",
                  "seconds_optimize")),
        # The best poses per scene, ranked.
        Schema("ranked", 2, "rank",
               CARRIED_FIELDS + CONTACT_FIELDS
               + ("poses", "scores", "losses", "penetrations", "n_poses", "seconds_encode", "seconds_select",
                  "seconds_optimize", "seconds_rank")),
    ]
}
