"""Superquadrics, the object-agnostic shapes the autoencoder is trained on (docs/design.md, The method).

A superquadric with semi-axes (a, b, c) and exponents (e1, e2) is the surface ``F(x, y, z) = 1`` of the
inside-outside function

    F = (|x/a|^(2/e2) + |y/b|^(2/e2))^(e2/e1) + |z/c|^(2/e1),

that is the spherical product of two unit superellipses: a meridian ``|u1|^(2/e1) + |v1|^(2/e1) = 1``
(u1 >= 0) and a horizontal section ``|u2|^(2/e2) + |v2|^(2/e2) = 1``, with surface point
``(a u1 u2, b u1 v2, c v1)``. Exponents near 0 give boxes (flat faces, sharp edges and corners), 1 gives
ellipsoids, values toward 2 give diamond-like shapes with ridges (obtuse edges).

Meshing. The usual parametrisation ``u = sign(cos t) |cos t|^e`` puts almost all vertices in the corners
when e is small and leaves the faces with a handful. Instead each of the two superellipses is sampled by
the polar angle of its points (which sweeps faces evenly), densely, and then re-sampled so that every
segment is at most ``max_edge`` long and turns its normal by at most ``max_turn``: flat faces get
``max_edge`` spacing, and rounded edges and corners as many vertices as their turning needs.

``F`` is homogeneous, ``F(s p) = s^(2/e1) F(p)``, so ``radial_distance = F^(e1/2)`` is homogeneous of
degree 1: ``p / radial_distance(p)`` is the surface point on the ray through p. That projects points
sampled on the mesh's flat triangles exactly onto the surface.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from tactile6d.core.errors import ConfigError
from tactile6d.core.sensor import sensor_poses_touching

# Dense samples per superellipse before re-sampling: enough that a corner rounded over 0.3 % of the
# turn (e = 0.1 on an 80 x 15 mm section) still gets about 10 of them.
_FINE_SAMPLES = 20000

# Bends sharper than this radius count as this radius when spending the turning budget. Exponents above
# 1 make the curvature infinite at the axis points (ridges, pole tips), where an unbounded budget would
# pile vertices into sub-micron slivers; the gel cannot resolve such detail anyway.
_MIN_BEND_RADIUS = 0.0002

# The most points one superellipse gets. A mesh has (points per curve)^2 vertices, so an unbounded
# budget (a shape far larger than max_edge, or a degenerate one) would ask for more memory than the
# machine has; at this cap a mesh has at most ~4M vertices. The training and calibration shapes stay far
# below it (their curves need at most a few hundred points), so it only turns an out-of-memory crash
# into a coarser mesh, with a warning.
_MAX_CURVE_SAMPLES = 2048

# Contact kinds, by how many directions the surface bends sharply in.
SURFACE, EDGE, CORNER = 0, 1, 2
KIND_NAMES = ("surface", "edge", "corner")


@dataclass(frozen=True)
class Superquadric:
    """Semi-axes a, b, c (metres, along x, y, z) and exponents e1 (meridian), e2 (horizontal section)."""

    a: float
    b: float
    c: float
    e1: float
    e2: float

    @property
    def axes(self) -> np.ndarray:
        return np.array([self.a, self.b, self.c])


def _spow(x: np.ndarray, p: float) -> np.ndarray:
    """Signed power sign(x) |x|^p."""
    return np.sign(x) * np.abs(x) ** p


def _norm_e(s: np.ndarray, t: np.ndarray, e: float) -> np.ndarray:
    """(|s|^(2/e) + |t|^(2/e))^(e/2), scaled by max(|s|, |t|) first so powers like 20 cannot overflow."""
    s, t = np.abs(s), np.abs(t)
    m = np.maximum(s, t)
    safe = np.where(m > 0.0, m, 1.0)
    return np.where(m > 0.0, m * ((s / safe) ** (2.0 / e) + (t / safe) ** (2.0 / e)) ** (e / 2.0), 0.0)


def _unit_coordinates(sq: Superquadric, points: np.ndarray) -> tuple[np.ndarray, ...]:
    """(n, 3) -> X, Y, Z (the point over the semi-axes) and u1 = (|X|^(2/e2) + |Y|^(2/e2))^(e2/2)."""
    X, Y, Z = (np.asarray(points, dtype=np.float64) / sq.axes).T
    return X, Y, Z, _norm_e(X, Y, sq.e2)


def radial_distance(sq: Superquadric, points: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n,): F^(e1/2); 1 on the surface, < 1 inside, and doubling with the point's distance."""
    _, _, Z, u1 = _unit_coordinates(sq, points)
    return _norm_e(u1, Z, sq.e1)


def inside_outside(sq: Superquadric, points: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n,): the classical inside-outside function F (1 on the surface)."""
    return radial_distance(sq, points) ** (2.0 / sq.e1)


def project_to_surface(sq: Superquadric, points: np.ndarray) -> np.ndarray:
    """(n, 3) nonzero points -> (n, 3): the surface point on the ray from the centre through each."""
    points = np.asarray(points, dtype=np.float64)
    return points / radial_distance(sq, points)[:, None]


def surface_normals(sq: Superquadric, points: np.ndarray) -> np.ndarray:
    """(n, 3) nonzero points -> (n, 3) unit outward normals of the level set of F through each point.

    The gradient of F, written in unit coordinates so that every power has a base in [0, 1]:
    grad F ~ (u1^(2/e1-1) (X/u1)^(2/e2-1) / a, u1^(2/e1-1) (Y/u1)^(2/e2-1) / b, Z^(2/e1-1) / c)
    (signed powers), evaluated on the surface point of the same ray (same direction, by homogeneity).
    """
    X, Y, Z, u1 = _unit_coordinates(sq, project_to_surface(sq, points))
    safe = np.where(u1 > 0.0, u1, 1.0)
    ring = np.where(u1 > 0.0, u1 ** (2.0 / sq.e1 - 1.0), 0.0)
    g = np.stack(
        [
            ring * _spow(X / safe, 2.0 / sq.e2 - 1.0) / sq.a,
            ring * _spow(Y / safe, 2.0 / sq.e2 - 1.0) / sq.b,
            _spow(Z, 2.0 / sq.e1 - 1.0) / sq.c,
        ],
        axis=-1,
    )
    return g / np.linalg.norm(g, axis=-1, keepdims=True)


# --- meshing -----------------------------------------------------------------------------------------


def _superellipse_at(e: float, p: float, q: float, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit-superellipse coordinates (u, v) of the point of the (p, q)-scaled curve at polar angle phi."""
    r = 1.0 / _norm_e(np.cos(phi) / p, np.sin(phi) / q, e)
    return r * np.cos(phi) / p, r * np.sin(phi) / q


def superellipse_samples(
    e: float, p: float, q: float, closed: bool, max_edge: float, max_turn: float
) -> tuple[np.ndarray, np.ndarray]:
    """Points on the superellipse ``|x/p|^(2/e) + |y/q|^(2/e) = 1``, as unit coordinates (u, v) (m,) each.

    closed: the whole curve from polar angle -pi, counter-clockwise, without repeating the start;
    otherwise the half with x >= 0 from -pi/2 to pi/2, both ends included. Consecutive points are at
    most ``max_edge`` apart (metres, on the scaled curve) and their normals at most ``max_turn`` apart
    (radians), approximately: both budgets are spread evenly along the curve. Bends sharper than
    ``_MIN_BEND_RADIUS`` get only that radius's share of the turning budget. At most
    ``_MAX_CURVE_SAMPLES`` points: beyond that the budgets are exceeded, evenly, with a warning.
    """
    lo, hi = (-np.pi, np.pi) if closed else (-np.pi / 2, np.pi / 2)
    phi = np.linspace(lo, hi, _FINE_SAMPLES)
    u, v = _superellipse_at(e, p, q, phi)
    pts = np.stack([p * u, q * v], axis=-1)
    normal_angle = np.unwrap(np.arctan2(_spow(v, 2.0 / e - 1.0) / q, _spow(u, 2.0 / e - 1.0) / p))
    ds = np.linalg.norm(np.diff(pts, axis=0), axis=-1)
    turn = np.minimum(np.abs(np.diff(normal_angle)), ds / _MIN_BEND_RADIUS)
    step = ds / max_edge + turn / max_turn
    cost = np.concatenate([[0.0], np.cumsum(step)])
    n_seg = max(16 if closed else 8, int(np.ceil(cost[-1])))
    if n_seg > _MAX_CURVE_SAMPLES:
        warnings.warn(f"the superellipse (e={e:.3g}, semi-axes {p:.3g} x {q:.3g} m) needs {n_seg} points for edges of "
                      f"{max_edge:.3g} m and turns of {max_turn:.3g} rad; meshed with {_MAX_CURVE_SAMPLES}, coarser",
                      stacklevel=2)
        n_seg = _MAX_CURVE_SAMPLES
    targets = np.linspace(0.0, cost[-1], n_seg + 1)
    if closed:
        targets = targets[:-1]
    phi_t = np.interp(targets, cost, phi)
    if not closed:
        phi_t[[0, -1]] = lo, hi
    return _superellipse_at(e, p, q, phi_t)


def _grid_faces(vertices: np.ndarray, n_rings: int, n_around: int) -> np.ndarray:
    """Triangles of a closed latitude-longitude grid: vertex 0 = south pole, then ``n_rings`` rings of
    ``n_around`` vertices (south to north, counter-clockwise seen from +z), then the north pole.

    Wound so that normals point outward. Each quad is split along its shorter diagonal: on a box's
    faces the quads are skewed parallelograms (meridians run radially, not across the face), and the
    longer diagonal can be twice the side.
    """
    ring = lambda i: 1 + i * n_around + np.arange(n_around)  # noqa: E731
    south, north = 0, 1 + n_rings * n_around
    faces = [np.stack([np.full(n_around, south), np.roll(ring(0), -1), ring(0)], axis=-1)]
    for i in range(n_rings - 1):
        lo, hi = ring(i), ring(i + 1)
        lo_next, hi_next = np.roll(lo, -1), np.roll(hi, -1)
        rising = np.linalg.norm(vertices[hi_next] - vertices[lo], axis=-1)
        falling = np.linalg.norm(vertices[hi] - vertices[lo_next], axis=-1)
        split = (rising <= falling)[:, None]
        faces.append(np.where(split, np.stack([lo, lo_next, hi_next], -1), np.stack([lo, lo_next, hi], -1)))
        faces.append(np.where(split, np.stack([lo, hi_next, hi], -1), np.stack([lo_next, hi_next, hi], -1)))
    last = ring(n_rings - 1)
    faces.append(np.stack([np.full(n_around, north), last, np.roll(last, -1)], axis=-1))
    return np.concatenate(faces)


def superquadric_mesh(sq: Superquadric, max_edge: float = 0.001, max_turn: float = 0.05) -> trimesh.Trimesh:
    """A watertight, outward-wound triangle mesh of the superquadric, with exact vertex normals.

    Vertices sit exactly on the surface; edges are about ``max_edge`` (metres) or shorter, and adjacent
    vertex normals differ by about ``max_turn`` (radians) or less (see ``superellipse_samples``).
    """
    u2, v2 = superellipse_samples(sq.e2, sq.a, sq.b, True, max_edge, max_turn)
    # Every meridian is this profile stretched horizontally by |(a u2, b v2)|: sample it at the
    # largest stretch (a box's corner, up to sqrt(a^2 + b^2)), where its spacing is widest.
    reach = float(np.max(np.hypot(sq.a * u2, sq.b * v2)))
    u1, v1 = superellipse_samples(sq.e1, reach, sq.c, False, max_edge, max_turn)
    u1, v1 = u1[1:-1], v1[1:-1]  # the poles are added once each below
    rings = np.stack(
        [sq.a * u1[:, None] * u2[None, :], sq.b * u1[:, None] * v2[None, :], sq.c * np.repeat(v1[:, None], len(u2), 1)],
        axis=-1,
    ).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, -sq.c]], rings, [[0.0, 0.0, sq.c]]])
    faces = _grid_faces(vertices, len(u1), len(u2))
    return trimesh.Trimesh(vertices, faces, vertex_normals=surface_normals(sq, vertices), process=False)


def grid_shape(mesh: trimesh.Trimesh) -> tuple[int, int]:
    """(rings, vertices per ring) of a mesh made by ``superquadric_mesh``."""
    n_around = int(np.sum(mesh.faces[:, 0] == 0))
    return (len(mesh.vertices) - 2) // n_around, n_around


def _normal_angle(n0: np.ndarray, n1: np.ndarray) -> np.ndarray:
    """Angle between unit vectors (..., 3), accurate for small angles."""
    return 2.0 * np.arcsin(np.clip(np.linalg.norm(n0 - n1, axis=-1) / 2.0, 0.0, 1.0))


def vertex_kinds(mesh: trimesh.Trimesh, sharp_radius: float) -> np.ndarray:
    """(n_vertices,) int: SURFACE, EDGE or CORNER for a mesh from ``superquadric_mesh``.

    The surface bends sharply in a direction when its curvature there exceeds 1 / ``sharp_radius``.
    On a superquadric the sharp features run along the grid lines (they come from one of the two
    superellipses), so the curvature is measured along the rings and along the meridians, by central
    differences of the vertex normals. A pole takes the sharpest kind of its neighbouring ring.
    """
    n_rings, n_around = grid_shape(mesh)
    P = np.asarray(mesh.vertices)
    N = np.asarray(mesh.vertex_normals)
    grid = 1 + np.arange(n_rings * n_around).reshape(n_rings, n_around)
    around = (np.roll(grid, 1, axis=1), np.roll(grid, -1, axis=1))
    padded = np.concatenate([np.zeros((1, n_around), int), grid, np.full((1, n_around), len(P) - 1)])
    along = (padded[:-2], padded[2:])
    sharp = np.zeros((n_rings, n_around), dtype=int)
    for prev, nxt in (around, along):
        curvature = _normal_angle(N[prev], N[nxt]) / np.linalg.norm(P[nxt] - P[prev], axis=-1)
        sharp += curvature > 1.0 / sharp_radius
    kinds = np.empty(len(P), dtype=int)
    kinds[grid] = sharp
    kinds[0], kinds[-1] = sharp[0].max(), sharp[-1].max()
    return kinds


def face_kinds(mesh: trimesh.Trimesh, sharp_radius: float) -> np.ndarray:
    """(n_faces,) int: the median kind of each face's three vertices."""
    return np.median(vertex_kinds(mesh, sharp_radius)[mesh.faces], axis=1).astype(int)


def nearest_vertex_kinds(mesh: trimesh.Trimesh, points: np.ndarray, sharp_radius: float) -> np.ndarray:
    """(n,) int: the kind (``vertex_kinds``) of the mesh vertex nearest each point (n, 3), metres."""
    _, nearest = cKDTree(np.asarray(mesh.vertices)).query(points)
    return vertex_kinds(mesh, sharp_radius)[nearest]


def sample_surface_contacts(
    sq: Superquadric,
    mesh: trimesh.Trimesh,
    n: int,
    rng: np.random.Generator,
    edge_bias: float,
    corner_bias: float,
    sharp_radius: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n contact points on the superquadric -> points (n, 3), outward unit normals (n, 3), kinds (n,).

    Each point is drawn area-weighted from the whole surface with probability
    ``1 - edge_bias - corner_bias``, else area-weighted from the EDGE faces (``edge_bias``) or the
    CORNER faces (``corner_bias``); a shape without such faces (an ellipsoid) falls back to the whole
    surface. Points are uniform on the chosen triangle, then projected exactly onto the surface.
    """
    if edge_bias < 0 or corner_bias < 0 or edge_bias + corner_bias > 1:
        raise ConfigError(f"edge_bias {edge_bias} and corner_bias {corner_bias} must be >= 0 and sum to <= 1")
    kinds = face_kinds(mesh, sharp_radius)
    area = np.asarray(mesh.area_faces)
    pools = [np.arange(len(area)), np.flatnonzero(kinds == EDGE), np.flatnonzero(kinds == CORNER)]
    pick = rng.choice(3, size=n, p=[1.0 - edge_bias - corner_bias, edge_bias, corner_bias])
    faces = np.empty(n, dtype=int)
    for k, pool in enumerate(pools):
        mask = pick == k
        if not mask.any():
            continue
        pool = pool if len(pool) else pools[0]
        faces[mask] = rng.choice(pool, size=int(mask.sum()), p=area[pool] / area[pool].sum())
    # Uniform barycentric coordinates: fold the unit square's upper triangle onto the lower one.
    r = rng.random((n, 2))
    r = np.where(r.sum(axis=1, keepdims=True) > 1.0, 1.0 - r, r)
    tri = np.asarray(mesh.vertices)[mesh.faces[faces]]
    points = project_to_surface(sq, tri[:, 0] + r[:, :1] * (tri[:, 1] - tri[:, 0]) + r[:, 1:] * (tri[:, 2] - tri[:, 0]))
    return points, surface_normals(sq, points), kinds[faces]


# --- the training set --------------------------------------------------------------------------------


class TrainingContact(NamedTuple):
    """One training image to render: the shape, the sensor pose in the shape's frame, press depth
    (metres) and roll about the sensor's x axis (radians)."""

    shape: Superquadric
    T_object_sensor: np.ndarray
    depth: float
    roll: float


def random_superquadric(rng: np.random.Generator, size_range, exponent_range) -> Superquadric:
    """Semi-axes uniform in ``size_range`` (metres) and exponents uniform in ``exponent_range``."""
    a, b, c = rng.uniform(size_range[0], size_range[1], size=3)
    e1, e2 = rng.uniform(exponent_range[0], exponent_range[1], size=2)
    return Superquadric(float(a), float(b), float(c), float(e1), float(e2))


_TRAINING_KEYS = (
    "n_images",
    "n_shapes",
    "size_range",
    "exponent_range",
    "depth_range",
    "edge_bias",
    "corner_bias",
    "sharp_radius",
    "mesh_max_edge",
    "mesh_max_turn",
)


def sample_training_contacts(n: int, rng: np.random.Generator, cfg: Mapping) -> list[TrainingContact]:
    """n random sensor contacts on ``cfg.n_shapes`` random superquadrics (the ``training_set`` section).

    The contacts come grouped by shape, in order, about n / n_shapes each, so a renderer builds each
    mesh once (``superquadric_mesh(shape, cfg.mesh_max_edge, cfg.mesh_max_turn)``, the same mesh the
    points were drawn on). Rolls are uniform in [-pi, pi), depths uniform in ``cfg.depth_range``, and
    the sensor poses come from ``sensor.sensor_poses_touching``.
    """
    missing = [k for k in _TRAINING_KEYS if k not in cfg]
    if missing:
        raise ConfigError(f"training_set config lacks keys {missing}")
    n_shapes = int(cfg["n_shapes"])
    if n_shapes < 1 or n < n_shapes:
        raise ConfigError(f"need 1 <= training_set.n_shapes <= n, got n_shapes={n_shapes}, n={n}")
    out: list[TrainingContact] = []
    for count in np.diff(np.linspace(0, n, n_shapes + 1).round().astype(int)):
        sq = random_superquadric(rng, cfg["size_range"], cfg["exponent_range"])
        mesh = superquadric_mesh(sq, float(cfg["mesh_max_edge"]), float(cfg["mesh_max_turn"]))
        points, normals, _ = sample_surface_contacts(
            sq, mesh, int(count), rng, float(cfg["edge_bias"]), float(cfg["corner_bias"]), float(cfg["sharp_radius"])
        )
        rolls = rng.uniform(-np.pi, np.pi, size=int(count))
        depths = rng.uniform(cfg["depth_range"][0], cfg["depth_range"][1], size=int(count))
        poses = sensor_poses_touching(points, normals, rolls, depths)
        out.extend(TrainingContact(sq, T, float(d), float(r)) for T, d, r in zip(poses, depths, rolls))
    return out


def training_contact_groups(contacts: list[TrainingContact]) -> list[tuple[int, int]]:
    """Index ranges [a, b) of consecutive contacts on the same shape (``sample_training_contacts`` groups them)."""
    edges = [0] + [i for i in range(1, len(contacts)) if contacts[i].shape is not contacts[i - 1].shape]
    return list(zip(edges, edges[1:] + [len(contacts)]))
