"""Rotations and rigid transforms, in NumPy float64.

Conventions (docs/design.md, Conventions):
- A pose is a 4x4 homogeneous matrix named ``T_<to>_<from>``: ``T_world_object`` maps object-frame
  points into the world frame.
- A rotation vector ``rotvec`` (3,) is ``axis * angle``; ``axis_angle`` keeps them apart (unit axis,
  angle in [0, pi]), as in the paper's pose text format ``x y z ax ay az angle``.
- ``xi = (t, omega)`` (6,) is the paper's pose parametrisation ``T = [exp(omega^), t]``; the true
  SE(3) exponential, whose translation part is coupled with the rotation, is ``se3_exp``.

Every function accepts leading batch dimensions ``(...)``.
"""

from __future__ import annotations

import numpy as np

# Below this angle, series expansions replace the closed forms (their 1/theta terms lose precision).
_SMALL_ANGLE = 1e-6


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3): the matrix ``v^`` with ``v^ @ w == cross(v, w)``."""
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotvec_to_rotmat(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3): the SO(3) exponential (Rodrigues' formula)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    K = skew(rotvec)
    return np.eye(3) + a * K + b * (K @ K)


def rotmat_to_rotvec(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3): the SO(3) logarithm, angle in [0, pi].

    Near pi the antisymmetric part vanishes, so the axis is read from the symmetric part instead.
    """
    R = np.asarray(R, dtype=np.float64)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    vee = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1
    )
    sin = np.sin(theta)
    generic = np.where(theta[..., None] < _SMALL_ANGLE, 0.5 + theta[..., None] ** 2 / 12.0, 0.0)
    regular = theta >= _SMALL_ANGLE
    factor = np.where(regular, theta / (2.0 * np.where(regular, sin, 1.0)), 0.0)
    out = np.where(theta[..., None] < _SMALL_ANGLE, generic * vee, factor[..., None] * vee)

    near_pi = theta > np.pi - 1e-3
    if np.any(near_pi):
        # sym(R) = cos I + (1 - cos) a a^T exactly: take the column of a a^T of largest norm as the
        # axis, then fix its sign with the (small but informative) antisymmetric part.
        Rn, cn = R[near_pi], cos[near_pi][:, None, None]
        B = ((Rn + np.swapaxes(Rn, -1, -2)) / 2.0 - cn * np.eye(3)) / (1.0 - cn)
        cols = np.linalg.norm(B, axis=-2)
        k = np.argmax(cols, axis=-1)
        axis = B[np.arange(len(k)), :, k] / cols[np.arange(len(k)), k][:, None]
        sign = np.sign(np.sum(axis * vee[near_pi], axis=-1))
        axis = axis * np.where(sign == 0, 1.0, sign)[:, None]
        out[near_pi] = axis * theta[near_pi][:, None]
    return out


def axis_angle_to_rotmat(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """axis (..., 3), angle (...) -> (..., 3, 3). The axis is normalised here."""
    axis = np.asarray(axis, dtype=np.float64)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("axis_angle_to_rotmat: zero-length rotation axis")
    return rotvec_to_rotmat(axis / norm * np.asarray(angle, dtype=np.float64)[..., None])


def rotmat_to_axis_angle(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3, 3) -> unit axis (..., 3), angle (...) in [0, pi]; the identity gives axis (1, 0, 0)."""
    rotvec = rotmat_to_rotvec(R)
    angle = np.linalg.norm(rotvec, axis=-1)
    axis = np.where(angle[..., None] > 0, rotvec / np.where(angle > 0, angle, 1.0)[..., None], [1.0, 0, 0])
    return axis, angle


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """R (..., 3, 3), t (..., 3) -> T (..., 4, 4)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) -> (..., 4, 4): T^-1 of a rigid transform, without a general matrix inverse."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_pose(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """T (..., 4, 4), points (..., N, 3) -> (..., N, 3): ``R p + t`` for each point."""
    T = np.asarray(T, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    return points @ np.swapaxes(T[..., :3, :3], -1, -2) + T[..., None, :3, 3]


def xi_to_pose(xi: np.ndarray) -> np.ndarray:
    """(..., 6) -> (..., 4, 4): the paper's parametrisation ``xi = (t, omega)``, ``T = [exp(omega^), t]``."""
    xi = np.asarray(xi, dtype=np.float64)
    return make_pose(rotvec_to_rotmat(xi[..., 3:]), xi[..., :3])


def pose_to_xi(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) -> (..., 6): inverse of ``xi_to_pose``."""
    T = np.asarray(T, dtype=np.float64)
    return np.concatenate([T[..., :3, 3], rotmat_to_rotvec(T[..., :3, :3])], axis=-1)


def _so3_left_jacobian(omega: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3): V(omega) = I + (1 - cos)/theta^2 K + (theta - sin)/theta^3 K^2."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    c = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    K = skew(omega)
    return np.eye(3) + b * K + c * (K @ K)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """(..., 6) twist ``(v, omega)`` -> (..., 4, 4): the SE(3) exponential."""
    xi = np.asarray(xi, dtype=np.float64)
    omega = xi[..., 3:]
    t = (_so3_left_jacobian(omega) @ xi[..., :3, None])[..., 0]
    return make_pose(rotvec_to_rotmat(omega), t)


def se3_log(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) -> (..., 6) twist ``(v, omega)``: the SE(3) logarithm."""
    T = np.asarray(T, dtype=np.float64)
    omega = rotmat_to_rotvec(T[..., :3, :3])
    v = np.linalg.solve(_so3_left_jacobian(omega), T[..., :3, 3:4])[..., 0]
    return np.concatenate([v, omega], axis=-1)


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """n uniformly distributed (Haar) rotations, (n, 3, 3), from normalised 4D Gaussian quaternions."""
    q = rng.standard_normal((n, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return quaternion_to_rotmat(q)


def quaternion_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternion ``(x, y, z, w)`` (normalised here) -> (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) x2 -> (...): the angle of ``R_a^T R_b`` in radians, in [0, pi]."""
    R = np.swapaxes(np.asarray(R_a, dtype=np.float64), -1, -2) @ np.asarray(R_b, dtype=np.float64)
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))


def is_rotation(R: np.ndarray, atol: float = 1e-6) -> np.ndarray:
    """(..., 3, 3) -> (...) bool: orthonormal with determinant +1, within ``atol``."""
    R = np.asarray(R, dtype=np.float64)
    ortho = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2)) < atol
    return ortho & (np.abs(np.linalg.det(R) - 1.0) < atol) & np.all(np.isfinite(R), axis=(-1, -2))


def matrix_to_nearest_rotation(M: np.ndarray) -> np.ndarray:
    """(..., 3, 3) -> (..., 3, 3): the rotation nearest M in the Frobenius norm (the special orthogonal
    Procrustes problem): ``U diag(1, 1, det(U V^T)) V^T`` of M's SVD ``U S V^T``. For a rotation rounded or
    accumulated in low precision, the rotation it was meant to be."""
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    d = np.sign(np.linalg.det(U @ Vt))
    return (U * np.stack([np.ones_like(d), np.ones_like(d), d], axis=-1)[..., None, :]) @ Vt


def symmetric_to_eigen(B: np.ndarray, max_sweeps: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-decomposition of symmetric 3 x 3 matrices by cyclic Jacobi rotations: B (N, 3, 3) ->
    (eigenvalues (N, 3), eigenvectors (N, 3, 3) as columns), unsorted, B ~= V diag(w) V^T.

    Each rotation is a few elementwise operations on (N,) arrays, so a batch of thousands costs about
    as much as a handful of numpy calls, where ``np.linalg.eigh`` and ``svd`` call LAPACK once per
    matrix. Sweeps stop when every off-diagonal entry is below 1e-15 of the trace's scale.
    """
    B = np.asarray(B, dtype=np.float64)
    b = {(i, j): B[:, i, j].copy() for i in range(3) for j in range(i, 3)}
    v = {(i, j): np.full(B.shape[0], float(i == j)) for i in range(3) for j in range(3)}
    scale = np.abs(b[0, 0]) + np.abs(b[1, 1]) + np.abs(b[2, 2])
    for _ in range(max_sweeps):
        if not np.any(np.abs(b[0, 1]) + np.abs(b[0, 2]) + np.abs(b[1, 2]) > 1e-15 * scale):
            break
        for p, q, r in ((0, 1, 2), (0, 2, 1), (1, 2, 0)):
            # The rotation in the (p, q) plane that zeroes b_pq (Numerical Recipes, section 11.1).
            bpq = b[p, q]
            active = bpq != 0.0
            with np.errstate(over="ignore"):  # theta overflows where b_pq is negligible: t -> 0, as it should
                theta = (b[q, q] - b[p, p]) / (2.0 * np.where(active, bpq, 1.0))
                t = np.copysign(1.0, theta) / (np.abs(theta) + np.sqrt(theta * theta + 1.0))
            t = np.where(active, t, 0.0)
            c = 1.0 / np.sqrt(t * t + 1.0)
            s = t * c
            b[p, p], b[q, q], b[p, q] = b[p, p] - t * bpq, b[q, q] + t * bpq, np.zeros_like(bpq)
            rp, rq = (min(r, p), max(r, p)), (min(r, q), max(r, q))
            b[rp], b[rq] = c * b[rp] - s * b[rq], s * b[rp] + c * b[rq]
            for k in range(3):
                v[k, p], v[k, q] = c * v[k, p] - s * v[k, q], s * v[k, p] + c * v[k, q]
    w = np.stack([b[0, 0], b[1, 1], b[2, 2]], axis=1)
    V = np.stack([np.stack([v[k, j] for j in range(3)], axis=1) for k in range(3)], axis=1)
    return w, V


def covariances_to_rotations(cov: np.ndarray) -> np.ndarray:
    """The rotations R maximising trace(R^T H) (Kabsch: H = sum_i w_i s_i p_i^T of centred points,
    R p ~ s): cov (N, 3, 3) -> (N, 3, 3), the same as ``U diag(1, 1, det(U V^T)) V^T`` from
    ``np.linalg.svd(H)`` up to rounding, about 2.5 times faster on large batches.

    With H's right singular vectors v1, v2 (the two largest) and u_k = H v_k / |H v_k|,
    R = u1 v1^T + u2 v2^T + (u1 x u2)(v1 x v2)^T, the one rotation taking v1 to u1 and v2 to u2: a
    reflection never arises and H of rank 2 (three points) needs no special case. The v_k come from
    ``symmetric_to_eigen(H^T H)``, whose squaring costs accuracy where sigma_2 is small: the error in
    R grows like 1e-16 (sigma_1 / sigma_2)^2, so H with sigma_2 < 1e-3 sigma_1 (nearly collinear points,
    where any turn about the line is almost as good) falls back to the SVD.
    """
    cov = np.asarray(cov, dtype=np.float64)
    w, V = symmetric_to_eigen(np.einsum("nab,nac->nbc", cov, cov))
    order = np.argsort(-w, axis=1)
    w_sorted = np.take_along_axis(w, order, axis=1)
    v1 = np.take_along_axis(V, order[:, None, :1], axis=2)[..., 0]
    v2 = np.take_along_axis(V, order[:, None, 1:2], axis=2)[..., 0]
    v2 = v2 - np.sum(v1 * v2, axis=1, keepdims=True) * v1
    v2 /= np.linalg.norm(v2, axis=1, keepdims=True)
    u1 = np.einsum("nab,nb->na", cov, v1)
    n1 = np.linalg.norm(u1, axis=1, keepdims=True)
    u2 = np.einsum("nab,nb->na", cov, v2)
    u2 = u2 - np.sum(u1 * u2, axis=1, keepdims=True) * u1 / np.maximum(n1 * n1, 1e-300)
    n2 = np.linalg.norm(u2, axis=1, keepdims=True)
    degenerate = ~(w_sorted[:, 1] > 1e-6 * w_sorted[:, 0])  # also all-zero and non-finite H
    u1, u2 = u1 / np.maximum(n1, 1e-300), u2 / np.maximum(n2, 1e-300)
    R = (u1[:, :, None] * v1[:, None, :] + u2[:, :, None] * v2[:, None, :]
         + np.cross(u1, u2)[:, :, None] * np.cross(v1, v2)[:, None, :])
    if degenerate.any():
        R[degenerate] = _covariances_to_rotations_svd(cov[degenerate])
    return R


def _covariances_to_rotations_svd(cov: np.ndarray) -> np.ndarray:
    """``covariances_to_rotations`` by the SVD (reference, and the fallback for rank < 2)."""
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    return u @ (np.concatenate([np.ones((len(d), 2)), d[:, None]], axis=1)[:, :, None] * vt)


def orthonormal_frame(x_axis: np.ndarray) -> np.ndarray:
    """(..., 3) unit vectors -> (..., 3, 3) rotations whose first column is ``x_axis``.

    The other two columns are fixed by a deterministic rule, so the same axis always gives the same
    frame: z is the world z (or the world y when x is within 25 deg of +-z) made orthogonal to x, and
    y = z x x.
    """
    x = np.asarray(x_axis, dtype=np.float64)
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    ref = np.where(np.abs(x[..., 2:3]) > 0.9, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
    z = ref - np.sum(ref * x, axis=-1, keepdims=True) * x
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


# --- the paper's pose text format: one pose per line, "x y z ax ay az angle" -----------------------

AXIS_LENGTH_TOL = 1e-3  # |length - 1| of a pose line's rotation axis; the paper's files are within 3e-16


def pose_to_line(T: np.ndarray) -> str:
    """(4, 4) -> ``"x y z ax ay az angle"`` (metres, unit axis, radians)."""
    axis, angle = rotmat_to_axis_angle(np.asarray(T)[:3, :3])
    values = list(np.asarray(T)[:3, 3]) + list(axis) + [float(angle)]
    return " ".join(f"{v:.17g}" for v in values)


def line_to_pose(line: str) -> np.ndarray:
    """``"x y z ax ay az angle"`` -> (4, 4). Raises ValueError naming the problem."""
    fields = line.split()
    if len(fields) != 7:
        raise ValueError(f"expected 7 numbers 'x y z ax ay az angle', got {len(fields)}: {line.strip()!r}")
    try:
        values = np.array([float(f) for f in fields])
    except ValueError as exc:
        raise ValueError(f"not a number in pose line {line.strip()!r}") from exc
    if not np.all(np.isfinite(values)):
        raise ValueError(f"NaN or infinite value in pose line {line.strip()!r}")
    axis = values[3:6]
    length = float(np.linalg.norm(axis))
    if length < 1e-12:
        if abs(values[6]) > 1e-12:
            raise ValueError(f"zero rotation axis with a non-zero angle in pose line {line.strip()!r}")
        axis = np.array([1.0, 0.0, 0.0])
    elif abs(length - 1.0) > AXIS_LENGTH_TOL:
        # Normalising it quietly would hide a file in another format (a rotation vector, degrees, a quaternion).
        raise ValueError(f"rotation axis of length {length:.6g}, not a unit vector (the format is 'x y z ax ay az "
                         f"angle' with a unit axis and the angle in radians), in pose line {line.strip()!r}")
    if abs(values[6]) > 2.0 * np.pi + 1e-9:
        # More than a full turn: no writer of this format puts one there, but an angle in degrees does.
        raise ValueError(f"rotation angle {values[6]:.6g} is more than a full turn (2 pi): the format's angle is in "
                         f"radians ({values[6]:.6g} deg would be {np.radians(values[6]):.6g}), in pose line "
                         f"{line.strip()!r}")
    return make_pose(axis_angle_to_rotmat(axis, values[6]), values[:3])


def poses_to_text(T: np.ndarray) -> str:
    """(n, 4, 4) -> text with one ``x y z ax ay az angle`` line per pose."""
    return "".join(pose_to_line(pose) + "\n" for pose in np.asarray(T).reshape(-1, 4, 4))


def text_to_poses(text: str) -> np.ndarray:
    """Text with one pose per non-empty line -> (n, 4, 4). ValueError starting ``line <k>:`` (1-based, as
    in the file) for a bad line."""
    poses = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            poses.append(line_to_pose(line))
        except ValueError as exc:
            raise ValueError(f"line {number}: {exc}") from exc
    return np.stack(poses) if poses else np.zeros((0, 4, 4))
