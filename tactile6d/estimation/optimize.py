"""Pose hypotheses from tuples of database points (docs/design.md, The method).

A tuple j pairs each sensor's contact point ``s_i`` (world, m) with a database point ``p_ij`` (object
frame, m). A pose ``T = [R, t]`` (``T_world_object``) is fitted to the loss of the paper's reference
code, the mean of plain (not squared) distances::

    E(T) = 1/L sum_i || s_i - (R p_ij + t) ||

Two solvers:

``gd`` (faithful): the paper's gradient descent on xi = (t, omega), T = [exp(omega^), t],
xi <- xi - K dE/dxi with K = diag(gain_t I3, gain_r I3), k_max steps, from one uniformly random
rotation per tuple and 15 translations (the centroid of the sensor points, plus ``offset`` along
+-x, +-y, +-z and the 8 cube corners (+-1, +-1, +-1) * offset): 15 poses per tuple. JAX, jit-compiled,
vmapped over poses, split across JAX's CPU devices when there are several (``use_cpu_devices``).

``fast``: closed form, then iteratively reweighted least squares. For L >= 3 the Kabsch fit of the
squared loss starts, and each IRLS step solves a weighted Kabsch problem with weights 1 / ||r_i||;
this is a majorise-minimise scheme for the sum of distances, so E never increases. The minimum does
not depend on the start, so one pose per tuple replaces the 15. For L < 3 the rotation is not
determined: the tuple's random rotation R0 is kept and only corrected as little as needed, which
reaches the loss's lower bound exactly (L = 1: t = s - R0 p, E = 0; L = 2: rotate R0 by the smallest
rotation that aligns R0 (p_2 - p_1) with s_2 - s_1, centre the residuals, E = | ||s_2 - s_1|| -
||p_2 - p_1|| | / 2, the least any pose can reach by the triangle inequality). So the random rotation
keeps its role: one hypothesis per tuple, spread over the rotations the contacts allow.

Orientation-aware fast solver (``optimize.normal_weight`` lambda > 0, m/rad; not in the paper): each
sensor's contact normal m_i (world, its -x axis) should be the rotated database normal R n_ij, so the
loss gains a term of plain distances between unit vectors::

    E_n(T) = 1/L sum_i || s_i - (R p_ij + t) || + lambda/L sum_i || m_i - R n_ij ||

and the IRLS solves weighted Kabsch problems whose cross-covariance adds lambda-weighted normal
pairs (translation from the weighted point centroids as before). For L = 2 the normals fix the
rotation the points leave free (start: the unit-weight combined Kabsch); for L = 1 the random
rotation is turned by the smallest rotation that carries R0 n onto m, t = s - R p. The reported loss
is E_n, so the ranking prefers hypotheses whose normals agree.

Contacts known only to a noise (``noise`` = (sigma_d m, sigma_a rad)): sensor poses that are off move every
contact by about sigma_d. The IRLS weights then become 1 / max(||r_i||, sigma_d) (and lambda / max(||m_i -
R n_i||, sigma_a)), so residuals below the noise are fitted in least squares, as Gaussian noise asks, instead
of one of them being pulled to zero as the plain distances do; residuals above it keep the robust weight.
This minimises the Huber-like sum of rho(r) = r^2 / (2 sigma) + sigma / 2 below sigma, r above; the loss
reported is E (or E_n) all the same, so the ranking's scale does not change. ``optimize.noise_floor`` takes
the noise from ``sensors.pose_sigma_*``; it is off by default (measured no gain: docs/real_sensors.md).

Both return ``PoseHypotheses``: poses (P, 4, 4) float64, losses (P,) m, tuple_index (P,).

``fast`` is the default: on synthetic scenes its loss was never above gd's, and it is much faster
(figures: docs/speed.md). gd does not settle on the minimum: the gradient of a plain distance has unit
norm, so each step moves t by up to gain_t (1 cm), and even with exact correspondences and a start near
the answer gd ends in a limit cycle, in float32 and float64 alike.

``optimize`` is step 3 of an estimate, as the estimator and the optimize stage call it: each selected tuple
gets one random rotation and one or more starting translations, refined so that the tuple's database
points land on the sensors' contact points (the paper's gradient descent, solver ``gd``, or the
closed-form + IRLS solver, ``fast``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import (
    covariances_to_rotations,
    make_pose,
    random_rotations,
    rotmat_to_rotvec,
    rotvec_to_rotmat,
    xi_to_pose,
)
from tactile6d.core.settings import OptimizeSettings, SensorSettings
from tactile6d.perception.contacts import Contacts

# The 14 directions of the paper's translation hypotheses: 6 face centres, then 8 cube corners
# (unnormalised, so the corners are sqrt(3) * offset away).
_FACES = np.concatenate([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]
_CORNERS = np.array([[x, y, z] for x in (1, -1) for y in (1, -1) for z in (1, -1)], dtype=np.float64)
TRANSLATION_DIRECTIONS = np.concatenate([np.zeros((1, 3)), _FACES, _CORNERS])

# IRLS weights are 1 / max(||r||, this) (m): a residual already under a micrometre is treated as
# fitted, which keeps the weights finite when a correspondence is exact.
_IRLS_FLOOR = 1e-7


@dataclass(frozen=True)
class PoseHypotheses:
    """poses (P, 4, 4) float64 ``T_world_object``; losses (P,) E in metres; tuple_index (P,) int64."""

    poses: np.ndarray
    losses: np.ndarray
    tuple_index: np.ndarray


def initial_translations(sensor_points: np.ndarray, offset: float) -> np.ndarray:
    """sensor_points (L, 3) m -> (15, 3): the centroid, then centroid + offset * each direction."""
    centroid = np.asarray(sensor_points, dtype=np.float64).mean(axis=0)
    return centroid + offset * TRANSLATION_DIRECTIONS


def poses_to_losses(poses: np.ndarray, object_points: np.ndarray, sensor_points: np.ndarray) -> np.ndarray:
    """The loss E, in NumPy float64.

    poses (P, 4, 4), object_points (P, L, 3) the tuple's database points (object frame),
    sensor_points (L, 3) (world) -> (P,) metres.
    """
    poses = np.asarray(poses, dtype=np.float64)
    moved = np.einsum("pab,plb->pla", poses[:, :3, :3], object_points) + poses[:, None, :3, 3]
    return np.linalg.norm(sensor_points[None] - moved, axis=-1).mean(axis=-1)


def _check(object_points: np.ndarray, sensor_points: np.ndarray):
    p = np.asarray(object_points, dtype=np.float64)
    s = np.asarray(sensor_points, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 3 or s.shape[0] < 1:
        raise InputError(f"sensor points must be (L, 3) with L >= 1, got {s.shape}")
    if p.ndim != 3 or p.shape[1:] != s.shape:
        raise InputError(f"tuple points must be (N, {s.shape[0]}, 3), got {p.shape}")
    return p, s


# --- fast solver ---------------------------------------------------------------------------------


def weighted_kabsch(
    object_points: np.ndarray,
    sensor_points: np.ndarray,
    weights: np.ndarray,
    directions: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The pose minimising sum_i w_i ||s_i - (R p_i + t)||^2 (+ sum_i v_i ||m_i - R n_i||^2).

    object_points (N, L, 3), sensor_points (L, 3) or (N, L, 3), weights (N, L) >= 0 -> (N, 4, 4).
    directions: optional (n (N, L, 3) object-frame unit vectors, m (L, 3) or (N, L, 3) world unit
    vectors, v (N, L) >= 0 weights), which only enter the rotation. Without them L >= 3
    non-collinear points; the rotation is ``geometry.covariances_to_rotations`` of the weighted cross-covariance (never a reflection).
    """
    total = weights.sum(axis=1, keepdims=True)
    w = weights / total
    s = np.broadcast_to(sensor_points, object_points.shape)
    p_mean = np.einsum("nl,nla->na", w, object_points)
    s_mean = np.einsum("nl,nla->na", w, s)
    cov = np.einsum("nl,nla,nlb->nab", w, s - s_mean[:, None], object_points - p_mean[:, None])
    if directions is not None:
        n_obj, m_world, v = directions
        m_world = np.broadcast_to(m_world, n_obj.shape)
        cov = cov + np.einsum("nl,nla,nlb->nab", v / total, m_world, n_obj)
    R = covariances_to_rotations(cov)
    return make_pose(R, s_mean - np.einsum("nab,nb->na", R, p_mean))


def _align_two(object_points: np.ndarray, sensor_points: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """L = 2: the pose nearest ``rotations`` (N, 3, 3) reaching the loss's lower bound -> (N, 4, 4)."""
    R = _minimal_turn(rotations, object_points[:, 1] - object_points[:, 0], sensor_points[1] - sensor_points[0])
    t = sensor_points.mean(axis=0) - np.einsum("nab,nb->na", R, object_points.mean(axis=1))
    return make_pose(R, t)


def _minimal_turn(rotations: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """rotations (N, 3, 3), u (N, 3) object-frame vectors, v (N, 3) world vectors -> (N, 3, 3): each
    rotation turned by the smallest rotation carrying R u onto v (a half turn about a perpendicular
    axis when antiparallel)."""
    u = np.einsum("nab,nb->na", rotations, u)
    v = np.broadcast_to(v, u.shape)
    u = u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
    axis = np.cross(u, v)
    sin, cos = np.linalg.norm(axis, axis=1), np.sum(u * v, axis=1)
    perpendicular = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    axis = np.where((sin < 1e-12)[:, None] & (cos < 0)[:, None], perpendicular, axis)
    norm = np.linalg.norm(axis, axis=1, keepdims=True)
    rotvec = np.where(norm > 1e-300, axis / np.maximum(norm, 1e-300), 0.0) * np.arctan2(sin, cos)[:, None]
    return rotvec_to_rotmat(rotvec) @ rotations


def normal_losses(poses: np.ndarray, object_normals: np.ndarray, sensor_normals: np.ndarray) -> np.ndarray:
    """poses (P, 4, 4), object_normals (P, L, 3), sensor_normals (L, 3) -> (P,) 1/L sum_i ||m_i - R n_i||."""
    turned = np.einsum("pab,plb->pla", np.asarray(poses)[:, :3, :3], object_normals)
    return np.linalg.norm(sensor_normals[None] - turned, axis=-1).mean(axis=-1)


def fit_fast(
    object_points: np.ndarray,
    sensor_points: np.ndarray,
    rotations: np.ndarray,
    n_irls: int,
    normals: tuple[np.ndarray, np.ndarray] | None = None,
    normal_weight: float = 0.0,
    noise: tuple[float, float] = (0.0, 0.0),
) -> PoseHypotheses:
    """The fast solver (module docstring), one pose per tuple.

    object_points (N, L, 3) object frame, sensor_points (L, 3) world, rotations (N, 3, 3) the tuples'
    random rotations (used for L < 3 only, L = 1 with normals), n_irls IRLS steps (L >= 3, or L = 2
    with normals) -> PoseHypotheses with P = N. normals: (object normals (N, L, 3), sensor contact
    normals (L, 3)) and normal_weight lambda (m/rad) > 0 switch on the orientation-aware loss E_n. noise:
    (m, rad) the contacts' expected error, below which residuals are fitted in least squares.
    """
    p, s = _check(object_points, sensor_points)
    floor_d, floor_a = (max(float(x), _IRLS_FLOOR) for x in noise)
    n, n_sensors = p.shape[:2]
    rotations = np.asarray(rotations, dtype=np.float64)
    if normals is not None and normal_weight > 0:
        return _fit_fast_normals(p, s, rotations, n_irls, normals, float(normal_weight), floor_d, floor_a)
    if n_sensors == 1:
        poses = make_pose(rotations, s[0] - np.einsum("nab,nb->na", rotations, p[:, 0]))
    elif n_sensors == 2:
        poses = _align_two(p, s, rotations)
    else:
        poses = weighted_kabsch(p, s, np.ones((n, n_sensors)))
        for _ in range(n_irls):
            residual = np.linalg.norm(s[None] - (np.einsum("nab,nlb->nla", poses[:, :3, :3], p) + poses[:, None, :3, 3]), axis=-1)
            poses = weighted_kabsch(p, s, 1.0 / np.maximum(residual, floor_d))
    return PoseHypotheses(poses, poses_to_losses(poses, p, s), np.arange(n))


def _fit_fast_normals(p, s, rotations, n_irls, normals, lam, floor_d, floor_a) -> PoseHypotheses:
    """fit_fast with the normal term (module docstring); floor_d (m), floor_a (rad): the IRLS floors."""
    n_obj = np.asarray(normals[0], dtype=np.float64)
    m = np.asarray(normals[1], dtype=np.float64)
    n, n_sensors = p.shape[:2]
    if n_obj.shape != p.shape or m.shape != s.shape:
        raise InputError(f"normals must be (N, L, 3) and (L, 3) like the points, got {n_obj.shape}, {m.shape}")
    if n_sensors == 1:
        R = _minimal_turn(rotations, n_obj[:, 0], np.broadcast_to(m[0], (n, 3)))
        poses = make_pose(R, s[0] - np.einsum("nab,nb->na", R, p[:, 0]))
    else:
        ones = np.ones((n, n_sensors))
        poses = weighted_kabsch(p, s, ones, (n_obj, m, lam * ones))
        for _ in range(n_irls):
            residual = np.linalg.norm(s[None] - (np.einsum("nab,nlb->nla", poses[:, :3, :3], p) + poses[:, None, :3, 3]), axis=-1)
            turned = np.linalg.norm(m[None] - np.einsum("nab,nlb->nla", poses[:, :3, :3], n_obj), axis=-1)
            # The normal term's IRLS weight lambda / ||m - R n|| (a chord between unit vectors, about the angle
            # between them for small angles, floored at the normals' expected error).
            poses = weighted_kabsch(p, s, 1.0 / np.maximum(residual, floor_d),
                                    (n_obj, m, lam / np.maximum(turned, floor_a)))
    losses = poses_to_losses(poses, p, s) + lam * normal_losses(poses, n_obj, m)
    return PoseHypotheses(poses, losses, np.arange(n))


# --- faithful solver (JAX) -----------------------------------------------------------------------


def use_cpu_devices(n: int) -> int:
    """Ask JAX for ``n`` CPU devices, so that ``fit_gd`` splits its batch over n cores.

    Works only before JAX has run anything in this process (JAX's rule); call it at program start.
    Returns the number of CPU devices in effect, which is the old one when it was too late.
    """
    import jax

    try:
        jax.config.update("jax_num_cpu_devices", int(n))
    except RuntimeError:
        pass
    return jax.local_device_count()


def use_cpu_devices_for(solver: str, cpu_devices: int) -> None:
    """At program start: ``use_cpu_devices(cpu_devices)`` when the ``gd`` solver will run (the ``fast``
    solver does not use JAX). The device count is process-wide, so programs set it, not the library."""
    if solver == "gd":
        use_cpu_devices(cpu_devices)


GD_CHUNK = 8192  # poses per call of the compiled descent, for batches larger than that (fit_gd)


def gd_batch_size(n: int, multiple: int) -> int:
    """The batch size ``fit_gd`` pads n poses to: the least size >= n that is a multiple of ``multiple``
    and of the form c * 2^k with c in 16..31 (at most 6.25 % more than n, beyond the multiple), so that
    the tuple counts of an octave share 16 compiled programs."""
    size = max(int(n), 1)
    step = 2 ** max(0, size.bit_length() - 5)  # sizes c * 2^k with 16 <= c <= 31 are 2^k apart
    size = -(-size // step) * step
    return -(-size // multiple) * multiple


@functools.lru_cache(maxsize=8)
def _gd_program(n_steps: int, gain_t: float, gain_r: float):
    """A jitted function (xi (6, B), p (L, 3, B), s (L, 3)) -> xi after n_steps of the paper's GD.

    Arrays are laid out component-major ("structure of arrays"): every quantity is a (B,) vector, so
    that XLA fuses the whole step into one elementwise loop over the batch instead of B tiny 3x3
    products.
    """
    import jax
    import jax.numpy as jnp

    # No division by a square root, anywhere in the program or its gradient: XLA rewrites x / sqrt(y) as
    # x * rsqrt(y) and compiles rsqrt on the CPU from the approximate vrsqrtps and two Newton steps, whose
    # last bit depends on the CPU's vendor (docs/reproducibility.md, Across machines). JAX's own derivative
    # of sqrt is 0.5 / sqrt(x); this one is 0.5 * sqrt(x) / x, a correctly rounded square root and divisions.
    @jax.custom_jvp
    def sqrt(x):
        return jnp.sqrt(x)

    @sqrt.defjvp
    def _sqrt_jvp(primals, tangents):
        (x,), (dx,) = primals, tangents
        y = jnp.sqrt(x)
        return y, dx * (0.5 * y / x)

    def rotation(w0, w1, w2):
        # R = I + a K + b K^2 with K^2 = w w^T - theta^2 I (Rodrigues), series near 0 where the closed
        # forms lose precision; the double where keeps the gradient finite at omega = 0. sin(theta) / theta
        # is written sin(theta) theta / theta^2, for the reason above.
        theta2 = w0 * w0 + w1 * w1 + w2 * w2
        small = theta2 < 1e-6
        safe = jnp.where(small, 1.0, theta2)
        theta = sqrt(safe)
        a = jnp.where(small, 1.0 - theta2 / 6.0, jnp.sin(theta) * theta / safe)
        b = jnp.where(small, 0.5 - theta2 / 24.0, (1.0 - jnp.cos(theta)) / safe)
        return (
            (1.0 + b * (w0 * w0 - theta2), -a * w2 + b * w0 * w1, a * w1 + b * w0 * w2),
            (a * w2 + b * w0 * w1, 1.0 + b * (w1 * w1 - theta2), -a * w0 + b * w1 * w2),
            (-a * w1 + b * w0 * w2, a * w0 + b * w1 * w2, 1.0 + b * (w2 * w2 - theta2)),
        )

    def total_loss(xi, p, s):
        # Sum over the batch of each pose's E: poses are independent, so its gradient with respect to
        # xi (6, B) is every pose's own gradient.
        R = rotation(xi[3], xi[4], xi[5])
        total = 0.0
        for i in range(p.shape[0]):
            r2 = 0.0
            for a in range(3):
                r = s[i, a] - (R[a][0] * p[i, 0] + R[a][1] * p[i, 1] + R[a][2] * p[i, 2] + xi[a])
                r2 = r2 + r * r
            # sqrt has an infinite derivative at 0: an exactly fitted point contributes no gradient.
            positive = r2 > 0
            total = total + jnp.where(positive, sqrt(jnp.where(positive, r2, 1.0)), 0.0)
        return jnp.sum(total) / p.shape[0]

    gains = (gain_t,) * 3 + (gain_r,) * 3
    gradient = jax.grad(total_loss)

    def run(xi, p, s):
        def step(_, x):
            return tuple(xk - jnp.asarray(gk, xk.dtype) * dk for xk, gk, dk in zip(x, gains, gradient(x, p, s)))

        # The loop carries xi as six (B,) vectors, not one (6, B) array: XLA then fuses a step into one
        # multi-output loop that computes the rotation and residuals once per pose for all six
        # components. A (6, B) carry became a concatenation that re-evaluated them for each component
        # (4.6x slower at 75000 poses on a 2-core AMD EPYC).
        return jnp.stack(jax.lax.fori_loop(0, n_steps, step, tuple(xi[k] for k in range(6))))

    return jax.jit(run)


def fit_gd(
    object_points: np.ndarray,
    sensor_points: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    n_steps: int,
    gain_t: float,
    gain_r: float,
    precision: str = "float32",
) -> PoseHypotheses:
    """The faithful solver: the paper's GD from every (tuple rotation, start translation) pair.

    object_points (N, L, 3) object frame, sensor_points (L, 3) world, rotations (N, 3, 3) one random
    rotation per tuple, translations (K, 3) start translations (``initial_translations``), n_steps
    (k_max), gains of K, precision 'float32' or 'float64' -> PoseHypotheses with P = K * N, ordered
    translation-major (pose k * N + j starts from translation k and tuple j). The losses are
    recomputed in float64 from the final float64 poses.
    """
    import jax
    import jax.numpy as jnp

    p, s = _check(object_points, sensor_points)
    n = p.shape[0]
    translations = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    if precision not in ("float32", "float64"):
        raise InputError(f"precision must be float32 or float64, got {precision!r}")
    omega = rotmat_to_rotvec(np.asarray(rotations, dtype=np.float64))
    xi0 = np.concatenate(
        [np.repeat(translations, n, axis=0), np.tile(omega, (translations.shape[0], 1))], axis=1
    )
    p_all = np.tile(p, (translations.shape[0], 1, 1))

    with jax.enable_x64(precision == "float64"):
        dtype = jnp.float64 if precision == "float64" else jnp.float32
        devices = jax.devices()
        # Pad the batch (with copies of the first pose, dropped below) and shard it along the batch axis;
        # XLA then runs each device's share of the (independent) poses on its own core. A share's length is
        # a multiple of 64, since one of odd length ran XLA's loop unvectorised (2.9x slower at 50685 poses).
        # A batch of more than GD_CHUNK poses runs in chunks of GD_CHUNK, smaller ones at one of few sizes
        # (``gd_batch_size``): either way the next estimate reuses the compiled program instead of compiling
        # one for its own tuple count (about 1 s, a third of a full-load descent).
        unit = 64 * len(devices)
        total = xi0.shape[0]
        chunk = gd_batch_size(total, unit)
        if chunk > GD_CHUNK:
            chunk = -(-GD_CHUNK // unit) * unit
        pad = -total % chunk
        xi = np.concatenate([xi0, np.repeat(xi0[:1], pad, axis=0)]).T
        pts = np.moveaxis(np.concatenate([p_all, np.repeat(p_all[:1], pad, axis=0)]), 0, -1)
        program = _gd_program(int(n_steps), float(gain_t), float(gain_r))
        s_in = jnp.asarray(s, dtype)
        parts = []
        for start in range(0, total + pad, chunk):
            xi_in, p_in = jnp.asarray(xi[:, start : start + chunk], dtype), jnp.asarray(pts[..., start : start + chunk], dtype)
            if len(devices) > 1:
                mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
                xi_in = jax.device_put(xi_in, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(None, "batch")))
                p_in = jax.device_put(p_in, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(None, None, "batch")))
            parts.append(np.asarray(program(xi_in, p_in, s_in), dtype=np.float64))
        xi_out = np.concatenate(parts, axis=1).T[:total]
    poses = xi_to_pose(xi_out)
    tuple_index = np.tile(np.arange(n), translations.shape[0])
    return PoseHypotheses(poses, poses_to_losses(poses, p_all, s), tuple_index)


# --- entry point ---------------------------------------------------------------------------------


def tuples_to_poses(
    points: np.ndarray,
    sensor_points: np.ndarray,
    tuples: np.ndarray,
    solver: str,
    rng: np.random.Generator,
    n_steps: int = 700,
    gain_t: float = 0.01,
    gain_r: float = 1.0,
    offset: float = 0.2,
    n_translations: int = 15,
    n_irls: int = 5,
    precision: str = "float32",
    normals: np.ndarray | None = None,
    sensor_normals: np.ndarray | None = None,
    normal_weight: float = 0.0,
    noise: tuple[float, float] = (0.0, 0.0),
) -> PoseHypotheses:
    """Pose hypotheses for the selected tuples.

    points (M, 3) database points (object frame, m), sensor_points (L, 3) sensor contact points (world,
    m), tuples (N, L) int indices into points, solver 'fast' or 'gd', rng draws one uniformly random
    rotation per tuple. gd uses n_steps, gain_t, gain_r, offset (m), the first n_translations (1-15)
    of ``initial_translations`` and precision; fast uses n_irls and, when normal_weight > 0, normals
    (M, 3) the database normals and sensor_normals (L, 3) the sensors' contact normals (world), and
    noise (m, rad): the contacts' expected error, the IRLS floor (module docstring; gd ignores it).
    """
    tuples = np.asarray(tuples)
    if tuples.ndim != 2 or tuples.shape[0] == 0:
        raise InputError(f"need a non-empty (N, L) array of tuples, got shape {tuples.shape}")
    object_points = np.asarray(points, dtype=np.float64)[tuples]
    rotations = random_rotations(tuples.shape[0], rng)
    if solver == "fast":
        if normal_weight > 0:
            if normals is None or sensor_normals is None:
                raise InputError("optimize.normal_weight > 0 needs the database and sensor normals")
            pair = (np.asarray(normals, dtype=np.float64)[tuples], np.asarray(sensor_normals, dtype=np.float64))
            return fit_fast(object_points, sensor_points, rotations, n_irls, pair, normal_weight, noise)
        return fit_fast(object_points, sensor_points, rotations, n_irls, noise=noise)
    if solver == "gd":
        if not 1 <= n_translations <= len(TRANSLATION_DIRECTIONS):
            raise InputError(f"n_translations must be 1..{len(TRANSLATION_DIRECTIONS)}, got {n_translations}")
        translations = initial_translations(sensor_points, offset)[:n_translations]
        return fit_gd(object_points, sensor_points, rotations, translations, n_steps, gain_t, gain_r, precision)
    raise InputError(f"unknown solver {solver!r} (fast or gd)")


def optimize(
    points: np.ndarray,
    contacts: Contacts,
    tuples: np.ndarray,
    settings: OptimizeSettings,
    normals: np.ndarray | None = None,
    *,
    sensors: SensorSettings,
) -> PoseHypotheses:
    """Pose hypotheses for the tuples: (P, 4, 4) poses, (P,) losses (m), tuple index.

    contacts: the L sensors' contact points and normals (``tactile6d.perception.contacts``); normals (M, 3): the database
    normals, needed when ``optimize.normal_weight`` > 0; sensors: how far the sensor poses may be off, whose
    contact error (``SensorSettings.contact_sigma``, ``angle_sigma``) is the fast solver's noise floor when
    ``optimize.noise_floor`` is on. tuples (T, L) as ``select.select`` gives them: a sensor the object does not
    touch (``contacts.touching``, its column -1) is left out of the fit.
    """
    on = np.flatnonzero(contacts.touching)
    if len(on) < contacts.points.shape[0]:
        contacts, tuples = contacts.of_sensors(on), np.asarray(tuples)[:, on]
    return tuples_to_poses(
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
