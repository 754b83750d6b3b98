"""Generated tracking sequences: an object held in a grasp of L DIGIT sensors that rolls and slides, rendered
frame by frame, with the sensor poses a real hand would report (issue 37).

A sequence is F frames at ``fps`` (t = 0 .. F-1). A *profile* is a smooth random curve u(t) in [-1, 1] with
u(0) = 0 (``smooth_profile``): a blend of the ramp (1 - cos(pi t / (F-1))) / 2 and a sine of 0.5 to 1.5
cycles over the sequence, with a random sign; it changes by at most 1.5 pi / (F-1) per frame (0.05 at 90
frames). Each quantity below has its own profile and an amplitude uniform in [1/2, 1] of its maximum.

Motion model (all of it in the object frame but the hand):

- **Frame 0** is drawn like a validation scene (``scenes.validation_candidates``, then
  ``scenes.draw_validation_scene`` with the spec's sensors, depths and candidates): each sensor i touches a
  surface point p_i0 with its gel apex along the normal, at a random roll, pressed d_i0 deep, no body
  penetrating the object or another body. (Frame 0's sensors are then placed as every frame's are, below:
  along the averaged normal, which turns them from the validation pose by a few degrees.)
- **Slide** (the contact moves over the object): p_i(t) is the surface point closest to
  ``p_i0 + slide_i u(t) e_i``, e_i a random tangent at p_i0, slide_i up to ``slide_max``. Its normal n_i(t)
  is the outward surface normal there, averaged over the surface within ``normal_radius`` (the objects
  are scans whose faces tilt by several degrees against their neighbours, so a face's own normal would
  jerk the sensor at every face crossed; ``normal_radius`` 0 takes the face's own).
- **Sensor on its contact**: ``scenes.sensor_pose_touching_off_axis(p_i(t), n_i(t), roll_i(t), depth_i(t),
  tilt_axis_i(t), tilt_i(t), gel_offset_i(t))``. The sensor's y axis at frame 0 is carried from frame to
  frame over the turning normal (parallel transport), so the sensor turns only as the surface does;
  roll_i(t) adds a **twist** of up to ``twist_max_deg`` about the normal. The **tilt** of the sensor's
  axis from the normal is up to ``tilt_max_deg`` about a tangent axis fixed in that transported frame.
  **Rolling**: the gel point that touches moves from the apex by up to ``gel_travel_max`` along a random
  direction on the gel (``gel_offset_i(t)``, m in the sensor's y and z). The **depth** oscillates between
  d_i0 and another depth of ``depth_range`` (raised cosine of 0.5 to 1.5 cycles).
- **Lift-off**: with ``lift_probability`` one random sensor leaves the surface once: for ``lift_seconds``
  from a random frame in the middle half of the sequence its depth is ``-lift_distance`` (its gel that
  far from the surface along its axis: an image without contact), ramped from and back to its profile
  over ``LIFT_RAMP_FRAMES`` frame intervals. A sensor touches (``touching``) where the object presses into
  its gel somewhere, as the renderer's geometry sees it (``sim.gel_press``, on the default ray grid of
  ``TOUCH_STEP`` pixels): wherever its depth is >= ``SURE_TOUCH_DEPTH``, and wherever else the rays say so
  (on a ramp the apex may still press while the off-centre touching point has left).
- **Hand**: the whole grasp moves in the world, ``T_world_object(t) = hand(t) @ T_world_object(0)``;
  hand(t) turns about a random axis through the object's position by up to ``hand_rotation_max_deg`` and
  moves it by up to ``hand_translation_max`` (three profiles, one per world axis, the vector clipped to
  unit length). T_world_object(0) is drawn as in the validation scenes: a uniformly random rotation, the
  position uniform within +-``translation_range`` of (0.1, 0, 0.2) m. True sensor poses:
  ``T_world_sensors_true(t) = T_world_object(t) @ T_object_sensors(t)``.
- **Validity**: every frame of a sequence must be one a real grasp can show: no contact jumps more than
  ``max_contact_step`` nor its normal turns more than ``max_normal_turn_deg`` between frames (a slide
  across an edge, or onto another part of the surface), no sensor body penetrates the object
  (``scenes.body_penetrates``; a drawn tilt that would make it is scaled down first, ``sensor_track``), no
  two bodies overlap (``core.sensor.bodies_overlap``), a fully lifted gel touches nowhere and the render
  callable raises no InputError. A sensor whose own frames are not all valid draws its motion again (up to
  ``SENSOR_TRIES`` times, ``draw_track``); otherwise the whole sequence is drawn again, ``max_tries`` times
  at most. On a flat face the tilt is mostly scaled away: a DIGIT's body box ends 2.4 mm behind the gel
  apex, so a tilt of more than a degree or two drives its edge into the surface.
- **Reported poses** carry a hand's forward-kinematics error: ``T_world_sensors(t) =
  T_world_sensors_true(t) @ bias_i @ jitter_i(t)``, each error a rotation by a Gaussian rotation vector
  (``pose_sigma_deg``, ``jitter_deg`` per axis) and a Gaussian translation (``pose_sigma_mm``,
  ``jitter_mm`` per axis) in the sensor's frame, as ``perturb.perturb_sensor_poses`` draws them; the bias
  is drawn once per sensor and sequence, the jitter every frame. The images are those of the true poses.

Arrays of a ``SequenceSet`` (Q sequences, F frames, L sensors), world frame unless said otherwise:
``names`` (Q,) str, ``objects`` (Q,) str, ``fps`` float, ``T_world_object`` (Q, F, 4, 4),
``T_world_sensors`` (Q, F, L, 4, 4) as reported, ``T_world_sensors_true`` (Q, F, L, 4, 4), ``images``
(Q, F, L, 320, 240, 3) uint8 RGB, ``touching`` (Q, F, L) bool, ``contact_points`` (Q, F, L, 3) m and
``contact_normals`` (Q, F, L, 3) outward unit (each sensor's surface point p_i(t), also while lifted),
``depths`` (Q, F, L) m (press depth of the touching gel point along the sensor's axis; negative: the gap
of a lifted gel), ``lift_weights`` (Q, F, L) in [0, 1] (1: lifted, between 0 and 1: on a lift's ramp),
``pose_bias_translation`` (Q, L, 3) m and ``pose_bias_rotvec`` (Q, L, 3) rad (the bias drawn, sensor frame).

Everything is drawn from ``np.random.default_rng(seed)`` and generators spawned from it, one set per
sequence: placement and motion (with the render seeds), the world pose and hand motion, the pose errors.
So a sequence's grasp does not change with the hand's or the errors' settings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace

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
from tactile6d.core.sensor import BOX_CENTER, BOX_HALF_EXTENTS, GEL_CENTER, bodies_overlap
from tactile6d.data.hdf5 import Artifact
from tactile6d.data.schemas import SEQUENCE_FIELDS
from tactile6d.sim import surface_sampling
from tactile6d.sim.gel_press import poses_to_gel_depths
from tactile6d.sim.render import mesh_arrays
from tactile6d.sim.scenes import (
    CADDEO2023_T_WORLD_OBJECT,
    PlacementError,
    ValidationSpec,
    body_penetrates,
    draw_validation_scene,
    sensor_pose_touching_off_axis,
    validation_candidates,
)

LIFT_RAMP_FRAMES = 3  # frame intervals over which a lifting sensor leaves the surface, and comes back
SENSOR_TRIES = 10  # draws of a sensor's motion before its grasp is drawn again
TILT_SCALES = (1.0, 0.5, 0.25, 0.0)  # a drawn tilt that drives the body into the object is scaled by these in turn
TOUCH_STEP = 2  # pixels; the ray grid ``touching`` is measured on: the renderer's default render_step
SURE_TOUCH_DEPTH = 0.0005  # m; a gel point pressed this deep makes an imprint no ray grid misses
_BODY_RADIUS = float(np.linalg.norm(BOX_HALF_EXTENTS))  # the body box's circumradius, m


@dataclass(frozen=True)
class SequenceSpec:
    """How tracking sequences are drawn (config section ``sequences``; the module docstring's model).

    Lengths in m unless named ``_mm``; angles in degrees.

    n_frames, fps: frames per sequence and their rate (1/s). n_sensors: L. depth_range (m): press depths
    of the touching gel point. translation_range (m): T_world_object(0)'s position within +- this of
    (0.1, 0, 0.2). candidates_per_object, min_database_distance (m): frame 0's contacts, as in
    ``scenes.ValidationSpec``. slide_max: how far a contact slides over the object's surface.
    gel_travel_max: how far the touching gel point moves from the apex (rolling). twist_max_deg: the
    sensor's turn about the normal. tilt_max_deg: its axis' tilt from the normal. hand_translation_max,
    hand_rotation_max_deg: the grasp's motion in the world. lift_probability: the chance that one sensor
    of a sequence lifts off once, for lift_seconds (s), lift_distance away. pose_sigma_mm,
    pose_sigma_deg: each sensor's kinematic bias per axis (sensor frame; Gaussian), constant over a
    sequence. jitter_mm, jitter_deg: the per-frame error on top. normal_radius: the contact normal is the
    surface's averaged within this (0: the face's). max_normal_turn_deg, max_contact_step: the largest
    turn of a contact normal and the largest step of a contact point between frames. max_tries: draws of
    a sequence before giving up.
    """

    n_frames: int = 90
    fps: float = 30.0
    n_sensors: int = 3
    depth_range: tuple[float, float] = (0.0012, 0.0020)
    translation_range: float = 0.05
    candidates_per_object: int = 600
    min_database_distance: float = 0.0005
    slide_max: float = 0.004
    gel_travel_max: float = 0.003
    twist_max_deg: float = 15.0
    tilt_max_deg: float = 8.0
    hand_translation_max: float = 0.02
    hand_rotation_max_deg: float = 20.0
    lift_probability: float = 0.5
    lift_seconds: float = 0.3
    lift_distance: float = 0.003
    pose_sigma_mm: float = 1.5
    pose_sigma_deg: float = 1.5
    jitter_mm: float = 0.1
    jitter_deg: float = 0.1
    normal_radius: float = 0.002
    max_normal_turn_deg: float = 20.0
    max_contact_step: float = 0.001
    max_tries: int = 50

    def placement(self) -> ValidationSpec:
        """The validation spec frame 0 is drawn with (apex contacts along the normal)."""
        return ValidationSpec(scenes_per_object=1, n_sensors=self.n_sensors,
                              candidates_per_object=self.candidates_per_object, depth_range=tuple(self.depth_range),
                              translation_range=self.translation_range,
                              min_database_distance=self.min_database_distance)

    @property
    def lift_frames(self) -> int:
        """Frames a lifted sensor stays fully off the surface (at least 1)."""
        return max(1, int(round(self.lift_seconds * self.fps)))


@dataclass
class SequenceSet:
    """Sequences of one set, all with the same F and L (arrays as in the module docstring)."""

    names: np.ndarray
    objects: np.ndarray
    fps: float
    T_world_object: np.ndarray
    T_world_sensors: np.ndarray
    T_world_sensors_true: np.ndarray
    images: np.ndarray
    touching: np.ndarray
    contact_points: np.ndarray
    contact_normals: np.ndarray
    depths: np.ndarray
    lift_weights: np.ndarray
    pose_bias_translation: np.ndarray
    pose_bias_rotvec: np.ndarray

    def __len__(self) -> int:
        return len(self.names)

    def as_datasets(self) -> dict[str, np.ndarray]:
        """The arrays by ``schemas.SEQUENCE_FIELDS`` name, for ``hdf5.write_artifact(..., "sequences", ...)``."""
        return {k: np.float64(self.fps) if k == "fps" else getattr(self, k) for k in SEQUENCE_FIELDS}


def sequence_set_from_artifact(art: Artifact) -> SequenceSet:
    """A SequenceSet from a ``sequences`` artifact (``hdf5.read_artifact(path, "sequences")``)."""
    return SequenceSet(**{k: float(art[k]) if k == "fps" else np.asarray(art[k]) for k in SEQUENCE_FIELDS})


@dataclass(frozen=True)
class SensorMotion:
    """One sensor's drawn motion over F frames (object frame; the module docstring's model).

    point0 (3,) m, its surface point at frame 0; y_axis0 (3,) its y axis at frame 0; slide_direction (3,)
    unit tangent; slide (F,) m along it; depths (F,) m; twist (F,) rad; tilt_axis_angle rad, in the
    transported tangent frame; tilt (F,) rad; gel_offsets (F, 2) m in the sensor's y and z.
    """

    point0: np.ndarray
    y_axis0: np.ndarray
    slide_direction: np.ndarray
    slide: np.ndarray
    depths: np.ndarray
    twist: np.ndarray
    tilt_axis_angle: float
    tilt: np.ndarray
    gel_offsets: np.ndarray


@dataclass(frozen=True)
class Track:
    """A grasp's sensors over F frames, object frame: T_object_sensors (F, L, 4, 4), points (F, L, 3) m and
    outward normals (F, L, 3) of the contacts, depths (F, L) m (negative: lifted), lift weights (F, L),
    touching (F, L) bool. One sensor's track has the same arrays without the L axis."""

    T_object_sensors: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    depths: np.ndarray
    lift_weights: np.ndarray
    touching: np.ndarray


class TrackError(RuntimeError):
    """A drawn track has a frame no real grasp shows (``track_violation``); the sequence is drawn again."""


# --- profiles -------------------------------------------------------------------------------------


def smooth_profile(n_frames: int, rng: np.random.Generator) -> np.ndarray:
    """(F,) in [-1, 1], 0 at frame 0: ``w ramp + (1 - w) wave`` with a random sign, the ramp
    (1 - cos(pi tau)) / 2 and the wave (sin(2 pi f tau + phase) - sin(phase)) / 2, tau = t / (F-1), w uniform
    in [0, 1], f uniform in [0.5, 1.5] cycles; steps at most 1.5 pi / (F-1) per frame."""
    tau = np.arange(n_frames) / max(n_frames - 1, 1)
    w, f, phase = rng.uniform(), rng.uniform(0.5, 1.5), rng.uniform(-np.pi, np.pi)
    sign = rng.choice([-1.0, 1.0])
    ramp = 0.5 * (1.0 - np.cos(np.pi * tau))
    wave = 0.5 * (np.sin(2 * np.pi * f * tau + phase) - np.sin(phase))
    return sign * (w * ramp + (1.0 - w) * wave)


def amplitude(maximum: float, rng: np.random.Generator) -> float:
    """A motion's amplitude: uniform in [maximum / 2, maximum]."""
    return float(rng.uniform(0.5, 1.0) * maximum)


def depth_profile(depth0: float, depth_range: tuple[float, float], n_frames: int,
                  rng: np.random.Generator) -> np.ndarray:
    """(F,) m: from ``depth0`` to another depth of ``depth_range`` and back, as a raised cosine of 0.5 to 1.5
    cycles over the sequence; stays within the range when depth0 does."""
    tau = np.arange(n_frames) / max(n_frames - 1, 1)
    other, f = rng.uniform(*depth_range), rng.uniform(0.5, 1.5)
    return depth0 + (other - depth0) * 0.5 * (1.0 - np.cos(2 * np.pi * f * tau))


def lift_weights(n_frames: int, start: int, length: int, ramp: int = LIFT_RAMP_FRAMES) -> np.ndarray:
    """(F,) in [0, 1]: 1 on frames ``start .. start + length - 1`` (lifted), rising linearly over the
    ``ramp`` frame intervals before and falling over those after, 0 elsewhere."""
    t = np.arange(n_frames)
    return np.clip(np.minimum(t - (start - ramp), start + length - 1 + ramp - t) / ramp, 0.0, 1.0)


def lift_start_range(n_frames: int, length: int, ramp: int = LIFT_RAMP_FRAMES) -> tuple[int, int]:
    """Inclusive range of a lift's first fully lifted frame: in the middle half of the sequence, with its
    ramps inside it where the sequence is long enough."""
    lo = max(ramp, int(np.ceil(n_frames / 4)))
    hi = min(n_frames - length - ramp, int(np.floor(3 * n_frames / 4)) - length)
    return lo, max(lo, hi)


# --- the contact on the object, and the sensor on it ------------------------------------------------


def surface_normals(mesh: trimesh.Trimesh, surface: surface_sampling.SurfaceSamples, points: np.ndarray,
                    faces: np.ndarray, radius: float) -> np.ndarray:
    """Outward unit normals (n, 3) at points (n, 3) on the mesh's ``faces`` (n,): the mean of the surface
    samples' normals within ``radius`` (m) that face the same side as the face (a thin wall's other side
    does not count), weighted by that agreement; the face's own normal where there is none, or radius 0."""
    own = np.asarray(mesh.face_normals[faces], dtype=np.float64)
    if radius <= 0:
        return own
    out = own.copy()
    for k, near in enumerate(surface.tree.query_ball_point(points, radius)):
        if near:
            n = surface.normals[near]
            mean = (np.clip(n @ own[k], 0.0, None)[:, None] * n).sum(axis=0)
            length = np.linalg.norm(mean)
            if length > 1e-9:
                out[k] = mean / length
    return out


def contact_track(mesh: trimesh.Trimesh, surface: surface_sampling.SurfaceSamples, point0: np.ndarray,
                  direction: np.ndarray, slide: np.ndarray, normal_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """A contact sliding over the surface: the surface points closest to ``point0 + slide[t] direction``
    -> points (F, 3) m and outward normals (F, 3) (``surface_normals``), object frame."""
    targets = np.asarray(point0)[None] + np.asarray(slide)[:, None] * np.asarray(direction)[None]
    points, _, faces = trimesh.proximity.closest_point(mesh, targets)
    return np.asarray(points, dtype=np.float64), surface_normals(mesh, surface, points, faces, normal_radius)


def transported_axes(normals: np.ndarray, y_axis0: np.ndarray) -> np.ndarray:
    """A tangent axis carried along the normals (F, 3): (F, 3) unit, each the previous frame's projected
    onto the tangent plane of this one (parallel transport); the first is ``y_axis0`` projected."""
    out = np.empty_like(normals)
    y = np.asarray(y_axis0, dtype=np.float64)
    for t, n in enumerate(normals):
        y = y - (y @ n) * n
        y = y / np.linalg.norm(y)
        out[t] = y
    return out


def sensor_poses_along(points: np.ndarray, normals: np.ndarray, motion: SensorMotion, depths: np.ndarray) -> np.ndarray:
    """T_object_sensor (F, 4, 4) of one sensor touching ``points`` (F, 3) with outward ``normals`` (F, 3) at
    ``depths`` (F,) m, its roll, tilt and gel offset from ``motion`` (``sensor_pose_touching_off_axis``).

    The roll and the tilt axis are angles from the transported y axis (``transported_axes``), so the
    sensor turns about the normal only by ``motion.twist``."""
    references = transported_axes(normals, motion.y_axis0)
    out = np.empty((len(points), 4, 4))
    for t, (p, n, y) in enumerate(zip(points, normals, references)):
        frame = orthonormal_frame(-n)
        phi = np.arctan2(y @ frame[:, 2], y @ frame[:, 1])  # the reference's angle about -n from the frame's y
        out[t] = sensor_pose_touching_off_axis(p, n, phi + motion.twist[t], depths[t], phi + motion.tilt_axis_angle,
                                               motion.tilt[t], motion.gel_offsets[t])
    return out


def draw_sensor_motion(point0: np.ndarray, normal0: np.ndarray, y_axis0: np.ndarray, depth0: float,
                       spec: SequenceSpec, rng: np.random.Generator) -> SensorMotion:
    """One sensor's motion from its frame-0 contact (point0 (3,), outward normal0 (3,)), its y axis and
    depth (m) there: a random slide direction, the profiles and their amplitudes (module docstring)."""
    F = spec.n_frames
    e1, e2 = orthonormal_frame(np.asarray(normal0))[:, 1:].T
    a = rng.uniform(-np.pi, np.pi)
    direction = np.cos(a) * e1 + np.sin(a) * e2
    slide = amplitude(spec.slide_max, rng) * smooth_profile(F, rng)
    depths = depth_profile(depth0, spec.depth_range, F, rng)
    twist = np.radians(amplitude(spec.twist_max_deg, rng)) * smooth_profile(F, rng)
    tilt_axis_angle = float(rng.uniform(-np.pi, np.pi))
    tilt = np.radians(amplitude(spec.tilt_max_deg, rng)) * smooth_profile(F, rng)
    g = rng.uniform(-np.pi, np.pi)
    gel = amplitude(spec.gel_travel_max, rng) * smooth_profile(F, rng)
    gel_offsets = gel[:, None] * np.array([np.cos(g), np.sin(g)])
    return SensorMotion(np.asarray(point0, dtype=np.float64), np.asarray(y_axis0, dtype=np.float64), direction, slide,
                        depths, twist, tilt_axis_angle, tilt, gel_offsets)


def draw_lift(spec: SequenceSpec, rng: np.random.Generator) -> tuple[int, np.ndarray] | None:
    """Whether a sensor lifts off: None, or (its index, lift weights (F,) of ``lift_weights``). Draws the
    same random numbers either way."""
    lifts = rng.random() < spec.lift_probability
    sensor = int(rng.integers(spec.n_sensors))
    lo, hi = lift_start_range(spec.n_frames, spec.lift_frames)
    start = int(rng.integers(lo, hi + 1))
    return (sensor, lift_weights(spec.n_frames, start, spec.lift_frames)) if lifts else None


def lifted_depths(depths: np.ndarray, weights: np.ndarray, lift_distance: float) -> np.ndarray:
    """A depth profile (F,) m with a lift: ``(1 - w) depth - w lift_distance``, w the lift weights (F,)."""
    return (1.0 - weights) * depths - weights * lift_distance


# --- validity -----------------------------------------------------------------------------------------


def _near(surface: surface_sampling.SurfaceSamples, centre: np.ndarray,
          radius: float) -> surface_sampling.SurfaceSamples:
    """The surface samples within ``radius`` of ``centre`` (object frame), as SurfaceSamples of the same mesh:
    what ``scenes.body_penetrates`` needs of a body there, much faster than all samples."""
    keep = surface.tree.query_ball_point(centre, radius)
    return surface_sampling.SurfaceSamples(surface.mesh, surface.points[keep], surface.normals[keep], surface.tree)


def penetrates(surface: surface_sampling.SurfaceSamples, T_object_sensor: np.ndarray) -> bool:
    """``scenes.body_penetrates`` of a sensor at T_object_sensor (4, 4) on the surface samples near its body."""
    centre = transform_points(T_object_sensor, BOX_CENTER[None])[0]
    return body_penetrates(_near(surface, centre, _BODY_RADIUS), T_object_sensor)


def touching(mesh: trimesh.Trimesh, T_object_sensors: np.ndarray, depths: np.ndarray) -> np.ndarray:
    """Whether the object (its mesh, object frame) presses into each sensor's gel: sensors at
    T_object_sensors (..., 4, 4) whose touching gel point is pressed ``depths`` (...) m -> (...) bool. True
    where the depth is >= ``SURE_TOUCH_DEPTH``; elsewhere the renderer's rays decide (``gel_press``, grid
    ``TOUCH_STEP``)."""
    out = np.asarray(depths) >= SURE_TOUCH_DEPTH
    unsure = np.flatnonzero(~out.ravel())
    if unsure.size:
        poses = np.asarray(T_object_sensors).reshape(-1, 4, 4)[unsure]
        pressed = poses_to_gel_depths(mesh_arrays(mesh), np.eye(4), poses, TOUCH_STEP)[0]  # (n, h, w)
        out.ravel()[unsure] = pressed.reshape(len(unsure), -1).max(axis=1) > 0
    return out


def motion_violation(surface: surface_sampling.SurfaceSamples, track: Track, spec: SequenceSpec) -> str | None:
    """Why the sensors' motions of a track (one sensor's, arrays (F, ...), or a grasp's, (F, L, ...)) are no
    real grasp's, each sensor on its own (module docstring, Validity: contact steps, normal turns, body
    penetration, a lifted sensor that still touches), or None when every frame is valid."""
    steps = np.linalg.norm(np.diff(track.points, axis=0), axis=-1)
    if steps.size and steps.max() > spec.max_contact_step:
        return f"a contact jumps {1e3 * steps.max():.1f} mm between frames"
    cosines = np.sum(track.normals[1:] * track.normals[:-1], axis=-1)
    if cosines.size and cosines.min() < np.cos(np.radians(spec.max_normal_turn_deg)):
        return "a contact normal turns too fast (an edge crossed)"
    still = np.argwhere((track.lift_weights >= 1.0) & track.touching)
    if len(still):
        return f"a lifted sensor still touches at frame {still[0][0]}"
    poses = track.T_object_sensors.reshape(-1, 4, 4)
    bad = next((k for k, T in enumerate(poses) if penetrates(surface, T)), None)
    if bad is not None:
        return f"a sensor penetrates the object at frame {bad * len(track.T_object_sensors) // len(poses)}"
    return None


def overlap_violation(track: Track) -> str | None:
    """Where two sensors' bodies of a grasp's track (arrays (F, L, ...)) overlap, or None."""
    T = track.T_object_sensors
    for t in range(T.shape[0]):
        for i in range(T.shape[1]):
            if any(bodies_overlap(T[t, i], T[t, j]) for j in range(i)):
                return f"sensor {i} overlaps another at frame {t}"
    return None


def track_violation(surface: surface_sampling.SurfaceSamples, track: Track, spec: SequenceSpec) -> str | None:
    """Why a grasp's track (arrays (F, L, ...)) is no real grasp's (module docstring, Validity, but the
    renderer's), or None when every frame is valid."""
    return motion_violation(surface, track, spec) or overlap_violation(track)


# --- a sequence -----------------------------------------------------------------------------------------


def draw_track(mesh: trimesh.Trimesh, surface: surface_sampling.SurfaceSamples, candidates: np.ndarray,
               candidate_normals: np.ndarray, candidate_types: np.ndarray, spec: SequenceSpec,
               rng: np.random.Generator) -> Track:
    """One grasp's sensors over the sequence, object frame (mesh, and its ``surface_sampling.sample_surface``).

    Frame 0 from ``scenes.draw_validation_scene`` over the candidates (points (n, 3), outward normals (n, 3),
    contact types (n,)), then a lift, then each sensor's motion: drawn again, up to ``SENSOR_TRIES`` times,
    while the sensor's own frames are not all valid (``sensor_track``). Raises PlacementError when frame 0
    cannot be placed and TrackError when a sensor finds no valid motion or two bodies overlap.
    """
    T0, idx, depth0 = draw_validation_scene(mesh, surface, candidates, candidate_normals, candidate_types,
                                            spec.placement(), rng)
    lift = draw_lift(spec, rng)
    weights = np.zeros((spec.n_frames, spec.n_sensors))
    if lift is not None:
        weights[:, lift[0]] = lift[1]
    sensors = []
    for i, j in enumerate(idx):
        for _ in range(SENSOR_TRIES):
            motion = draw_sensor_motion(candidates[j], candidate_normals[j], T0[i, :3, 1], depth0[i], spec, rng)
            motion = replace(motion, depths=lifted_depths(motion.depths, weights[:, i], spec.lift_distance))
            one = sensor_track(mesh, surface, motion, weights[:, i], spec)
            if one is not None:
                break
        else:
            raise TrackError(f"sensor {i}: no valid motion in {SENSOR_TRIES} draws")
        sensors.append(one)
    track = Track(*(np.stack([getattr(one, f.name) for one in sensors], axis=1) for f in fields(Track)))
    reason = overlap_violation(track)
    if reason is not None:
        raise TrackError(reason)
    return track


def sensor_track(mesh: trimesh.Trimesh, surface: surface_sampling.SurfaceSamples, motion: SensorMotion,
                 lift_weights: np.ndarray, spec: SequenceSpec) -> Track | None:
    """One sensor's track (arrays (F, ...)) for its motion (whose depths carry the lift, ``lift_weights``
    (F,)), or None when some frame is invalid (``motion_violation``).

    A DIGIT's body (the box proxy) ends 2.4 mm behind the gel apex, so on a flat face a tilt of more than a
    degree or two drives the body's edge into the surface: the motion's tilt is scaled by ``TILT_SCALES``
    in turn, and the first valid track taken.
    """
    points, normals = contact_track(mesh, surface, motion.point0, motion.slide_direction, motion.slide,
                                    spec.normal_radius)
    for scale in TILT_SCALES:
        poses = sensor_poses_along(points, normals, replace(motion, tilt=scale * motion.tilt), motion.depths)
        track = Track(poses, points, normals, motion.depths, lift_weights, touching(mesh, poses, motion.depths))
        if motion_violation(surface, track, spec) is None:
            return track
    return None


def hand_motion(center: np.ndarray, spec: SequenceSpec, rng: np.random.Generator) -> np.ndarray:
    """(F, 4, 4) world motions hand(t), hand(0) = I: a turn about a random axis through ``center`` (3,)
    by up to ``hand_rotation_max_deg``, and a translation of the centre by up to ``hand_translation_max``
    (a profile per world axis, the vector clipped to unit length)."""
    F = spec.n_frames
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = np.radians(amplitude(spec.hand_rotation_max_deg, rng)) * smooth_profile(F, rng)
    way = np.stack([smooth_profile(F, rng) for _ in range(3)], axis=1)
    way /= np.maximum(1.0, np.linalg.norm(way, axis=1, keepdims=True))
    shift = amplitude(spec.hand_translation_max, rng) * way
    R = rotvec_to_rotmat(angle[:, None] * axis)
    center = np.asarray(center, dtype=np.float64)
    return make_pose(R, center + shift - R @ center)


def kinematic_errors(spec: SequenceSpec, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hand's kinematic error for one sequence: errors (F, L, 4, 4) with ``T_reported = T_true @ error``
    (bias_i @ jitter_i(t), sensor frame), and the bias drawn: translations (L, 3) m, rotation vectors (L, 3)
    rad."""
    F, L = spec.n_frames, spec.n_sensors
    bias_t = rng.normal(0.0, 1e-3 * spec.pose_sigma_mm, (L, 3))
    bias_w = rng.normal(0.0, np.radians(spec.pose_sigma_deg), (L, 3))
    jitter_t = rng.normal(0.0, 1e-3 * spec.jitter_mm, (F, L, 3))
    jitter_w = rng.normal(0.0, np.radians(spec.jitter_deg), (F, L, 3))
    bias = make_pose(rotvec_to_rotmat(bias_w), bias_t)
    return bias[None] @ make_pose(rotvec_to_rotmat(jitter_w), jitter_t), bias_t, bias_w


Render = Callable[[str, np.ndarray, np.ndarray, int], np.ndarray]


def render_frames(obj: str, T_world_object: np.ndarray, T_world_sensors: np.ndarray, seeds: np.ndarray,
                  render: Render, progress: Callable | None = None) -> np.ndarray:
    """Every frame's images (F, L, 320, 240, 3) uint8: ``render(obj, T_world_object[t] (4, 4),
    T_world_sensors[t] (L, 4, 4), seeds[t])``. ``progress(1)`` after each frame; when ``render`` raises
    (InputError), ``progress(-done)`` takes the frames back before the error passes on."""
    frames = []
    try:
        for t in range(len(T_world_object)):
            frames.append(np.asarray(render(obj, T_world_object[t], T_world_sensors[t], int(seeds[t]))))
            if progress is not None:
                progress(1)
    except BaseException:
        if progress is not None and frames:
            progress(-len(frames))
        raise
    return np.stack(frames)


def make_sequence(obj: str, mesh: trimesh.Trimesh, surface: surface_sampling.SurfaceSamples,
                  database_points: np.ndarray, render: Render, spec: SequenceSpec, rng: np.random.Generator,
                  progress: Callable | None = None) -> dict:
    """One sequence of object ``obj`` (module docstring) -> its arrays by SequenceSet field, without the
    sequence axis (names, objects and fps left out).

    mesh, surface: the object's mesh and ``surface_sampling.sample_surface`` of it; database_points (M, 3);
    render, progress: as ``generate_sequences`` takes them. RuntimeError naming the object after
    ``spec.max_tries`` invalid draws.
    """
    grasp_rng, world_rng, error_rng = rng.spawn(3)
    T_world_object0 = make_pose(random_rotations(1, world_rng)[0], CADDEO2023_T_WORLD_OBJECT[:3, 3]
                                + world_rng.uniform(-1, 1, 3) * spec.translation_range)
    T_world_object = hand_motion(T_world_object0[:3, 3], spec, world_rng) @ T_world_object0
    errors, bias_t, bias_w = kinematic_errors(spec, error_rng)
    candidates = validation_candidates(mesh, surface, database_points, spec.placement(), grasp_rng)
    for _ in range(spec.max_tries):
        try:
            track = draw_track(mesh, surface, *candidates, spec, grasp_rng)
        except (PlacementError, TrackError):
            continue
        seeds = grasp_rng.integers(2**31, size=spec.n_frames)
        T_true = T_world_object[:, None] @ track.T_object_sensors
        try:
            images = render_frames(obj, T_world_object, T_true, seeds, render, progress)
        except InputError:
            continue
        R = T_world_object[:, None, :3, :3]
        return dict(T_world_object=T_world_object, T_world_sensors=T_true @ errors, T_world_sensors_true=T_true,
                    images=images, touching=track.touching,
                    contact_points=transform_points(T_world_object[:, None], track.points[:, :, None])[:, :, 0],
                    contact_normals=(R @ track.normals[..., None])[..., 0], depths=track.depths,
                    lift_weights=track.lift_weights,
                    pose_bias_translation=bias_t, pose_bias_rotvec=bias_w)
    raise RuntimeError(f"{obj}: no valid sequence in {spec.max_tries} draws")


def generate_sequences(
    object_names: list[str],
    meshes_by_name: dict[str, trimesh.Trimesh],
    surfaces: dict[str, surface_sampling.SurfaceSamples],
    database_points: dict[str, np.ndarray],
    render: Render,
    spec: SequenceSpec,
    n_sequences: int,
    seed: int,
    progress: Callable | None = None,
) -> SequenceSet:
    """``n_sequences`` tracking sequences (module docstring): sequence q is of object ``object_names[q % n]``
    after the names are shuffled by the seed's generator, named ``<object>/sequence_<q>``.

    meshes_by_name: the objects' meshes (object frame, m); surfaces: their ``surface_sampling.sample_surface``
    (of the same meshes); database_points (M, 3): points frame 0's contacts keep away from; render(object,
    T_world_object (4, 4), T_world_sensors_true (L, 4, 4), seed int) -> (L, 320, 240, 3) uint8 RGB, raising
    InputError for a pose it cannot render; progress(n): n more frames rendered (negative when a sequence
    whose rendering failed is drawn again). Deterministic in ``seed``.
    """
    rng = np.random.default_rng(seed)
    order = [str(o) for o in rng.permutation(np.asarray(object_names))]
    children = rng.spawn(n_sequences)
    rows, names, objects = [], [], []
    for q in range(n_sequences):
        obj = order[q % len(order)]
        rows.append(make_sequence(obj, meshes_by_name[obj], surfaces[obj], database_points[obj], render, spec,
                                  children[q], progress))
        names.append(f"{obj}/sequence_{q}")
        objects.append(obj)
    stacked = {k: np.stack([r[k] for r in rows]) for k in rows[0]} if rows else empty_arrays(spec)
    return SequenceSet(names=np.asarray(names, dtype=str), objects=np.asarray(objects, dtype=str), fps=float(spec.fps),
                       **stacked)


def empty_arrays(spec: SequenceSpec) -> dict:
    """A SequenceSet's arrays for no sequence (0 along the first axis)."""
    F, L = spec.n_frames, spec.n_sensors
    return dict(T_world_object=np.zeros((0, F, 4, 4)), T_world_sensors=np.zeros((0, F, L, 4, 4)),
                T_world_sensors_true=np.zeros((0, F, L, 4, 4)), images=np.zeros((0, F, L, 320, 240, 3), np.uint8),
                touching=np.zeros((0, F, L), bool), contact_points=np.zeros((0, F, L, 3)),
                contact_normals=np.zeros((0, F, L, 3)), depths=np.zeros((0, F, L)), lift_weights=np.zeros((0, F, L)),
                pose_bias_translation=np.zeros((0, L, 3)), pose_bias_rotvec=np.zeros((0, L, 3)))


# --- diagnostics ----------------------------------------------------------------------------------------


def gel_contacts(seqs: SequenceSet) -> np.ndarray:
    """(Q, F, L, 2) m: where each contact lies on its gel, the contact point's y and z in the sensor's
    frame (true poses) relative to the gel's centre; the apex is (0, 0)."""
    T_sensor_world = invert_pose(seqs.T_world_sensors_true)
    local = transform_points(T_sensor_world, seqs.contact_points[..., None, :])[..., 0, :]
    return local[..., 1:] - GEL_CENTER[1:]


def object_contacts(seqs: SequenceSet) -> np.ndarray:
    """(Q, F, L, 3) m: each contact point in the object's frame."""
    T_object_world = invert_pose(seqs.T_world_object)[:, :, None]
    return transform_points(T_object_world, seqs.contact_points[..., None, :])[..., 0, :]


def frame_steps(paths: np.ndarray) -> np.ndarray:
    """(Q, F, L, d) positions -> (Q, F-1, L) distances moved from each frame to the next."""
    return np.linalg.norm(np.diff(paths, axis=1), axis=-1)


def path_lengths(paths: np.ndarray) -> np.ndarray:
    """(Q, F, L, d) positions -> (Q, L) the length of each path."""
    return frame_steps(paths).sum(axis=1)


def summary(seqs: SequenceSet) -> dict:
    """What a set holds, in numbers: sequences, frames per sequence, the share of frames in which some sensor
    does not touch (lifted), and per contact the mean path over its gel and over the object's surface (mm)."""
    return {"sequences": len(seqs), "frames": int(seqs.T_world_object.shape[1]), "fps": float(seqs.fps),
            "lifted_frame_share": float(np.mean(~seqs.touching.all(axis=2))) if len(seqs) else 0.0,
            "gel_travel_mm": float(1e3 * path_lengths(gel_contacts(seqs)).mean()) if len(seqs) else 0.0,
            "surface_slide_mm": float(1e3 * path_lengths(object_contacts(seqs)).mean()) if len(seqs) else 0.0}
