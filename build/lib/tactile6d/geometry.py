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
    if np.linalg.norm(axis) < 1e-12:
        if abs(values[6]) > 1e-12:
            raise ValueError(f"zero rotation axis with a non-zero angle in pose line {line.strip()!r}")
        axis = np.array([1.0, 0.0, 0.0])
    return make_pose(axis_angle_to_rotmat(axis, values[6]), values[:3])


def poses_to_text(T: np.ndarray) -> str:
    """(n, 4, 4) -> text with one ``x y z ax ay az angle`` line per pose."""
    return "".join(pose_to_line(pose) + "\n" for pose in np.asarray(T).reshape(-1, 4, 4))


def text_to_poses(text: str) -> np.ndarray:
    """Text with one pose per non-empty line -> (n, 4, 4)."""
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return np.stack([line_to_pose(line) for line in lines]) if lines else np.zeros((0, 4, 4))
