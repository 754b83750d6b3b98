"""Where to touch to tell an ambiguous estimate's poses apart.

An estimate is ambiguous when poses far apart explain the contacts about equally well (``Estimate.distinct``): a
box touched on its large faces, a pitcher touched on its body. The images and sensor poses in hand cannot settle
it; one more touch where the poses' surfaces differ can. ``touch_to_tell_apart`` picks that touch on the best
pose's surface: a point that every rival pose leaves at least ``enough`` away from its own surface (beyond it the
touch says no more), where the surface is flat over a gel's footprint (a press there reads well; the points
farthest from the rivals are the object's extremes, corners and spouts, where a press reads worst), and where a
sensor pressing it keeps clear of the object (as the best pose places it) and of the sensors already touching;
where no such point is far enough from the rivals, the flattest reachable one.

The hand then moves a sensor along the touch's approach line until it meets the object (a guarded move: where the
best pose is right it meets it at the touch point, elsewhere earlier or later, or not at all), and ``choose``
re-scores the poses with that sensor's image and pose beside the others: refined against every contact and
ranked as the single-shot ranking re-scores its candidates.

Units: metres; poses 4x4 ``T_world_*``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import transform_points
from tactile6d.core.sensor import bodies_overlap, sensor_poses_touching
from tactile6d.estimation import rank as rank_step
from tactile6d.sim.scenes import body_penetrates
from tactile6d.sim.surface_sampling import SurfaceSamples

if TYPE_CHECKING:
    from tactile6d.estimation.estimator import Estimator


class Touch(NamedTuple):
    """A touch to tell poses apart: ``point`` (3,) world, where the sensor meets the surface if the best pose is
    right; ``normal`` (3,) world, the outward surface normal there (approach along ``-normal``);
    ``T_world_sensor`` (4, 4) the sensor pressing there as the best pose places the object; ``separation`` m, how
    far the nearest rival's surface lies from ``point``; ``tells_apart``: whether that is at least
    ``touch_to_tell_apart``'s ``least`` (False for its fallback, the flattest reachable spot: a touch that pins
    the pose better without telling the poses apart)."""

    point: np.ndarray
    normal: np.ndarray
    T_world_sensor: np.ndarray
    separation: float
    tells_apart: bool


def separation_from_rivals(points: np.ndarray, surface: SurfaceSamples, rivals: np.ndarray) -> np.ndarray:
    """For points (N, 3) in the world, the distance (N,) m to the nearest of the rival poses' (R, 4, 4) surfaces
    (``surface``'s samples placed by each), the smallest over the rivals; inf with no rival."""
    separation = np.full(len(points), np.inf)
    for T in rivals:
        distance, _ = cKDTree(transform_points(T, surface.points)).query(points)
        separation = np.minimum(separation, distance)
    return separation


def flatness(surface: SurfaceSamples, indices: np.ndarray, radius: float) -> np.ndarray:
    """For the samples ``indices`` (N,) of ``surface``, the least cosine (N,) between each one's normal and the
    normals of the samples within ``radius`` of it (1 on a plane; smaller where the surface bends or breaks)."""
    neighbours = surface.tree.query_ball_point(surface.points[indices], radius)
    return np.array([float(np.min(surface.normals[near] @ surface.normals[i])) for i, near in zip(indices, neighbours)])


def touch_to_tell_apart(
    surface: SurfaceSamples,
    poses: np.ndarray,
    T_world_sensors: np.ndarray,
    enough: float = 0.01,
    least: float = 0.003,
    flat_radius: float = 0.006,
    flat_deg: float = 15.0,
    clearance: float = 0.003,
    press: float = 0.0018,
    max_points: int = 4000,
    seed: int = 0,
) -> Touch | None:
    """The touch on the best pose's surface that tells it from its rivals (module docstring).

    surface: the object's surface samples (object frame); poses (K, 4, 4) ``T_world_object``, the best first
    (e.g. ``estimate.poses[estimate.distinct]``), K >= 2; T_world_sensors (L, 4, 4) the sensors already touching.
    Of ``max_points`` surface samples (drawn with ``seed``) whose normals turn by less than ``flat_deg`` within
    ``flat_radius`` and where a sensor pressed ``press`` deep keeps its body off the object and ``clearance``
    away from every sensor's body, the one whose separation from the rivals, counted up to ``enough``, is
    largest, the flattest of those that tie. When none lies ``least`` or more from every rival, the flattest
    of them (its ``separation`` then under ``least``): one more contact still pins the pose better, and on the
    tuning sets such touches helped (docs/confidence.md). None when no sample qualifies at all.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or len(poses) < 2:
        raise ValueError(f"touch_to_tell_apart needs the best pose and at least one rival, got poses of shape "
                         f"{poses.shape}")
    rng = np.random.default_rng(seed)
    candidates = rng.choice(len(surface.points), size=min(max_points, len(surface.points)), replace=False)
    best = poses[0]
    world = transform_points(best, surface.points[candidates])
    separation = separation_from_rivals(world, surface, poses[1:])
    flat = flatness(surface, candidates, flat_radius)
    is_flat = flat >= np.cos(np.radians(flat_deg))
    # Most separation first (beyond `enough` a touch tells no more), then the flattest; else the flattest.
    telling = np.lexsort((-flat, -np.minimum(separation, enough)))
    telling = telling[is_flat[telling] & (separation[telling] >= least)]
    flattest = np.argsort(-flat, kind="stable")
    flattest = flattest[is_flat[flattest]]
    T_object_sensors = sensor_poses_touching(surface.points[candidates], surface.normals[candidates], 0.0, press)
    for k in np.concatenate([telling, flattest]):
        if body_penetrates(surface, T_object_sensors[k]):
            continue
        T_world_sensor = best @ T_object_sensors[k]
        if any(bodies_overlap(T_world_sensor, T, -clearance) for T in np.asarray(T_world_sensors)):
            continue
        return Touch(world[k], best[:3, :3] @ surface.normals[candidates[k]], T_world_sensor, float(separation[k]),
                     bool(separation[k] >= least))
    return None


def touch_as_met(mesh, T_world_object: np.ndarray, touch: Touch, reach: float = 0.03,
                 press: float = 0.0018) -> tuple[np.ndarray, bool]:
    """Where a guarded move along ``touch``'s approach line meets an object (a simulation of the hand, for
    tests and studies): mesh (object frame, trimesh) at T_world_object (4, 4). The sensor starts ``reach`` out
    along the normal and moves in along ``-normal`` until it meets the surface, at most ``2 reach`` on (past
    the touch point as far as it started before it; the start is taken to be outside the object), then presses
    ``press``. -> (T_world_sensor (4, 4), met): pressing where it met the object, or where the touch placed it
    (``touch.T_world_sensor``) when it met none.
    """
    start = touch.point + reach * touch.normal
    local_start = transform_points(np.linalg.inv(T_world_object), start[None])[0]
    local_direction = np.asarray(T_world_object)[:3, :3].T @ -touch.normal
    hits, _, _ = mesh.ray.intersects_location([local_start], [local_direction])
    along = (hits - local_start) @ local_direction if len(hits) else np.zeros(0)
    ahead = (along >= 0) & (along <= 2 * reach)
    if not ahead.any():
        return np.asarray(touch.T_world_sensor), False
    met = start - float(np.min(along[ahead])) * touch.normal
    return sensor_poses_touching(met[None], touch.normal[None], 0.0, press)[0], True


@dataclass
class Choice:
    """Poses told apart (``choose``), best first: poses (K, 4, 4) ``T_world_object`` as refined against the
    sensors' contacts; scores (K,) m, the ranking's re-scoring; order (K,) int, each one's index among the poses
    given."""

    poses: np.ndarray
    scores: np.ndarray
    order: np.ndarray

    @property
    def best(self) -> np.ndarray:
        return self.poses[0]


def choose(estimator: Estimator, poses, T_world_sensors, images=None, backgrounds=None) -> Choice:
    """Poses already found (K, 4, 4) ``T_world_object`` told apart by the sensors at T_world_sensors (L, 4, 4) and
    their images, e.g. after one more touch (``touch_to_tell_apart``): the inputs checked and the images read as
    ``Estimator.estimate`` reads them (``Estimator.read_scene``: each brought to its no-contact image's light
    first; backgrounds as for ``estimate``), then each pose refined against every touching sensor's contact and
    patch and scored as the ranking re-scores its candidates (``rank.refine_and_score``: a pose that presses a
    sensor whose image shows none pays for it) -> ``Choice``, best first. No search: a pose not among ``poses``
    is not found. A sensor whose image shows no contact (a touch that met nothing) is expected here, and not
    warned about."""
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
        raise InputError(f"choose needs poses of shape (K, 4, 4), K >= 1, got {poses.shape}")
    T, contacts = estimator.read_scene(T_world_sensors, images, backgrounds)
    settings = estimator.settings
    scored = rank_step.refine_and_score(estimator.penetration_model, estimator.surface, estimator.mesh, poses, T,
                                        contacts, settings.rank, settings.sensors, int(settings.rank.refine_iterations))
    order = np.argsort(scored.scores, kind="stable")
    return Choice(scored.poses[order], scored.scores[order], order)

