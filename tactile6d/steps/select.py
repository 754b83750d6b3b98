"""Step 2, select: the candidate tuples of database points for the sensors.

Tactile selection keeps, per sensor, the database points whose latent angle is within ``delta_h`` of
the image's (``selection.angles_to_omegas``); distance selection keeps the tuples of those points whose
pairwise distances match the sensors' (``selection.select_tuples``). Nothing matching either is a
``NoMatch`` outcome, not an input error.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from tactile6d import selection
from tactile6d.contacts import Contacts
from tactile6d.errors import InputError
from tactile6d.settings import SelectSettings, SensorSettings


@dataclass(frozen=True)
class Selection:
    """Result and diagnostics of the selection step.

    tuples (T, L) int64 database indices; errors (T,) mean pair-distance error (m); omega_sizes (L,)
    |Omega_i|; delta_h (L,) the latent-angle threshold each sensor used (rad; NaN for the baseline);
    widened (L,) whether it had to be raised above ``select.delta_h``; delta_d the distance threshold
    the adaptive rule stopped at (m); capped: only the N lowest-error tuples were kept.
    """

    tuples: np.ndarray
    errors: np.ndarray
    omega_sizes: np.ndarray
    delta_h: np.ndarray
    widened: np.ndarray
    delta_d: float
    capped: bool


def select(
    points: np.ndarray,
    db_angles: np.ndarray | None,
    contacts: Contacts,
    angles: np.ndarray | None,
    settings: SelectSettings,
    normals: np.ndarray | None = None,
    *,
    sensors: SensorSettings,
) -> Selection:
    """Tactile then distance selection; method 'baseline' skips the tactile part (all M points per sensor).

    points (M, 3) database points (object frame, m); db_angles (M,) their latent angles (rad; unused
    by the baseline); contacts: the L sensors' contact points and normals (``tactile6d.contacts``); angles (L,) the sensors' latent angles (rad; unused by
    the baseline); normals (M, 3) the points' outward normals, needed when ``select.normal_tol_deg``
    is set (normal-consistent tuples only); sensors: how far the sensor poses may be off, which widens
    the distance and normal tolerances (``SensorSettings.pair_distance_tolerance``, ``pair_angle_tolerance``).
    """
    n_sensors = contacts.points.shape[0]
    check = None
    if settings.normals_apply(n_sensors):
        if normals is None:
            raise InputError("select.normal_tol_deg is set: the database normals are needed")
        check = selection.NormalCheck(np.asarray(normals, dtype=np.float64), contacts.normals,
                                      float(np.radians(settings.normal_tol_deg)) + sensors.pair_angle_tolerance)
    if settings.method == "ours":
        if db_angles is None or angles is None:
            raise InputError("method 'ours' needs the database's and the images' latent angles")
        # The widening is reported in Selection.widened; no warning per scene.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tactile = selection.angles_to_omegas(
                db_angles, angles, settings.delta_h, settings.delta_h_widen_step, settings.delta_h_max
            )
        omegas, delta_h = tactile.omegas, tactile.delta_h
        widened = delta_h > settings.delta_h + 1e-12
    else:
        omegas = selection.all_points_omegas(points.shape[0], n_sensors)
        delta_h = np.full(n_sensors, np.nan)
        widened = np.zeros(n_sensors, dtype=bool)
    chosen = selection.select_tuples(
        points,
        contacts.points,
        omegas,
        n_max=int(settings.N),
        delta_start=float(settings.delta_d_start),
        step_down=float(settings.delta_d_down),
        step_up=float(settings.delta_d_up),
        delta_max=float(settings.delta_d_max),
        rng=np.random.default_rng(settings.seed),
        rule=str(settings.delta_d_rule),
        normals=check,
        tolerance=sensors.pair_distance_tolerance,
    )
    return Selection(
        tuples=chosen.tuples,
        errors=chosen.errors,
        omega_sizes=np.array([len(o) for o in omegas]),
        delta_h=np.asarray(delta_h, dtype=np.float64),
        widened=np.asarray(widened, dtype=bool),
        delta_d=chosen.delta_d,
        capped=chosen.capped,
    )
