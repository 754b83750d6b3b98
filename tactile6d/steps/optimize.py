"""Step 3, optimize: pose hypotheses for the selected tuples.

Each tuple gets one random rotation and one or more starting translations, refined so that the tuple's
database points land on the sensors' contact points (``tactile6d.optimize``: the paper's gradient
descent, solver ``gd``, or a closed-form + IRLS solver, ``fast``).
"""

from __future__ import annotations

import numpy as np

from tactile6d import optimize as optimization
from tactile6d.contacts import Contacts
from tactile6d.settings import OptimizeSettings, SensorSettings


def optimize(
    points: np.ndarray,
    contacts: Contacts,
    tuples: np.ndarray,
    settings: OptimizeSettings,
    normals: np.ndarray | None = None,
    *,
    sensors: SensorSettings,
) -> optimization.PoseHypotheses:
    """Pose hypotheses for the tuples: (P, 4, 4) poses, (P,) losses (m), tuple index.

    contacts: the L sensors' contact points and normals (``tactile6d.contacts``); normals (M, 3): the database
    normals, needed when ``optimize.normal_weight`` > 0; sensors: how far the sensor poses may be off, whose
    contact error (``SensorSettings.contact_sigma``, ``angle_sigma``) is the fast solver's noise floor when
    ``optimize.noise_floor`` is on.
    """
    return optimization.tuples_to_poses(
        points,
        contacts.points,
        tuples,
        settings.solver,
        np.random.default_rng(settings.seed),
        n_steps=int(settings.n_steps),
        gain_t=float(settings.gain_t),
        gain_r=float(settings.gain_r),
        offset=float(settings.offset),
        n_translations=int(settings.n_translations),
        n_irls=int(settings.n_irls),
        precision=str(settings.precision),
        normals=normals,
        sensor_normals=contacts.normals,
        normal_weight=settings.normal_weight_for(contacts.points.shape[0]),
        noise=settings.noise_for(sensors),
    )
