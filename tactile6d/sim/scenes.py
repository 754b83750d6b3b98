"""Scene sets with ground truth: the paper's 40 triplets, and generated scenes (``validation``, where every
sensor touches with its gel apex along the surface normal, and ``offaxis``, where each sensor is tilted
and touches off the gel's centre, as a fingertip does).

A scene is one object at a known pose touched by L sensors. Arrays (S scenes, L sensors):
``objects`` (S,) str, ``T_world_object`` (S, 4, 4), ``T_world_sensors`` (S, L, 4, 4),
``images`` (S, L, 320, 240, 3) uint8 RGB, ``contact_points`` (S, L, 3) and ``contact_normals`` (S, L, 3)
in the world frame (outward surface normals), ``contact_types`` (S, L) codes of
``tactile6d.sim.contact_types.CONTACT_TYPES``; optionally ``backgrounds`` (S, L, 320, 240, 3) uint8 RGB, each
sensor's own no-contact image (sets whose sensors have their own, ``tactile6d.sim.perturb``; without, every
sensor's is ``render.background``'s). A set may carry more arrays (``extra``: how it was perturbed).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import trimesh

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import (
    invert_pose,
    make_pose,
    orthonormal_frame,
    random_rotations,
    rotvec_to_rotmat,
    transform_points,
)
from tactile6d.core.sensor import (
    BOX_CENTER,
    BOX_HALF_EXTENTS,
    GEL_CENTER,
    bodies_overlap,
    contact_normals,
    contact_points,
    sensor_poses_touching,
)
from tactile6d.data.hdf5 import Artifact
from tactile6d.data.schemas import SCENE_FIELDS
from tactile6d.sim import contact_types, surface_sampling
from tactile6d.sim.render import CAMERA_POSITION, gel_surface

# The paper's ground truth for all 40 triplets.
CADDEO2023_T_WORLD_OBJECT = make_pose(np.eye(3), [0.1, 0.0, 0.2])


@dataclass
class SceneSet:
    """Scenes of one set, all with the same number of sensors L (arrays as in the module docstring)."""

    names: np.ndarray
    objects: np.ndarray
    T_world_object: np.ndarray
    T_world_sensors: np.ndarray
    images: np.ndarray
    contact_points: np.ndarray
    contact_normals: np.ndarray
    contact_types: np.ndarray
    backgrounds: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.names)

    def backgrounds_of(self, s: int) -> np.ndarray | None:
        """Scene s's sensors' own no-contact images (L, 320, 240, 3), or None when the set has none."""
        return None if self.backgrounds is None else self.backgrounds[s]

    def as_datasets(self) -> dict[str, np.ndarray]:
        own = {} if self.backgrounds is None else {"backgrounds": self.backgrounds}
        return {**{k: getattr(self, k) for k in SCENE_FIELDS}, **own, **self.extra}


def scene_set_from_artifact(art: Artifact) -> SceneSet:
    """A SceneSet from a ``scenes`` artifact (``tactile6d.data.hdf5.read_artifact(path, "scenes")``)."""
    extra = {k: np.asarray(v) for k, v in art.data.items() if k not in SCENE_FIELDS and k != "backgrounds"}
    backgrounds = np.asarray(art["backgrounds"]) if "backgrounds" in art else None
    return SceneSet(**{k: np.asarray(art[k]) for k in SCENE_FIELDS}, backgrounds=backgrounds, extra=extra)


def concatenate(sets: list[SceneSet]) -> SceneSet:
    """Scenes of several sets (same L) as one set; their own no-contact images only if every set has them."""
    own = [s.backgrounds for s in sets]
    backgrounds = None if any(b is None for b in own) else np.concatenate(own)
    return SceneSet(**{k: np.concatenate([getattr(s, k) for s in sets]) for k in SCENE_FIELDS},
                    backgrounds=backgrounds)


def scene_set_from_known_sensors(
    names: list[str],
    objects: list[str],
    T_world_object: np.ndarray,
    T_world_sensors: np.ndarray,
    images: np.ndarray,
    surfaces: dict[str, surface_sampling.SurfaceSamples],
) -> SceneSet:
    """Ground truth of scenes whose sensors are given: contact point = each sensor's landmark, normal =
    its -x axis, type = the classifier's at that point (object frame). Used for the paper's triplets."""
    points = contact_points(T_world_sensors)
    normals = contact_normals(T_world_sensors)
    types = np.zeros(points.shape[:2], dtype=np.int64)
    for s, obj in enumerate(objects):
        T_object_world = invert_pose(T_world_object[s])
        p_obj = transform_points(T_object_world, points[s])
        n_obj = normals[s] @ T_object_world[:3, :3].T
        types[s] = contact_types.classify_contacts(surfaces[obj], p_obj, n_obj)
    return SceneSet(np.asarray(names), np.asarray(objects), T_world_object, T_world_sensors, images, points,
                    normals, types)


# --- validation scenes ----------------------------------------------------------------------------


def body_penetrates(surface: surface_sampling.SurfaceSamples, T_object_sensor: np.ndarray, margin: float = 0.0) -> bool:
    """Whether the sensor's body box and the object overlap: some of the object's surface lies inside the
    box, or the whole box lies inside the object (the gel lies beyond the box, at x > 19.6 mm, so a
    pressed gel alone never counts).

    The second case has no surface inside the box. It happens where a candidate point's normal faces
    into the solid's interior, as on the inner lip of a can's rim: a sensor "touching" there from along
    that normal sits wholly inside the can (offaxis scene 002_master_chef_can/scene_2 before 2026-11-23).
    """
    local = transform_points(invert_pose(T_object_sensor), surface.points)
    inside = np.all(np.abs(local - BOX_CENTER) < BOX_HALF_EXTENTS - margin, axis=1)
    if inside.any():
        return True
    box_center = transform_points(T_object_sensor, BOX_CENTER[None])
    return bool(surface.mesh.contains(box_center)[0])


@dataclass(frozen=True)
class ValidationSpec:
    """How generated scenes are drawn (config section ``scenes.<set>``; validation and offaxis alike).

    tilt_max (rad): each sensor's +x axis is turned from the inward surface normal by an angle uniform in
    [0, tilt_max] about a random axis; gel_offset_max (m): the gel point that touches is off the gel's
    centre by up to this in y and z (uniform). Both 0: the sensor touches with its apex, as in the
    paper's data, and no extra random numbers are drawn.
    """

    scenes_per_object: int = 4
    n_sensors: int = 3
    candidates_per_object: int = 600
    depth_range: tuple[float, float] = (0.0015, 0.0020)
    translation_range: float = 0.05
    min_database_distance: float = 0.0005
    max_tries: int = 200
    tilt_max: float = 0.0
    gel_offset_max: float = 0.0

    @property
    def off_axis(self) -> bool:
        return self.tilt_max > 0 or self.gel_offset_max > 0


def gel_point(offset_y: float, offset_z: float) -> np.ndarray:
    """(3,) sensor frame, m: the point of the undeformed gel surface seen by the camera ray through the
    point (offset_y, offset_z) from the gel's centre in the apex plane; (0, 0) gives the apex."""
    apex_distance = GEL_CENTER[0] - CAMERA_POSITION[0]
    ray = np.array([1.0, offset_y / apex_distance, offset_z / apex_distance])
    points, _ = gel_surface(ray[None])
    return points[0]


def sensor_pose_touching_off_axis(
    point: np.ndarray, normal: np.ndarray, roll: float, depth: float, tilt_axis_angle: float, tilt: float,
    gel_offset: np.ndarray,
) -> np.ndarray:
    """A sensor pose (4, 4) ``T_surfaceframe_sensor`` whose gel touches ``point`` (3,) off its centre and
    tilted.

    The sensor's +x axis is ``-normal`` turned by ``tilt`` (rad) about the axis perpendicular to the
    normal at angle ``tilt_axis_angle`` (rad) in the normal's ``geometry.orthonormal_frame``; ``roll``
    then turns the sensor about its own +x axis. The gel point ``gel_point(*gel_offset)`` (gel_offset
    (2,) m in y, z) is pushed ``depth`` (m) toward the camera, along the sensor's -x, onto ``point``: the
    object presses into the gel there by ``depth``. With tilt 0 and offset 0 this is
    ``sensor.sensor_poses_touching`` (the landmark is not used here, so the contact sits at the apex).
    """
    normal = np.asarray(normal, dtype=np.float64)
    normal = normal / np.linalg.norm(normal)
    frame = orthonormal_frame(-normal)
    axis = frame[:, 1] * np.cos(tilt_axis_angle) + frame[:, 2] * np.sin(tilt_axis_angle)
    R = rotvec_to_rotmat(tilt * axis) @ frame @ rotvec_to_rotmat(roll * np.array([1.0, 0.0, 0.0]))
    touching = gel_point(*gel_offset) - np.array([depth, 0.0, 0.0])
    return make_pose(R, np.asarray(point, dtype=np.float64) - R @ touching)


class PlacementError(RuntimeError):
    """No draw of ``spec.max_tries`` placed all of a scene's sensors (``draw_validation_scene``): the ones
    placed first left no room for the rest. ``generate_validation`` draws the scene again."""


def draw_validation_scene(
    mesh: trimesh.Trimesh,
    surface: surface_sampling.SurfaceSamples,
    candidates: np.ndarray,
    candidate_normals: np.ndarray,
    candidate_types: np.ndarray,
    spec: ValidationSpec,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One object's sensors for one scene, in the object frame.

    Each sensor takes a contact type drawn uniformly among the types the object has (so flat, edge,
    corner and curved contacts are mixed as far as the shape allows), then a random candidate point of
    that type, a random roll and a random press depth; a draw is rejected when the sensor's body
    would penetrate the object or overlap another sensor's body. PlacementError when ``spec.max_tries``
    draws do not place all L.
    Returns T_object_sensors (L, 4, 4), candidate indices (L,), depths (L,).
    """
    available = np.unique(candidate_types)
    chosen_T, chosen_idx, chosen_depth = [], [], []
    for _ in range(spec.max_tries):
        if len(chosen_T) == spec.n_sensors:
            break
        kind = rng.choice(available)
        pool = np.flatnonzero(candidate_types == kind)
        j = int(rng.choice(pool))
        if j in chosen_idx:
            continue
        depth = rng.uniform(*spec.depth_range)
        roll = rng.uniform(-np.pi, np.pi)
        if spec.off_axis:
            tilt_axis_angle, tilt = rng.uniform(-np.pi, np.pi), rng.uniform(0.0, spec.tilt_max)
            offset = rng.uniform(-spec.gel_offset_max, spec.gel_offset_max, 2)
            T = sensor_pose_touching_off_axis(candidates[j], candidate_normals[j], roll, depth, tilt_axis_angle,
                                              tilt, offset)
        else:
            T = sensor_poses_touching(candidates[j], candidate_normals[j], roll, depth)
        if body_penetrates(surface, T) or any(bodies_overlap(T, other) for other in chosen_T):
            continue
        chosen_T.append(T)
        chosen_idx.append(j)
        chosen_depth.append(depth)
    if len(chosen_T) < spec.n_sensors:
        raise PlacementError(f"could not place {spec.n_sensors} sensors without collisions in {spec.max_tries} tries")
    return np.stack(chosen_T), np.asarray(chosen_idx), np.asarray(chosen_depth)


def validation_candidates(
    mesh: trimesh.Trimesh,
    surface: surface_sampling.SurfaceSamples,
    database_points: np.ndarray,
    spec: ValidationSpec,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random surface points (not database points), their outward normals and contact types."""
    from scipy.spatial import cKDTree

    from tactile6d.sim.surface_sampling import sample_surface_random

    points, faces = sample_surface_random(mesh, spec.candidates_per_object, rng)
    normals = np.asarray(mesh.face_normals[faces])
    far, _ = cKDTree(database_points).query(points)
    keep = far > spec.min_database_distance
    points, normals = points[keep], normals[keep]
    return points, normals, contact_types.classify_contacts(surface, points, normals)


def generate_validation(
    object_names: list[str],
    meshes_by_name: dict[str, trimesh.Trimesh],
    surfaces: dict[str, surface_sampling.SurfaceSamples],
    database_points: dict[str, np.ndarray],
    render: Callable[[str, np.ndarray, np.ndarray, int], np.ndarray],
    spec: ValidationSpec,
    seed: int,
    progress: Callable | None = None,
) -> SceneSet:
    """Generated scenes: for each object, ``scenes_per_object`` uniformly random object rotations (and
    translations within +-``translation_range`` of (0.1, 0, 0.2) m), L sensors from
    ``draw_validation_scene``; images from ``render(object, T_world_object, T_world_sensors, seed)``.

    A draw whose sensors cannot all be placed (PlacementError) or whose images cannot be rendered
    (``render`` raises InputError: a tilted gel pressed deeper than the gel allows, or the object inside
    a sensor body) is drawn again, at most ``spec.max_tries`` times per scene; a set that never needs it
    has the random stream of single draws.
    """
    rng = np.random.default_rng(seed)
    rows = []
    for obj in object_names:
        mesh, surface = meshes_by_name[obj], surfaces[obj]
        cand, cand_n, cand_t = validation_candidates(mesh, surface, database_points[obj], spec, rng)
        for k in range(spec.scenes_per_object):
            T_world_object = make_pose(random_rotations(1, rng)[0],
                                       CADDEO2023_T_WORLD_OBJECT[:3, 3] + rng.uniform(-1, 1, 3) * spec.translation_range)
            for _ in range(spec.max_tries):
                try:
                    T_object_sensors, idx, _ = draw_validation_scene(mesh, surface, cand, cand_n, cand_t, spec, rng)
                except PlacementError:
                    continue
                T_world_sensors = T_world_object @ T_object_sensors
                try:
                    images = render(obj, T_world_object, T_world_sensors, int(rng.integers(2**31)))
                    break
                except InputError:
                    continue
            else:
                raise RuntimeError(f"{obj}: no placeable, renderable scene in {spec.max_tries} draws")
            rows.append((f"{obj}/scene_{k}", obj, T_world_object, T_world_sensors, images,
                         transform_points(T_world_object, cand[idx]), cand_n[idx] @ T_world_object[:3, :3].T,
                         cand_t[idx]))
            if progress is not None:
                progress()
    columns = list(zip(*rows))
    return SceneSet(*(np.asarray(c) if i < 2 else np.stack(c) for i, c in enumerate(columns)))


def scene_backgrounds(scenes: Mapping[str, np.ndarray], s: int) -> np.ndarray | None:
    """Scene s's sensors' own no-contact images (L, 320, 240, 3) from a ``scenes`` artifact (``hdf5.Artifact``)
    or mapping, or None when the set has none (``scenes.SceneSet.backgrounds``)."""
    return np.asarray(scenes["backgrounds"][s]) if "backgrounds" in scenes else None
