"""Refining ranked pose hypotheses against the object's surface (not in the paper; ``rank.refine``).

The optimiser fits each pose to database points, which lie millimetres apart, so even the right tuple
leaves a few millimetres of error. Refinement moves a pose so that every sensor's contact point
(``sensor.contact_points``) lies on the object's surface, ``offset`` outside it, and (weight
``normal_weight``) every sensor's contact normal (its -x axis, ``sensor.contact_normals``) matches
the surface normal there:

    F(T) = sum_i (m_i . (q_i - c_i) - offset)^2 + normal_weight^2 sum_i || u_i - m_i ||^2

with q_i = T^-1 s_i the contact point in the object frame, u_i = R^T n_i the contact normal there,
and (c_i, m_i) the surface sample (point, outward face normal) matched to sensor i: among the ``k``
samples nearest q_i, the one minimising ||q_i - c||^2 + normal_weight^2 ||u_i - m||^2 (so that a
contact near an edge matches the face the sensor presses, not the one around the corner). Each
iteration re-matches, then takes one damped, robustly weighted (Cauchy, 2 mm and 10 deg) Gauss-Newton step on SE(3), ``T <- T [exp(omega^), v]``
(a weak prior anchoring the pose to its start keeps directions the contacts leave free in place;
each step is clipped to 5 mm and 5 deg); all poses are refined together, vectorised. The surface is a dense,
fixed, area-uniform sample with face normals (``surface_sampling.sample_surface``, 1 mm spacing).

With the contact patches read from the images (``rank.refine_patch_points``), the points of each patch's
pressed gel, which lie on the object's surface, join the fit as further point-to-plane rows (matched to
their nearest sample, robustly weighted like the contacts); one sensor's patch points together weigh
``rank.refine_patch_weight`` times its contact point. A patch spans millimetres of surface, so it also
fixes how the surface is tilted and curved there, which one point cannot.

With ``rank.refine_free_weight`` above 0, the gel the patches leave untouched joins the fit too, one-sided: a
point of the undeformed gel outside the observed mask (``Contacts.free_points``) that lies inside the object,
deeper than a margin, is pushed out point-to-plane; one outside it costs nothing. The pressed points alone let a
pose press the gel over a wider area than the image shows (render-and-compare then pays for it); these rows make
the fit reproduce the image's extent as well (``free_rows``).

Three contact points alone leave three degrees of freedom (each point-to-plane residual is one
equation); the normal term adds two equations per sensor, which fixes the pose for L >= 2 and also
tells apart hypotheses that fit the points equally well. ``surface_losses`` gives the two terms of
a refined pose (mean absolute point-to-plane residual, m; mean normal angle, rad), from which the
ranking scores refined poses (``estimator.rank``).

Sensor poses from a robot's forward kinematics are off by millimetres and degrees, so the contacts read
through them are too, each sensor by its own error, and no single object pose makes every sensor touch.
``refine_poses_and_sensors`` (used unless ``sensors.pose_sigma_mm``/``_deg`` declare the poses exact) lets each sensor see the
object through a small correction of its own, under a Gaussian prior of the sensor poses' expected error:
what no object pose explains goes to the sensors, at a cost ``sensor_corrections_cost`` that the ranking
adds to the score.

Units: metres, radians. Poses are 4x4 float64 ``T_world_object``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile6d.core.geometry import make_pose, rotmat_to_rotvec, rotvec_to_rotmat, skew

# A prior anchoring each pose to its start: each metre of accumulated translation counts as a
# residual of _PRIOR_T metres, each radian of rotation as _PRIOR_R metres. Directions the contacts
# leave free (contacts on two opposite faces and a third let the object slide along them) then stay
# where the database fit put them instead of drifting.
_PRIOR_T = 0.05
_PRIOR_R = 0.001
# Each step is clipped to this much translation (m) and rotation (rad): refinement corrects the few
# millimetres and degrees of a database fit; it is not a global search.
_MAX_STEP_T = 0.005
_MAX_STEP_R = np.radians(5.0)
# Scales of the robust weights: point-to-plane residual (m), normal difference (~ rad).
_ROBUST_DISTANCE = 0.002
_ROBUST_ANGLE = np.radians(10.0)
# How far (m) a contact of the right pose, seen through exact sensor poses, is off the surface: the noise the
# sensor corrections' prior is weighed against (a correction of one sigma costs as much as a residual this
# large). 0.2, 0.5 and 1 mm were tried on the kinematic set (docs/real_sensors.md); 0.5 mm ranked best.
FIT_NOISE = 0.0005


@dataclass(frozen=True)
class SurfaceFit:
    """What the refinement fits and scores: the sensors' contacts against the object's surface.

    surface: an object with ``points`` (S, 3), unit ``normals`` (S, 3) and a cKDTree ``tree`` over the
    points, in the object frame (``surface_sampling.SurfaceSamples``); points (L, 3) the sensors' contact
    points and normals (L, 3) their outward normals, world frame (stored as float64, normals made unit);
    normal_weight in m/rad (0: points only); offset (m) how far outside the surface the contact points
    should sit (a number, or (L,) one per sensor); k surface samples considered per match.
    """

    surface: object
    points: np.ndarray
    normals: np.ndarray
    normal_weight: float = 0.01
    offset: float | np.ndarray = 0.0
    k: int = 32

    def __post_init__(self) -> None:
        points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        normals = np.asarray(self.normals, dtype=np.float64).reshape(-1, 3)
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "normals", normals / np.linalg.norm(normals, axis=1, keepdims=True))
        object.__setattr__(self, "normal_weight", float(self.normal_weight))

    def match(self, q: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q, u (..., 3) object-frame contact points and normals -> matched sample points, normals (..., 3):
        among the ``k`` samples nearest each point, the one minimising ||q - c||^2 + normal_weight^2 ||u - m||^2."""
        shape, flat_q, points, normals = q.shape, q.reshape(-1, 3), self.surface.points, self.surface.normals
        k = int(min(self.k, len(points)))
        _, idx = self.surface.tree.query(flat_q, k=k)
        idx = np.asarray(idx).reshape(len(flat_q), k)
        c, m = points[idx], normals[idx]  # (n, k, 3)
        cost = (np.sum((flat_q[:, None] - c) ** 2, axis=-1)
                + self.normal_weight**2 * np.sum((u.reshape(-1, 3)[:, None] - m) ** 2, axis=-1))
        best = np.argmin(cost, axis=1)
        rows = np.arange(len(flat_q))
        return c[rows, best].reshape(shape), m[rows, best].reshape(shape)


def _to_object(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """poses (P, 4, 4) ``T_world_object``, world points (M, 3) -> the points in each pose's object frame (P, M, 3)."""
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    return np.einsum("pba,plb->pla", R, points[None] - t[:, None])


def _local(poses: np.ndarray, sensor_points: np.ndarray, sensor_normals: np.ndarray):
    """poses (P, 4, 4), or (P, L, 4, 4) the object as each sensor sees it (``refine_poses_and_sensors``)
    -> contact points q and normals u in each pose's object frame, (P, L, 3)."""
    if poses.ndim == 4:
        R = poses[..., :3, :3]
        return (np.einsum("plba,plb->pla", R, sensor_points[None] - poses[..., :3, 3]),
                np.einsum("plba,lb->pla", R, sensor_normals))
    return _to_object(poses, sensor_points), np.einsum("pba,lb->pla", poses[:, :3, :3], sensor_normals)


def _point_to_plane(q: np.ndarray, c: np.ndarray, m: np.ndarray, offset, weight) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations (JtJ (P, 6, 6), Jtr (P, 6)) of point-to-plane rows for points q (P, n, 3) matched to
    surface samples c with normals m: r = m.(q - c) - offset, dr/dv = -m, dr/domega = m x q; each row
    weighted ``weight`` (a number or (n,)) times a robust (Cauchy) weight 1 / (1 + (r / 2 mm)^2), so that
    a point matched to the wrong facet (a rounded edge of a scanned mesh) does not drag the pose (IRLS)."""
    r = np.sum(m * (q - c), axis=-1) - offset  # (P, n)
    J = np.concatenate([-m, np.cross(m, q)], axis=-1)  # (P, n, 6)
    rho = weight / (1.0 + (r / _ROBUST_DISTANCE) ** 2)
    return np.einsum("pl,pla,plb->pab", rho, J, J), np.einsum("pl,pla,pl->pa", rho, J, r)


def _normal_rows(u: np.ndarray, m: np.ndarray, w: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The normal rows of contact normals u (P, L, 3) matched to surface normals m: r = w (u - m) (P, L, 3),
    dr/domega = w [u]x (P, L, 3, 3) (u' = u + u x omega; dr/dv = 0), and their robust (Cauchy) weights (P, L)."""
    n_poses, n_sensors = u.shape[:2]
    J = w * skew(u.reshape(-1, 3)).reshape(n_poses, n_sensors, 3, 3)
    return w * (u - m), J, 1.0 / (1.0 + (np.linalg.norm(u - m, axis=-1) / _ROBUST_ANGLE) ** 2)


def _clip_step(step: np.ndarray) -> np.ndarray:
    """Steps (..., 6) (translation, rotation) with each part clipped to ``_MAX_STEP_T`` m, ``_MAX_STEP_R`` rad."""
    for part, limit in ((slice(0, 3), _MAX_STEP_T), (slice(3, 6), _MAX_STEP_R)):
        norm = np.linalg.norm(step[..., part], axis=-1, keepdims=True)
        step[..., part] *= np.minimum(1.0, limit / np.maximum(norm, 1e-300))
    return step


def free_rows(q: np.ndarray, surface, margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-sided point-to-plane rows of untouched gel points q (P, F, 3), object frame, against the surface.

    Each point is matched to its nearest surface sample (c, outward normal m); the signed distance m.(q - c) is
    negative inside the object. -> r (P, F) = m.(q - c) + margin where that is below 0 (the point lies deeper
    than margin inside) and the point is within ``2.5 * _ROBUST_DISTANCE`` of the sample (farther, the nearest
    sample's normal says little about inside and out), else 0; J (P, F, 6) dr/d(v, omega) as the patch rows'
    (-m, m x q); active (P, F) bool, where r is not 0 by the rule above.
    """
    distance, idx = surface.tree.query(q.reshape(-1, 3))
    c, m = surface.points[idx].reshape(q.shape), surface.normals[idx].reshape(q.shape)
    r = np.sum(m * (q - c), axis=-1) + margin
    active = (r < 0.0) & (np.asarray(distance).reshape(r.shape) < 2.5 * _ROBUST_DISTANCE)
    return np.where(active, r, 0.0), np.concatenate([-m, np.cross(m, q)], axis=-1), active


def _free_weights(r: np.ndarray, active: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Residual weights (P, F) of ``free_rows``: squared weights (F,) times the robust (Cauchy) weight where active."""
    return np.where(active, weights / (1.0 + (r / _ROBUST_DISTANCE) ** 2), 0.0)


def refine_poses(
    fit: SurfaceFit,
    poses: np.ndarray,
    n_iterations: int = 8,
    patch_points: np.ndarray | None = None,
    patch_weights: np.ndarray | None = None,
    free_points: np.ndarray | None = None,
    free_weights: np.ndarray | None = None,
    free_margin: float = 0.0,
) -> np.ndarray:
    """Refine poses (P, 4, 4) so the sensors of ``fit`` touch its surface (module docstring) -> (P, 4, 4).

    patch_points (M, 3), world frame, with patch_weights (M,): further points known to lie on the
    surface (the pressed gel of the observed contact patches, ``Contacts.patch_points``), each fitted
    point-to-plane to its nearest surface sample with residual weight ``patch_weights``. free_points
    (F, 3), world frame, with free_weights (F,): points of untouched gel (``Contacts.free_points``) that
    the surface must not lie beyond by more than free_margin (m), fitted one-sided (``free_rows``).
    """
    T, s, n, surface = np.array(poses, dtype=np.float64).reshape(-1, 4, 4), fit.points, fit.normals, fit.surface
    n_poses = T.shape[0]
    if n_poses == 0:
        return T
    w = fit.normal_weight
    prior = np.diag([_PRIOR_T**2] * 3 + [_PRIOR_R**2] * 3)
    moved = np.zeros((n_poses, 6))  # accumulated steps (local frame, first order)
    has_patch = patch_points is not None and len(patch_points) > 0
    if has_patch:
        extra = np.asarray(patch_points, dtype=np.float64).reshape(-1, 3)
        extra_w = np.asarray(patch_weights, dtype=np.float64).reshape(-1) ** 2
    has_free = free_points is not None and len(free_points) > 0
    if has_free:
        free = np.asarray(free_points, dtype=np.float64).reshape(-1, 3)
        free_w = np.asarray(free_weights, dtype=np.float64).reshape(-1) ** 2
    for _ in range(int(n_iterations)):
        q, u = _local(T, s, n)
        c, m = fit.match(q, u)
        JtJ, Jtr = _point_to_plane(q, c, m, fit.offset, 1.0)
        if has_patch:
            qp = _to_object(T, extra)  # (P, M, 3); each matched to its nearest sample
            _, idx = surface.tree.query(qp.reshape(-1, 3))
            patch_JtJ, patch_Jtr = _point_to_plane(qp, surface.points[idx].reshape(qp.shape),
                                                   surface.normals[idx].reshape(qp.shape), 0.0, extra_w)
            JtJ += patch_JtJ
            Jtr += patch_Jtr
        if has_free:
            r_f, J_f, active = free_rows(_to_object(T, free), surface, free_margin)
            rho_f = _free_weights(r_f, active, free_w)
            JtJ += np.einsum("pf,pfa,pfb->pab", rho_f, J_f, J_f)
            Jtr += np.einsum("pf,pfa,pf->pa", rho_f, J_f, r_f)
        if w > 0:
            r_n, J_n, rho_n = _normal_rows(u, m, w)
            JtJ[:, 3:, 3:] += np.einsum("pl,plia,plib->pab", rho_n, J_n, J_n)
            Jtr[:, 3:] += np.einsum("pl,plia,pli->pa", rho_n, J_n, r_n)
        step = _clip_step(-np.linalg.solve(JtJ + prior, (Jtr + moved @ prior)[..., None])[..., 0])
        moved += step
        T = T @ make_pose(rotvec_to_rotmat(step[:, 3:]), step[:, :3])
    return T


def surface_losses(fit: SurfaceFit, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How well each pose (P, 4, 4) makes the sensors of ``fit`` touch its surface -> (distance (P,) m, angle (P,) rad):
    the mean over sensors of |point-to-plane residual| and of the angle between the contact normal and
    the matched surface normal (matching as in ``refine_poses``). Poses (P, L, 4, 4): the object as each
    sensor sees it (``refine_poses_and_sensors``)."""
    poses = np.asarray(poses, dtype=np.float64)
    q, u = _local(poses if poses.ndim == 4 else poses.reshape(-1, 4, 4), fit.points, fit.normals)
    c, m = fit.match(q, u)
    distance = np.abs(np.sum(m * (q - c), axis=-1) - fit.offset).mean(axis=1)
    angle = np.arccos(np.clip(np.sum(u * m, axis=-1), -1.0, 1.0)).mean(axis=1)
    return distance, angle


def refine_poses_and_sensors(
    fit: SurfaceFit,
    poses: np.ndarray,
    sigma_contact: float,
    sigma_angle: float,
    fit_noise: float = FIT_NOISE,
    n_iterations: int = 8,
    patch_points: np.ndarray | None = None,
    patch_weights: np.ndarray | None = None,
    patch_owners: np.ndarray | None = None,
    free_points: np.ndarray | None = None,
    free_weights: np.ndarray | None = None,
    free_owners: np.ndarray | None = None,
    free_margin: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``refine_poses`` for sensor poses that are off (forward kinematics): each sensor's small pose error
    is estimated beside the object's pose -> (poses (P, 4, 4), seen (P, L, 4, 4)).

    Sensor i sees the object at ``seen[p, i] = poses[p] exp(zeta_pi)`` instead of ``poses[p]``: everything
    read through sensor i (its contact point and normal, its patch points) is fitted against the object at
    ``seen[p, i]``. Each correction zeta_pi = (v, omega) (object frame) pays a Gaussian prior: the shift of
    the contact point, ``v + omega x q_i``, has standard deviation ``sigma_contact`` (m) per axis and the
    turn ``omega`` ``sigma_angle`` (rad), both against the residuals' own noise ``fit_noise`` (m), so that a
    correction of one sigma costs as much as a residual of ``fit_noise``. Contacts that no single object
    pose explains are then explained by small sensor errors instead of by moving the object, which the
    contacts common to every sensor still do. Other arguments as ``refine_poses``; patch_owners (M,) and
    free_owners (F,) the sensor each patch point and free point belongs to. With sigmas of 0 use ``refine_poses``.
    """
    T, s, n, surface = np.array(poses, dtype=np.float64).reshape(-1, 4, 4), fit.points, fit.normals, fit.surface
    n_poses, n_sensors = T.shape[0], s.shape[0]
    seen = np.repeat(T[:, None], n_sensors, axis=1)
    if n_poses == 0:
        return T, seen
    w = fit.normal_weight
    dim = 6 + 6 * n_sensors
    prior = np.diag([_PRIOR_T**2] * 3 + [_PRIOR_R**2] * 3)
    moved = np.zeros((n_poses, 6))
    zeta = np.zeros((n_poses, n_sensors, 6))
    has_patch = patch_points is not None and len(patch_points) > 0
    if has_patch:
        extra = np.asarray(patch_points, dtype=np.float64).reshape(-1, 3)
        extra_w = np.asarray(patch_weights, dtype=np.float64).reshape(-1) ** 2
        patch_owner = np.asarray(patch_owners, dtype=int).reshape(-1)  # (M,) each point's sensor
        owners = np.eye(n_sensors)[patch_owner]  # (M, L) one-hot
    has_free = free_points is not None and len(free_points) > 0
    if has_free:
        free = np.asarray(free_points, dtype=np.float64).reshape(-1, 3)
        free_w = np.asarray(free_weights, dtype=np.float64).reshape(-1) ** 2
        free_owned = np.eye(n_sensors)[np.asarray(free_owners, dtype=int).reshape(-1)]  # (F, L) one-hot
    a_scale, b_scale = fit_noise / sigma_contact, fit_noise / sigma_angle
    for _ in range(int(n_iterations)):
        R_seen = seen[..., :3, :3]
        q, u = _local(seen, s, n)  # (P, L, 3), each through its own sensor
        c, m = fit.match(q, u)
        r = np.sum(m * (q - c), axis=-1) - fit.offset  # (P, L)
        J = np.concatenate([-m, np.cross(m, q)], axis=-1)  # (P, L, 6)
        rho = 1.0 / (1.0 + (r / _ROBUST_DISTANCE) ** 2)
        B = np.einsum("pl,pla,plb->plab", rho, J, J)  # each sensor's rows' normal equations (P, L, 6, 6)
        g = np.einsum("pl,pla,pl->pla", rho, J, r)
        if has_patch:
            R_own, t_own = R_seen[:, patch_owner], seen[..., :3, 3][:, patch_owner]  # each point's own sensor
            qp = np.einsum("pmba,pmb->pma", R_own, extra[None] - t_own)
            _, idx = surface.tree.query(qp.reshape(-1, 3))
            cp, mp = surface.points[idx].reshape(qp.shape), surface.normals[idx].reshape(qp.shape)
            rp = np.sum(mp * (qp - cp), axis=-1)
            Jp = np.concatenate([-mp, np.cross(mp, qp)], axis=-1)
            rhop = extra_w / (1.0 + (rp / _ROBUST_DISTANCE) ** 2)
            # Each point's rows first, then summed onto its sensor's (one-hot owners): the same products and sums
            # in the same order as one einsum over (p, m, l, a, b), three times faster.
            B += np.einsum("ml,pmab->plab", owners, (rhop[..., None, None] * Jp[..., :, None]) * Jp[..., None, :])
            g += np.einsum("ml,pma->pla", owners, (rhop[..., None] * Jp) * rp[..., None])
        if has_free:
            R_own = np.einsum("fl,plab->pfab", free_owned, R_seen)
            t_own = np.einsum("fl,pla->pfa", free_owned, seen[..., :3, 3])
            r_f, J_f, active = free_rows(np.einsum("pfba,pfb->pfa", R_own, free[None] - t_own), surface, free_margin)
            rho_f = _free_weights(r_f, active, free_w)
            B += np.einsum("pf,fl,pfa,pfb->plab", rho_f, free_owned, J_f, J_f)
            g += np.einsum("pf,fl,pfa,pf->pla", rho_f, free_owned, J_f, r_f)
        if w > 0:
            r_n, J_n, rho_n = _normal_rows(u, m, w)
            B[..., 3:, 3:] += np.einsum("pl,plia,plib->plab", rho_n, J_n, J_n)
            g[..., 3:] += np.einsum("pl,plia,pli->pla", rho_n, J_n, r_n)
        # The sensors' priors: G zeta = (a_scale (v - [q]x omega), b_scale omega).
        G = np.zeros((n_poses, n_sensors, 6, 6))
        G[..., :3, :3] = a_scale * np.eye(3)
        G[..., :3, 3:] = -a_scale * skew(q.reshape(-1, 3)).reshape(n_poses, n_sensors, 3, 3)
        G[..., 3:, 3:] = b_scale * np.eye(3)
        sensor_prior = np.einsum("plia,plib->plab", G, G)
        H = np.zeros((n_poses, dim, dim))
        rhs = np.zeros((n_poses, dim))
        H[:, :6, :6] = B.sum(axis=1) + prior
        rhs[:, :6] = g.sum(axis=1) + moved @ prior
        for i in range(n_sensors):
            block = slice(6 + 6 * i, 12 + 6 * i)
            H[:, :6, block] = B[:, i]
            H[:, block, :6] = B[:, i]
            H[:, block, block] = B[:, i] + sensor_prior[:, i]
            rhs[:, block] = g[:, i] + np.einsum("pab,pb->pa", sensor_prior[:, i], zeta[:, i])
        step = _clip_step(-np.linalg.solve(H, rhs[..., None])[..., 0].reshape(n_poses, 1 + n_sensors, 6))
        moved += step[:, 0]
        zeta += step[:, 1:]
        T = T @ make_pose(rotvec_to_rotmat(step[:, 0, 3:]), step[:, 0, :3])
        seen = T[:, None] @ make_pose(rotvec_to_rotmat(zeta[..., 3:].reshape(-1, 3)),
                                      zeta[..., :3].reshape(-1, 3)).reshape(n_poses, n_sensors, 4, 4)
    return T, seen


def sensor_corrections_cost(poses: np.ndarray, seen: np.ndarray, sensor_points: np.ndarray, sigma_contact: float,
                            sigma_angle: float) -> np.ndarray:
    """How unlikely the sensor corrections of ``refine_poses_and_sensors`` are: poses (P, 4, 4), seen (P, L, 4, 4),
    sensor_points (L, 3) world -> (P,) the mean over sensors of the squared Mahalanobis norm of the correction
    (its shift of the contact point over ``sigma_contact`` m, its turn over ``sigma_angle`` rad); 0 for none."""
    correction = np.linalg.inv(np.asarray(poses, dtype=np.float64))[:, None] @ seen  # poses^-1 seen = exp(zeta)
    omega = rotmat_to_rotvec(correction[..., :3, :3].reshape(-1, 3, 3)).reshape(correction.shape[:2] + (3,))
    q, _ = _local(np.asarray(seen, dtype=np.float64), np.asarray(sensor_points, dtype=np.float64).reshape(-1, 3),
                  np.zeros_like(np.asarray(sensor_points, dtype=np.float64)).reshape(-1, 3))
    shift = correction[..., :3, 3] + np.cross(omega, q)
    return (np.sum(shift**2, axis=-1) / sigma_contact**2 + np.sum(omega**2, axis=-1) / sigma_angle**2).mean(axis=1)
