"""Each sensor's mounting error, learnt from grasps of a known object at a known pose (not in the paper).

A hand's forward kinematics puts each fingertip off by millimetres and degrees, and much of that error is
usually a bias of its own per finger (how the sensor sits on its link, a joint's zero offset) that stays from one
grasp to the next. The estimator only knows how large the error may be (``sensors.pose_sigma_*``); a bias
measured once can be taken out of every later grasp instead. Here each sensor's pose as the hand reports
it is corrected by a fixed offset in the sensor's own frame,

    T_world_sensor (true) = T_world_sensor (reported) @ offset_i,        offset_i = exp(xi_i), xi = (v, omega)

fitted from scenes whose object pose is known (a calibration object held in a fixture, or placed by a
motion-capture rig): in each such scene everything sensor i read from its image (its contact point and
normal, the points of its pressed gel, in the sensor's frame) is carried through the reported pose, the
offset and the known object pose onto the object, and should lie on its surface. For sensor i:

    min over xi_i of  sum_k sum_j rho(r_kj)^2 + ||(fit_noise / sigma_m) v_i||^2 + ||(fit_noise / sigma_rad) omega_i||^2

with point-to-plane residuals r = m . (q - c) (q the point in the object frame, (c, m) the surface sample
matched to it, as ``refine.SurfaceFit.match``), normal residuals ``normal_weight (u - m)``, Cauchy weights
(2 mm, 10 deg), and a Gaussian prior of the error the hand is declared to have (the same ``sensors``
sigmas), so that what the scenes leave free (a sensor that only ever pressed flat faces says nothing of
how far it slid along them) stays at zero. The object pose is known, so each sensor's offset is fitted
alone, by Gauss-Newton steps (clipped to 3 mm and 3 deg) on the right of its current offset.

What a press tells, and what it does not: a sensor pressing a surface shows how far the surface is along
its axis and how the surface is tilted under it, so each grasp fixes the offset's shift of the gel along
the sensor's axis (x) and, on flat faces, its tilt (turns about y and z), the latter as far as the contact
normals' noise (about 3 deg each: ``normal_weight`` against ``fit_noise``) lets the grasps outweigh the
prior. A flat face looks the same wherever the gel slides over it, and a curved one nearly so (its tilt
trades against the slide), so the sideways shift (y, z) and the twist about the axis are told only where
the surface under the gel changes shape from grasp to grasp (edges, corners, rims), and otherwise stay at
the prior's zero.
``SensorOffsets.gel_sigma_m`` and ``turn_sigma_rad`` say which: each offset's posterior standard deviation
of the gel centre's shift and of its turn per sensor axis (the Gauss-Newton system's inverse scaled by the
readings' noise ``fit_noise``; the prior's sigmas where the grasps told nothing). They bound what is left of
the bias; an error that changes from grasp to grasp (a joint's backlash) is not in them.

Units: metres, radians. Poses 4x4 float64.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import invert_pose, make_pose, rotmat_to_rotvec, rotvec_to_rotmat, skew
from tactile6d.core.sensor import GEL_CENTER
from tactile6d.estimation.refine import FIT_NOISE, SurfaceFit
from tactile6d.perception.contacts import Contacts

# Robust (Cauchy) scales of the point-to-plane and normal residuals, as the refinement's.
_ROBUST_DISTANCE = 0.002
_ROBUST_ANGLE = np.radians(10.0)
# A step is clipped to this much (m, rad): offsets are millimetres and degrees, not a global search.
_MAX_STEP_T = 0.003
_MAX_STEP_R = np.radians(3.0)
# The file format's name and version, written into every offsets file and checked on reading.
FORMAT = "tactile6d-sensor-offsets"
VERSION = 1


@dataclass(frozen=True)
class KnownGrasp:
    """One scene whose object pose is known: what the calibration reads from it.

    surface: the object's surface samples (``surface_sampling.SurfaceSamples``: ``points`` (S, 3), unit
    ``normals`` (S, 3), a cKDTree ``tree``), object frame; T_world_object (4, 4) the known pose;
    T_world_sensors (L, 4, 4) the sensor poses as the hand reported them; contacts: what the images say,
    read through those poses (``Estimator.read_scene``). Only sensors whose contact was read from their
    image count (``contacts.from_patch``): a landmark is where a contact would be, not where it is.
    """

    surface: object
    T_world_object: np.ndarray
    T_world_sensors: np.ndarray
    contacts: Contacts


@dataclass(frozen=True)
class SensorOffsets:
    """Fitted offsets: offsets (L, 4, 4), ``T_true = T_reported @ offsets[i]``; gel_sigma_m (L, 3) m and
    turn_sigma_rad (L, 3) rad, the posterior standard deviations of each offset's shift of the gel centre
    (``sensor.GEL_CENTER``) and of its turn, per axis of the sensor's frame (module docstring); grasps (L,)
    in how many scenes each sensor's contact was read; residual_mm (L,) the RMS point-to-plane residual of
    each sensor's contact points once corrected (mm), residual_before_mm (L,) before (NaN for a sensor
    never read); notes: free-form provenance written with the file."""

    offsets: np.ndarray
    gel_sigma_m: np.ndarray
    turn_sigma_rad: np.ndarray
    grasps: np.ndarray
    residual_mm: np.ndarray
    residual_before_mm: np.ndarray
    notes: dict = field(default_factory=dict)

    @property
    def n_sensors(self) -> int:
        return int(self.offsets.shape[0])

    def translations_mm(self) -> np.ndarray:
        """(L, 3) each offset's translation, mm, in its sensor's frame."""
        return 1000.0 * self.offsets[:, :3, 3]

    def rotations_deg(self) -> np.ndarray:
        """(L, 3) each offset's rotation vector, degrees, in its sensor's frame."""
        return np.degrees(rotmat_to_rotvec(self.offsets[:, :3, :3]))

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "convention": "T_world_sensor_true = T_world_sensor_reported @ offset; offset in the sensor's frame, "
                          "translation in metres, rotation as a rotation vector in radians",
            "sensors": [
                {
                    "translation_m": self.offsets[i, :3, 3].tolist(),
                    "rotvec_rad": rotmat_to_rotvec(self.offsets[i, :3, :3]).tolist(),
                    "gel_sigma_m": self.gel_sigma_m[i].tolist(),
                    "turn_sigma_rad": self.turn_sigma_rad[i].tolist(),
                    "grasps": int(self.grasps[i]),
                    "residual_mm": _number_or_none(self.residual_mm[i]),
                    "residual_before_mm": _number_or_none(self.residual_before_mm[i]),
                }
                for i in range(self.n_sensors)
            ],
            "notes": dict(self.notes),
        }

    def write(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def from_dict(cls, data: dict, source: str = "sensor offsets") -> SensorOffsets:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise InputError(f"{source}: not a sensor offsets file (no \"format\": \"{FORMAT}\")")
        if data.get("version") != VERSION:
            raise InputError(f"{source}: version {data.get('version')!r}, this tactile6d reads version {VERSION}")
        sensors = data.get("sensors")
        if not isinstance(sensors, list) or not sensors:
            raise InputError(f"{source}: \"sensors\" must be a non-empty list")
        try:
            t = np.array([s["translation_m"] for s in sensors], dtype=np.float64).reshape(-1, 3)
            w = np.array([s["rotvec_rad"] for s in sensors], dtype=np.float64).reshape(-1, 3)
            values = {k: np.array([np.nan if s[k] is None else s[k] for s in sensors], dtype=np.float64)
                      for k in ("gel_sigma_m", "turn_sigma_rad", "residual_mm", "residual_before_mm")}
            grasps = np.array([s["grasps"] for s in sensors], dtype=int)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{source}: a sensor entry is malformed ({exc})") from None
        if len(t) != len(sensors) or len(w) != len(sensors) or not (np.isfinite(t).all() and np.isfinite(w).all()):
            raise InputError(f"{source}: each sensor needs 3 finite translation_m and 3 finite rotvec_rad values")
        if values["gel_sigma_m"].shape != (len(sensors), 3) or values["turn_sigma_rad"].shape != (len(sensors), 3):
            raise InputError(f"{source}: each sensor needs 3 gel_sigma_m and 3 turn_sigma_rad values")
        return cls(make_pose(rotvec_to_rotmat(w), t), grasps=grasps, notes=dict(data.get("notes") or {}), **values)

    @classmethod
    def read(cls, path: str | Path) -> SensorOffsets:
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except OSError as exc:
            raise InputError(f"{path}: cannot read the sensor offsets ({exc.strerror or exc})") from None
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: not JSON ({exc})") from None
        return cls.from_dict(data, str(path))


def _number_or_none(value: float) -> float | None:
    """JSON has no NaN: a sensor never read has no residual."""
    return None if np.isnan(value) else float(value)


def apply_sensor_offsets(T_world_sensors: np.ndarray, offsets: SensorOffsets | np.ndarray) -> np.ndarray:
    """Reported sensor poses (..., L, 4, 4) -> corrected ones, ``T @ offsets[i]`` for each sensor i.

    offsets: a ``SensorOffsets`` or (L, 4, 4). The sensors must be in the order the offsets were fitted in."""
    T = np.asarray(T_world_sensors, dtype=np.float64)
    E = offsets.offsets if isinstance(offsets, SensorOffsets) else np.asarray(offsets, dtype=np.float64)
    if T.ndim < 3 or T.shape[-2:] != (4, 4):
        raise InputError(f"sensor poses must have shape (..., L, 4, 4), got {T.shape}")
    if T.shape[-3] != E.shape[0]:
        raise InputError(f"{T.shape[-3]} sensor poses but offsets for {E.shape[0]} sensors: the offsets were "
                         f"fitted for a hand of {E.shape[0]} sensors, given in the same order")
    return T @ E


def _grasp_rows(grasp: KnownGrasp, patch_points: int, patch_weight: float, normal_weight: float) -> list:
    """Each sensor's readings in one grasp, in its own frame -> per sensor None (its contact was not read from
    its image) or (A (4, 4) object <- reported sensor, points (M, 3) with the contact point first, their
    weights (M,), the contact normal (3,), the SurfaceFit that matches them)."""
    c = grasp.contacts
    T = np.asarray(grasp.T_world_sensors, dtype=np.float64)
    to_object = invert_pose(np.asarray(grasp.T_world_object, dtype=np.float64))
    fit = SurfaceFit(grasp.surface, np.zeros((1, 3)), np.ones((1, 3)), normal_weight)  # only its matching is used
    extra, owners = c.patch_points(T, patch_points)
    rows = []
    for i in range(len(T)):
        if not bool(c.from_patch[i]):
            rows.append(None)
            continue
        to_sensor = invert_pose(T[i])
        point = to_sensor[:3, :3] @ np.asarray(c.points[i], dtype=np.float64) + to_sensor[:3, 3]
        normal = to_sensor[:3, :3] @ np.asarray(c.normals[i], dtype=np.float64)
        own = extra[owners == i] @ to_sensor[:3, :3].T + to_sensor[:3, 3]
        weights = np.concatenate([[1.0], np.full(len(own), patch_weight / np.sqrt(max(len(own), 1)))])
        rows.append((to_object @ T[i], np.vstack([point[None], own]), weights, normal / np.linalg.norm(normal), fit))
    return rows


def _clip(step: np.ndarray) -> np.ndarray:
    step = step.copy()
    for part, limit in ((slice(0, 3), _MAX_STEP_T), (slice(3, 6), _MAX_STEP_R)):
        norm = np.linalg.norm(step[part])
        if norm > limit:
            step[part] *= limit / norm
    return step


def _normal_equations(rows, E: np.ndarray, normal_weight: float):
    """The Gauss-Newton system of one sensor's readings over its grasps at offset E (4, 4) -> (H (6, 6),
    g (6,), the contact points' point-to-plane residuals (K,) m). rows: per grasp (A (4, 4) object <- reported
    sensor, points (M, 3), weights (M,), normal (3,), SurfaceFit)."""
    H, g, contact_residuals = np.zeros((6, 6)), np.zeros(6), []
    for A, points, weights, normal, fit in rows:
        M = A @ E
        R = M[:3, :3]
        q = points @ R.T + M[:3, 3]
        u = R @ normal
        c0, m0 = fit.match(q[:1], u[None])  # the contact point, matched with its normal
        _, idx = fit.surface.tree.query(q[1:]) if len(q) > 1 else (None, np.zeros(0, dtype=int))
        c = np.vstack([c0, fit.surface.points[idx]])
        m = np.vstack([m0, fit.surface.normals[idx]])
        r = np.sum(m * (q - c), axis=1)
        contact_residuals.append(r[0])
        m_sensor = m @ R  # each matched normal in the sensor's frame: rows R^T m
        J = np.concatenate([m_sensor, np.cross(points, m_sensor)], axis=1)  # dr/d(v, omega), right perturbation
        rho = weights**2 / (1.0 + (r / _ROBUST_DISTANCE) ** 2)
        H += np.einsum("m,ma,mb->ab", rho, J, J)
        g += np.einsum("m,ma,m->a", rho, J, r)
        if normal_weight > 0:
            r_n = normal_weight * (u - m0[0])
            J_n = -normal_weight * R @ skew(normal)  # du/domega = -R [n]x
            rho_n = 1.0 / (1.0 + (np.linalg.norm(u - m0[0]) / _ROBUST_ANGLE) ** 2)
            H[3:, 3:] += rho_n * J_n.T @ J_n
            g[3:] += rho_n * J_n.T @ r_n
    return H, g, np.asarray(contact_residuals)


def fit_sensor_offsets(
    grasps: Sequence[KnownGrasp],
    sigma_m: float,
    sigma_rad: float,
    normal_weight: float = 0.01,
    patch_points: int = 32,
    patch_weight: float = 1.0,
    fit_noise: float = FIT_NOISE,
    n_iterations: int = 20,
) -> SensorOffsets:
    """Each sensor's offset from grasps of known objects at known poses (module docstring).

    grasps: the scenes (the same hand, its sensors in the same order in each); sigma_m (m) and sigma_rad
    (rad): the prior, per axis, on each offset (``sensors.pose_sigma_mm``/``_deg`` of the hand, > 0);
    normal_weight (m/rad), patch_points (per sensor) and patch_weight as the ranking's refinement
    (``rank.refine_normal_weight``, ``refine_patch_points``, ``refine_patch_weight``); fit_noise (m) the
    readings' noise the prior is weighed against. A sensor read in no grasp keeps the identity offset and
    its prior's sigmas.
    """
    if not grasps:
        raise InputError("no grasps to fit the sensor offsets from")
    if not (sigma_m > 0 and sigma_rad > 0):
        raise InputError("the sensor offsets' prior needs sensors.pose_sigma_mm and sensors.pose_sigma_deg > 0")
    n_sensors = {np.asarray(g.T_world_sensors).shape[0] for g in grasps}
    if len(n_sensors) != 1:
        raise InputError(f"the grasps have different numbers of sensors ({sorted(n_sensors)}): one hand, "
                         "its sensors in the same order, is calibrated at a time")
    L = n_sensors.pop()
    prior = np.diag([(fit_noise / sigma_m) ** 2] * 3 + [(fit_noise / sigma_rad) ** 2] * 3)
    offsets = np.repeat(np.eye(4)[None], L, axis=0)
    covariances = np.repeat((fit_noise**2 * np.linalg.inv(prior))[None], L, axis=0)
    counts, after, before = np.zeros(L, dtype=int), np.full(L, np.nan), np.full(L, np.nan)
    per_grasp = [_grasp_rows(grasp, patch_points, patch_weight, normal_weight) for grasp in grasps]
    for i in range(L):
        rows = [read[i] for read in per_grasp if read[i] is not None]
        counts[i] = len(rows)
        if not rows:
            continue
        E = np.eye(4)
        for iteration in range(int(n_iterations)):
            H, g, residuals = _normal_equations(rows, E, normal_weight)
            if iteration == 0:
                before[i] = 1000.0 * np.sqrt(np.mean(residuals**2))
            xi = np.concatenate([E[:3, 3], rotmat_to_rotvec(E[:3, :3])])
            step = _clip(-np.linalg.solve(H + prior, g + prior @ xi))
            E = E @ make_pose(rotvec_to_rotmat(step[3:]), step[:3])
        H, _, residuals = _normal_equations(rows, E, normal_weight)
        after[i] = 1000.0 * np.sqrt(np.mean(residuals**2))
        covariances[i] = fit_noise**2 * np.linalg.inv(H + prior)
        offsets[i] = E
    return SensorOffsets(offsets, *_gel_and_turn_sigmas(covariances), counts, after, before)


def gel_centre_shifts(errors: np.ndarray) -> np.ndarray:
    """Sensor-frame pose errors or offsets (..., 4, 4) -> how far each moves the gel centre
    (``sensor.GEL_CENTER``), (..., 3) m along the sensor's axes: x along its axis, y and z sideways."""
    errors = np.asarray(errors, dtype=np.float64)
    return np.einsum("...ab,b->...a", errors[..., :3, :3], GEL_CENTER) + errors[..., :3, 3] - GEL_CENTER


def _gel_and_turn_sigmas(covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(L, 6, 6) covariances of offsets (v, omega) -> standard deviations per sensor axis (L, 3) of the gel
    centre's shift, v + omega x GEL_CENTER (m), and of the turn omega (rad)."""
    to_gel = np.hstack([np.eye(3), -skew(GEL_CENTER)])
    gel = np.einsum("ab,lbc,dc->lad", to_gel, covariances, to_gel)
    return (np.sqrt(np.diagonal(gel, axis1=1, axis2=2)),
            np.sqrt(np.diagonal(covariances[:, 3:, 3:], axis1=1, axis2=2)))


def prior_sigmas(sigma_m: float, sigma_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """What the prior alone leaves uncertain, as ``SensorOffsets.gel_sigma_m`` and ``turn_sigma_rad`` of one
    sensor: (3,) m and (3,) rad per sensor axis."""
    gel, turn = _gel_and_turn_sigmas(np.diag([sigma_m**2] * 3 + [sigma_rad**2] * 3)[None])
    return gel[0], turn[0]

