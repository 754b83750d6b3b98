"""A fast DIGIT tactile-image simulator that follows TACTO's optical model.

The model, in the DIGIT frame of ``digit.STL`` (metres):

- A pinhole camera at ``CAMERA_POSITION`` looks along +x, vertical field of view ``CAMERA_YFOV``. Image
  rows run along -z (row 0 is the top, largest z), columns along -y (column 0 is the largest y), as in
  the paper's images.
- The gel is a sphere-cap patch (``sensor.GEL_WIDTH`` along y by ``sensor.GEL_HEIGHT`` along z) whose apex
  is ``sensor.GEL_CENTER``; it bulges ``GEL_CURVATURE_MAX`` toward +x with the profile of a sphere of
  radius ``GEL_RADIUS`` (TACTO's ``curvature`` gel). The camera sees the object only where the object
  lies between the camera and the gel surface, i.e. where it presses into the gel.
- Three point lights (red, green, blue) on a circle of radius ``LIGHT_RADIUS`` about ``LIGHT_CENTER``, at
  ``LIGHT_ANGLES`` in the y-z plane, shade gel and object with pyrender's metallic-roughness model (grey
  base colour 0.3, metallic 0.2, roughness 0.8), gamma 1/2.2, clipped to [0, 1], stored as 8 bits.
- Output = background + GaussianBlur7x7(0.5 x (render - render without contact)), clipped and truncated
  to uint8, then + N(0, noise_std) per channel, clipped and truncated again.

Instead of rasterising the whole scene, the renderer casts one ray per pixel (Embree) against only the
triangles that can lie in front of the gel, and shades only the pixels they cover; everywhere else the
difference image is exactly zero.

The light scale ``light_intensity`` is not TACTO's nominal 1: at 1 every surface in front of the camera
saturates to white. 0.0041 was fitted to the paper's 120 TACTO images by the Pearson correlation of the
difference images (``tactile6d fidelity``; figures in docs/simulator.md).

Channel order: the background is taken as OpenCV reads it (BGR), the way TACTO takes it, and flipped to
RGB inside; output images are RGB (red light in channel 0), the order of the paper's PNG files.
"""

from __future__ import annotations

import concurrent.futures
import inspect
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

import cv2
import numpy as np
import trimesh
from embreex import rtcore as embree_rtcore
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from tactile6d.core import sensor
from tactile6d.core.config import default_section
from tactile6d.core.errors import ConfigError, DataError, InputError, MeshError
from tactile6d.core.geometry import invert_pose, make_pose

# --- TACTO's config_digit.yml, in the DIGIT frame ------------------------------------------------------
CAMERA_POSITION = np.array([0.0, 0.0, 0.015])
CAMERA_YFOV = np.deg2rad(60.0)
GEL_RADIUS = 0.1  # sphere radius of the curved gel
GEL_CURVATURE_MAX = 0.005  # the gel apex bulges this far toward +x beyond its corners
LIGHT_CENTER = np.array([0.005, 0.0, 0.015])
LIGHT_RADIUS = 0.02
LIGHT_ANGLES = np.deg2rad([30.0, 150.0, 270.0])  # red, green, blue; polar angle in the y-z plane from +y
LIGHT_POSITIONS = LIGHT_CENTER + LIGHT_RADIUS * np.stack(
    [np.zeros(3), np.cos(LIGHT_ANGLES), np.sin(LIGHT_ANGLES)], axis=-1
)  # (3, 3), row i = light i

# pyrender's default material (trimesh meshes without colours get it; TACTO strips object textures).
BASE_COLOR = 0.3
METALLIC = 0.2
ROUGHNESS = 0.8

# The body check: the prism behind the gel, from the back of the DIGIT body (the paper's PhysX box) to the
# plane of the gel's corners, over the gel's y-z footprint. An object there has gone through the gel.
_BODY_BOX_MIN = np.array(
    [
        sensor.BOX_CENTER[0] - sensor.BOX_HALF_EXTENTS[0],
        sensor.GEL_CENTER[1] - sensor.GEL_WIDTH / 2,
        sensor.GEL_CENTER[2] - sensor.GEL_HEIGHT / 2,
    ]
)
_BODY_BOX_MAX = np.array(
    [
        sensor.GEL_CENTER[0] - GEL_CURVATURE_MAX,
        sensor.GEL_CENTER[1] + sensor.GEL_WIDTH / 2,
        sensor.GEL_CENTER[2] + sensor.GEL_HEIGHT / 2,
    ]
)


@dataclass(frozen=True)
class RenderResult:
    """One simulated DIGIT reading.

    image (H, W, 3) uint8 RGB; depth (H, W) float32 metres: how far the object presses into the gel along
    the camera axis (sensor +x), 0 where it does not; mask (H, W) bool: ``depth > 0``.
    """

    image: np.ndarray
    depth: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True)
class MeshArrays:
    """The parts of a mesh the renderer reads.

    vertex_rows (3, V) float64 m: vertex coordinates stored as component rows (x, y, z); faces (F, 3)
    int32; vertex_normals_rows (3, V) float32: unit vertex normals stored as component rows (see
    ``shade``). Rows, because posing them is then nine multiply-adds over contiguous rows
    (``_transform_rows``), which needs no BLAS call.
    """

    vertex_rows: np.ndarray
    faces: np.ndarray
    vertex_normals_rows: np.ndarray


def mesh_arrays(mesh: trimesh.Trimesh | MeshArrays) -> MeshArrays:
    """Validate a mesh and take its arrays. Raises MeshError for no faces, zero area or non-finite vertices.

    The object is shaded with smooth (vertex-interpolated) normals, as TACTO's pyrender meshes are; merge
    duplicated vertices first (``mesh.merge_vertices(merge_tex=True, merge_norm=True)``) or UV seams show.
    """
    if isinstance(mesh, MeshArrays):
        return mesh
    if not isinstance(mesh, trimesh.Trimesh):
        raise MeshError(f"expected a trimesh.Trimesh, got {type(mesh).__name__}")
    faces = np.asarray(mesh.faces)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if len(faces) == 0:
        raise MeshError("mesh has no faces")
    if not np.all(np.isfinite(vertices)):
        raise MeshError("mesh has non-finite vertex coordinates")
    if not mesh.area > 1e-12:
        raise MeshError(f"mesh has zero surface area ({mesh.area:.3g} m^2)")
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    return MeshArrays(
        np.ascontiguousarray(vertices.T), faces.astype(np.int32), np.ascontiguousarray(normals.T, dtype=np.float32)
    )


def _transform_rows(R: np.ndarray, t: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    """R (3, 3) @ rows (3, m) (+ t (3,)) -> (3, m), as elementwise row arithmetic.

    NumPy hands ``@`` with a 3-long inner dimension to multithreaded OpenBLAS, which slows down badly on
    a loaded machine with the renderer's worker processes beside it; the row form needs no BLAS call and
    does not depend on the load (timings: docs/simulator.md).
    """
    out = np.empty(rows.shape, dtype=rows.dtype)
    for i in range(3):
        np.multiply(rows[0], R[i, 0], out=out[i])
        out[i] += R[i, 1] * rows[1]
        out[i] += R[i, 2] * rows[2]
        if t is not None:
            out[i] += t[i]
    return out


# --- camera and gel ------------------------------------------------------------------------------------


def pixel_rays(width: int, height: int, step: int = 1) -> np.ndarray:
    """Ray directions through pixel centres, DIGIT frame, scaled so that their x component is 1.

    -> (height // step, width // step, 3). With ``step`` > 1, one ray through the centre of each
    ``step`` x ``step`` block. Row 0 looks toward +z, column 0 toward +y.
    """
    focal = (height / 2.0) / math.tan(CAMERA_YFOV / 2.0)  # pixels; square pixels, as in pyrender
    rows = (np.arange(height // step) + 0.5) * step
    cols = (np.arange(width // step) + 0.5) * step
    v = -(rows - height / 2.0) / focal
    u = -(cols - width / 2.0) / focal
    out = np.empty((len(rows), len(cols), 3))
    out[..., 0] = 1.0
    out[..., 1] = u[None, :]
    out[..., 2] = v[:, None]
    return out


def _gel_sag(dy: np.ndarray, dz: np.ndarray) -> np.ndarray:
    """Sphere-cap sag ``R - sqrt(R^2 - r^2)`` (m) at offsets (dy, dz) from the gel axis."""
    return GEL_RADIUS - np.sqrt(np.maximum(0.0, GEL_RADIUS**2 - dy**2 - dz**2))


_SAG_SCALE = GEL_CURVATURE_MAX / _gel_sag(sensor.GEL_WIDTH / 2, sensor.GEL_HEIGHT / 2)


def gel_surface(rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each ray from the camera meets the gel surface.

    rays (..., 3) with x component 1 -> points (..., 3) in the DIGIT frame, unit normals (..., 3) facing
    the camera. The gel is ``x = X0 - _SAG_SCALE * sag(y, z)``: the sphere-cap profile scaled so that the
    corners sit ``GEL_CURVATURE_MAX`` behind the apex, as TACTO builds its gel mesh.
    """
    x0, y0, z0 = sensor.GEL_CENTER
    x = np.full(rays.shape[:-1], x0)
    for _ in range(8):  # fixed-point iteration; the surface is shallow, so it contracts fast
        points = CAMERA_POSITION + x[..., None] * rays
        x = x0 - _SAG_SCALE * _gel_sag(points[..., 1] - y0, points[..., 2] - z0)
    points = CAMERA_POSITION + x[..., None] * rays
    dy, dz = points[..., 1] - y0, points[..., 2] - z0
    root = np.sqrt(np.maximum(1e-12, GEL_RADIUS**2 - dy**2 - dz**2))
    normals = np.stack([-np.ones_like(dy), -_SAG_SCALE * dy / root, -_SAG_SCALE * dz / root], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return points, normals


def shade(points: np.ndarray, normals: np.ndarray, light_intensity: float) -> np.ndarray:
    """pyrender's metallic-roughness shading of a grey surface lit by the three DIGIT lights.

    points (3, m), unit normals (3, m): component rows x, y, z in the DIGIT frame -> (3, m) float32 linear
    radiance (before gamma and clipping, which ``to_8bit`` applies), row i lit by light i (R, G, B) only.
    (Rows of components, not (m, 3): NumPy's elementwise arithmetic on rows is several times faster than
    reductions over a short last axis.)

    Only +, -, *, / and sqrt, which IEEE 754 rounds correctly on every SIMD path: NumPy's ``power`` (and
    its exp, log, tan...) take other code paths with AVX-512 and differ in the last bit, which moved
    framebuffer levels between machines (docs/reproducibility.md, Across machines).
    """
    p = np.asarray(points, dtype=np.float32)
    n = np.asarray(normals, dtype=np.float32)
    view = CAMERA_POSITION.astype(np.float32)[:, None] - p
    view *= 1.0 / np.sqrt(_dot3(view, view))
    nv = np.clip(np.abs(_dot3(n, view)), 0.001, 1.0)
    c_diff = BASE_COLOR * (1.0 - 0.04) * (1.0 - METALLIC)
    f0 = 0.04 * (1.0 - METALLIC) + BASE_COLOR * METALLIC
    k = (ROUGHNESS + 1.0) ** 2 / 8.0  # Schlick-GGX geometry term, as pyrender (direct lighting)
    alpha2 = ROUGHNESS**4
    g_view = nv / (nv * (1.0 - k) + k)
    out = np.empty((3, p.shape[1]), dtype=np.float32)
    for i, light in enumerate(LIGHT_POSITIONS.astype(np.float32)):
        to_light = light[:, None] - p
        dist2 = _dot3(to_light, to_light)
        to_light *= 1.0 / np.sqrt(dist2)
        half = to_light + view
        half *= 1.0 / np.sqrt(_dot3(half, half))
        nl = np.clip(_dot3(n, to_light), 0.001, 1.0)
        nh = np.clip(_dot3(n, half), 0.0, 1.0)
        vh = np.clip(_dot3(view, half), 0.0, 1.0)
        one_minus_vh = 1.0 - vh
        fresnel = f0 + (1.0 - f0) * (one_minus_vh * one_minus_vh) * (one_minus_vh * one_minus_vh) * one_minus_vh
        geometric = g_view * nl / (nl * (1.0 - k) + k)
        distribution = alpha2 / (np.pi * (nh * nh * (alpha2 - 1.0) + 1.0) ** 2)
        brdf = (1.0 - fresnel) * (c_diff / np.pi) + fresnel * geometric * distribution / (4.0 * nl * nv + 0.001)
        out[i] = nl * (light_intensity / dist2) * brdf
    return out


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (3, m) component arrays -> (m,)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _gamma_level_bounds() -> np.ndarray:
    """(255,) float64: the fifth power of the linear radiance at which each 8-bit level k + 1 begins.

    Level k is ``round(255 * x ** (1 / 2.2))``; it rises past k where ``x ** (5 / 11) = (k + 0.5) / 255``,
    i.e. ``x ** 5 = ((k + 0.5) / 255) ** 11``: computed exactly with rationals, then rounded once.
    """
    return np.array([float(Fraction(2 * k + 1, 510) ** 11) for k in range(255)])


_GAMMA_LEVEL_BOUNDS = _gamma_level_bounds()


def to_8bit(radiance: np.ndarray) -> np.ndarray:
    """Linear radiance (``shade``) -> 0..255 float32 levels as pyrender's framebuffer stores them.

    Gamma 1/2.2, clipping to [0, 1] and rounding to the nearest level, done without ``power``: the level
    is the number of bounds (``_gamma_level_bounds``) that ``x ** 5`` reaches, and ``x ** 5`` is four
    float64 products, rounded the same way on every CPU. Negative radiance (none in practice) is level 0.
    """
    x = np.maximum(np.asarray(radiance, dtype=np.float64), 0.0)
    fifth = (x * x) * (x * x) * x
    return np.searchsorted(_GAMMA_LEVEL_BOUNDS, fifth, side="right").astype(np.float32)


# --- the object's part in front of the gel ---------------------------------------------------------------


def _front_triangles(vertices: np.ndarray, faces: np.ndarray, x_far: float, half_y: float, half_z: float):
    """Indices of the faces that can be seen in front of the gel: (k,) int.

    vertices (V, 3) in the DIGIT frame. A face is kept when it faces the camera (pyrender culls back
    faces; so does this renderer, by leaving them out) and its bounding box overlaps the view box
    ``0 <= x <= x_far``, ``|y| <= half_y``, ``|z - z_cam| <= half_z``. The box test uses outcodes: a face
    misses the box exactly when its three corners are all outside the same one of its six planes.
    """
    z = vertices[:, 2] - CAMERA_POSITION[2]
    outcode = (
        (vertices[:, 0] < 0.0).astype(np.uint8)
        | ((vertices[:, 0] > x_far) << 1)
        | ((vertices[:, 1] < -half_y) << 2)
        | ((vertices[:, 1] > half_y) << 3)
        | ((z < -half_z) << 4)
        | ((z > half_z) << 5)
    ).astype(np.uint8)
    codes = outcode[faces]
    idx = np.nonzero((codes[:, 0] & codes[:, 1] & codes[:, 2]) == 0)[0]
    t = vertices[faces[idx]]
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    facing = np.sum(normal * (t[:, 0] - CAMERA_POSITION), axis=1) < 0.0
    return idx[facing]


def inside_body(vertices: np.ndarray) -> np.ndarray:
    """vertices (..., 3) in the DIGIT frame -> (...) bool: inside the DIGIT body behind the gel.

    "Behind the gel" is the prism over the gel's y-z footprint between the back of the body and the
    plane of the gel corners (x < GEL_CENTER.x - GEL_CURVATURE_MAX): an object there has gone through the
    whole gel. Vertices beside the gel's footprint are not checked (the paper's own data has an object
    grazing the body's top rim, which TACTO renders without complaint).
    """
    v = np.asarray(vertices)
    return np.all((v >= _BODY_BOX_MIN) & (v <= _BODY_BOX_MAX), axis=-1)


class _RayCaster:
    """First hits of rays from the camera on a set of triangles (Embree, single precision)."""

    def __init__(self):
        self._device = embree_rtcore.EmbreeDevice()

    def first_hits(self, triangles: np.ndarray, rays: np.ndarray, t_max: np.ndarray | None = None):
        """triangles (k, 3, 3), rays (n, 3) from CAMERA_POSITION -> t (n,) float64, face (n,) or -1,
        u (n,) float32, v (n,) float32.

        The hit point is ``CAMERA_POSITION + t * ray``; (u, v) are barycentric weights of corners 1 and 2.
        t_max (n,) float32, optional: Embree stops each ray there, so a first hit beyond it comes back as
        a miss (face -1), and one up to it is the same hit as without the limit.

        Embree only picks the triangle: its own t, u, v are float32 values that each of its intersection
        kernels (SSE2, AVX, AVX2, AVX-512, chosen for the CPU) rounds its own way, which moved a few
        pixels by one grey level between machines. They are recomputed here in float64 from the triangle
        Embree reports (``ray_triangle_hits``), and u, v rounded to float32 as Embree returns them.
        """
        scene = rtcore_scene.EmbreeScene(self._device)
        # Embree works in float32: shift to the camera so coordinates stay small and precise.
        corners = (triangles - CAMERA_POSITION).astype(np.float32)
        TriangleMesh(scene, corners)
        origins = np.zeros((len(rays), 3), dtype=np.float32)
        directions = rays.astype(np.float32)
        dists = None if t_max is None else np.asarray(t_max, dtype=np.float32)
        face = scene.run(origins, directions, dists=dists, output=1)["primID"]
        t = np.full(len(rays), np.inf)
        u, v = np.zeros(len(rays), dtype=np.float32), np.zeros(len(rays), dtype=np.float32)
        hit = np.nonzero(face >= 0)[0]
        # The float32 corners and rays Embree traced, so that the hit is on the triangle it chose.
        t[hit], hit_u, hit_v = ray_triangle_hits(corners[face[hit]].astype(np.float64), directions[hit].astype(np.float64))
        u[hit], v[hit] = hit_u.astype(np.float32), hit_v.astype(np.float32)
        return t, face, u, v


def ray_triangle_hits(corners: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where rays from the origin meet the planes of their triangles (Moeller-Trumbore, float64).

    corners (m, 3, 3), directions (m, 3) -> t (m,), u (m,), v (m,): the point is ``t * direction`` and
    ``(1 - u - v) * c0 + u * c1 + v * c2``. Elementwise products, sums and one division, written out so
    that the operation order is fixed: the same bits on every CPU.
    """
    c0 = corners[:, 0]
    e1, e2 = corners[:, 1] - c0, corners[:, 2] - c0
    s = -c0
    p, q = _cross_rows(directions, e2), _cross_rows(s, e1)
    inv_det = 1.0 / _dot_rows(e1, p)
    return _dot_rows(e2, q) * inv_det, _dot_rows(s, p) * inv_det, _dot_rows(directions, q) * inv_det


def _dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m, 3) . (m, 3) -> (m,), in a fixed order."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m, 3) x (m, 3) -> (m, 3), written out (np.cross's order is its own business)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


# --- the renderer ------------------------------------------------------------------------------------


class DigitRenderer:
    """Simulated DIGIT images over a real no-contact background.

    Every setting is the ``render`` config section's key of the same name (conf/render/default.yaml, which
    gives the values and their origin); ``from_config`` builds one from that section.

    background (h, w, 3) uint8 in OpenCV's BGR order (TACTO's convention; flipped to RGB here); another
    size than (height, width) is resized with a warning. noise_std: Gaussian noise on 0..255. blur_ksize:
    odd Gaussian kernel of the difference image. diff_scale: the difference image's scale before the
    blur. light_intensity: see the module docstring. max_press (m): deeper presses raise InputError (the
    object would be inside the body). render_step: cast one ray per ``render_step`` x ``render_step``
    pixel block and upsample (1 = every pixel; 2 casts a quarter of the rays, and the mask and depth are
    then blocky by 2 pixels). force: TACTO's normal force in [0, 100]; it moves the object toward the
    camera by force / 100 x ``max_deformation``. workers: processes for ``render_many``. strict: raise
    InputError when the object is inside the sensor body (``inside_body``, or a press deeper than
    ``max_press``); when False, render what the camera would see, as TACTO does (a database sampled on
    sharp edges or concave parts has such poses).

    Not thread-safe; use one renderer per thread. ``close()`` (or ``with``) ends the worker processes.
    """

    def __init__(
        self,
        background: np.ndarray,
        *,
        noise_std: float,
        blur_ksize: int,
        diff_scale: float,
        light_intensity: float,
        max_press: float,
        render_step: int,
        force: float,
        max_deformation: float,
        width: int,
        height: int,
        workers: int,
        strict: bool,
    ):
        if blur_ksize < 1 or blur_ksize % 2 == 0:
            raise ValueError(f"blur_ksize must be odd and positive, got {blur_ksize}")
        if render_step < 1 or width % render_step or height % render_step:
            raise ValueError(f"render_step {render_step} must divide the image size {width}x{height}")
        # The constructor arguments but the background and workers: worker processes rebuild from them.
        self.settings = dict(
            noise_std=float(noise_std),
            blur_ksize=int(blur_ksize),
            diff_scale=float(diff_scale),
            light_intensity=float(light_intensity),
            max_press=float(max_press),
            render_step=int(render_step),
            force=float(force),
            max_deformation=float(max_deformation),
            width=int(width),
            height=int(height),
            strict=bool(strict),
        )
        for key, value in self.settings.items():
            setattr(self, key, value)
        self.shift = min(max(self.force, 0.0), 100.0) / 100.0 * self.max_deformation  # m toward the camera
        self.workers = max(1, int(workers))
        self.background_bgr = np.asarray(background)
        self.background = _prepare_background(self.background_bgr, self.width, self.height)

        rays = pixel_rays(self.width, self.height, self.render_step)  # (h, w, 3)
        self.grid_shape = rays.shape[:2]
        gel_points, gel_normals = gel_surface(rays)
        footprint = np.abs(gel_points[..., 1:] - sensor.GEL_CENTER[1:]) <= [sensor.GEL_WIDTH / 2, sensor.GEL_HEIGHT / 2]
        if not np.all(footprint):
            raise ValueError(f"a {self.width}x{self.height} image sees past the gel's edges; keep the 3:4 aspect")
        # Per ray-grid pixel, flattened: ray (x = 1, u, v); gel hit parameter (= its x distance from the
        # camera); gel colour without contact (3, n) in 0..255.
        self._rays = np.ascontiguousarray(rays, dtype=np.float32)
        self._u = rays[..., 1].ravel().astype(np.float32)
        self._v = rays[..., 2].ravel().astype(np.float32)
        self._gel_t = (gel_points[..., 0] - CAMERA_POSITION[0]).ravel().astype(np.float32)
        self._gel_color = to_8bit(
            shade(gel_points.reshape(-1, 3).T, gel_normals.reshape(-1, 3).T, self.light_intensity)
        )
        self._pixel_index = np.arange(rays.shape[0] * rays.shape[1]).reshape(rays.shape[:2])
        # The view box: all rays between the camera and the gel apex plane.
        apex = sensor.GEL_CENTER[0]
        self._half_y = float(np.abs(rays[..., 1]).max() * apex) + 1e-4
        self._half_z = float(np.abs(rays[..., 2]).max() * apex) + 1e-4
        self._focal = (self.height / 2.0) / math.tan(CAMERA_YFOV / 2.0) / self.render_step
        self._caster = _RayCaster()
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None

    @classmethod
    def from_config(cls, config: Mapping, background: np.ndarray, **overrides) -> DigitRenderer:
        """A renderer from the ``render`` config section (conf/render/default.yaml), with ``overrides``
        (constructor arguments) on top; keys that are not constructor arguments (background path, database
        placement) are ignored. A ConfigError names any setting that neither gives."""
        names = set(inspect.signature(cls.__init__).parameters) - {"self", "background"}
        kwargs = {key: config[key] for key in config if key in names}
        kwargs.update(overrides)
        missing = sorted(names - set(kwargs))
        if missing:
            raise ConfigError(f"render config lacks keys {missing}")
        return cls(background, **kwargs)

    @classmethod
    def from_default_config(cls, background: np.ndarray, **overrides) -> DigitRenderer:
        """``from_config`` on the default config's ``render`` section (``config.default_section``)."""
        return cls.from_config(default_section("render"), background, **overrides)

    # -- single images ------------------------------------------------------------------------------

    def render(
        self, mesh: trimesh.Trimesh | MeshArrays, T_world_object: np.ndarray, T_world_sensor: np.ndarray, seed=None
    ) -> RenderResult:
        """The DIGIT reading of a sensor at ``T_world_sensor`` (4, 4) touching the mesh at ``T_world_object`` (4, 4).

        seed: for the noise (int, SeedSequence or None). Raises InputError when the object is inside the
        sensor body (if ``strict``) and MeshError for a degenerate mesh.
        """
        arrays = mesh_arrays(mesh)
        T_sensor_object = invert_pose(np.asarray(T_world_sensor, dtype=np.float64)) @ np.asarray(
            T_world_object, dtype=np.float64
        )
        diff, depth = self.contact(arrays, T_sensor_object)
        return self.compose(diff, depth, seed)

    def no_contact(self, seed=None) -> np.ndarray:
        """(H, W, 3) uint8 RGB: the background plus noise."""
        return self._add_noise(_truncate(self.background), seed)

    def contact(self, mesh: trimesh.Trimesh | MeshArrays, T_sensor_object: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free difference image and press depth on the ray grid.

        mesh, T_sensor_object (4, 4) -> diff (h, w, 3) float32 in 0..255 units, RGB: render minus render without
        contact (before scaling and blur); depth (h, w) float32 metres. (h, w) = image size / render_step.
        """
        arrays = mesh_arrays(mesh)
        h, w = self.grid_shape
        diff = np.zeros((3, h * w), dtype=np.float32)
        depth = np.zeros(h * w, dtype=np.float32)
        hits = self._gel_hits(arrays, T_sensor_object)
        if hits is not None:
            T, faces, pixels, t, prim, bu, bv = hits
            point = np.stack([t, t * self._u[pixels], CAMERA_POSITION[2] + t * self._v[pixels]])  # (3, m)
            # Smooth shading: barycentric blend of the corner normals in the object frame, then rotate.
            corners = arrays.faces[faces[prim]]  # (m, 3) vertex indices
            vn = arrays.vertex_normals_rows
            normal = (1.0 - bu - bv) * vn[:, corners[:, 0]] + bu * vn[:, corners[:, 1]] + bv * vn[:, corners[:, 2]]
            normal = _transform_rows(T[:3, :3].astype(np.float32), None, normal)
            normal *= 1.0 / np.sqrt(_dot3(normal, normal))
            diff[:, pixels] = to_8bit(shade(point, normal, self.light_intensity)) - self._gel_color[:, pixels]
            depth[pixels] = self._gel_t[pixels] - t
        return np.ascontiguousarray(diff.T).reshape(h, w, 3), depth.reshape(h, w)

    def ray_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """The camera's rays on this renderer's grid, flattened row by row: rays (n, 3) float32 (x = 1, u, v)
        and each ray's distance to the gel along the camera axis (n,) float32, the numbers every cast of the
        renderer uses (copies; n = h * w of ``grid_shape``)."""
        return self._rays.reshape(-1, 3).copy(), self._gel_t.copy()

    def contact_depth(self, mesh: trimesh.Trimesh | MeshArrays, T_sensor_object: np.ndarray) -> np.ndarray:
        """The press depth of ``contact`` alone, (h, w) float32 metres, without shading: for callers that
        need only where and how deep the object presses (render-and-compare). Bit-identical to it.

        Its rays stop at the gel (``_gel_hits``' ``stop_at_gel``), which spares Embree some traversal
        (about 6 ms of the 90 casts of an estimate, docs/speed.md).
        """
        arrays = mesh_arrays(mesh)
        depth = np.zeros(self.grid_shape[0] * self.grid_shape[1], dtype=np.float32)
        hits = self._gel_hits(arrays, T_sensor_object, stop_at_gel=True)
        if hits is not None:
            pixels, t = hits[2], hits[3]
            depth[pixels] = self._gel_t[pixels] - t
        return depth.reshape(self.grid_shape)

    def _gel_hits(self, arrays: MeshArrays, T_sensor_object: np.ndarray, stop_at_gel: bool = False):
        """Where the camera's rays hit the object in front of the gel -> None (no press) or (T, faces,
        pixels, t, prim, bu, bv): the pose used (with TACTO's force shift), the front faces, and per pressed
        ray its pixel index, hit distance, face (into ``faces``) and barycentric weights of corners 1 and 2.

        stop_at_gel: Embree stops each ray just past its gel point, since a first hit beyond the gel is
        dropped anyway. The pressed rays' hits are the same; ``contact`` keeps the unlimited cast, with
        which the stored databases and scene sets were rendered.

        Raises InputError (when ``strict``) for an object inside the sensor body.
        """
        T = np.asarray(T_sensor_object, dtype=np.float64)
        if self.shift > 0.0:
            # TACTO moves the object along the line from its origin to the camera.
            direction = CAMERA_POSITION - T[:3, 3]
            T = make_pose(T[:3, :3], T[:3, 3] + self.shift * direction / (np.linalg.norm(direction) + 1e-6))
        vertices = _transform_rows(T[:3, :3], T[:3, 3], arrays.vertex_rows).T  # (V, 3) view
        if self.strict:
            inside = inside_body(vertices)
            if np.any(inside):
                deepest = vertices[inside, 0].min()
                raise InputError(
                    f"the object is inside the DIGIT body: {int(inside.sum())} mesh vertices lie behind the "
                    f"gel, the deepest at x = {deepest * 1000:.1f} mm in the sensor frame"
                )
        faces = _front_triangles(vertices, arrays.faces, sensor.GEL_CENTER[0], self._half_y, self._half_z)
        if len(faces) == 0:
            return None
        triangles = vertices[arrays.faces[faces]]
        r0, r1, c0, c1 = self._pixel_window(triangles)
        if r0 >= r1 or c0 >= c1:
            return None
        pixels = self._pixel_index[r0:r1, c0:c1].ravel()
        # Just past the gel, so that a hit at the gel itself is still found and then dropped below.
        t_max = np.nextafter(self._gel_t[pixels], np.float32(np.inf)) if stop_at_gel else None
        t, prim, bu, bv = self._caster.first_hits(triangles, self._rays[r0:r1, c0:c1].reshape(-1, 3), t_max)
        hit = np.nonzero((prim >= 0) & (t < self._gel_t[pixels]))[0]
        if len(hit) == 0:
            return None
        pixels, t = pixels[hit], t[hit]
        press = self._gel_t[pixels] - t
        if self.strict and press.max() > self.max_press:
            raise InputError(
                f"the object presses {press.max() * 1000:.1f} mm into the gel, more than its "
                f"{self.max_press * 1000:.1f} mm: it would be inside the DIGIT body"
            )
        return T, faces, pixels, t, prim[hit], bu[hit], bv[hit]

    def _pixel_window(self, triangles: np.ndarray) -> tuple[int, int, int, int]:
        """Row and column range (of the ray grid) that the triangles (k, 3, 3) can cover: r0, r1, c0, c1."""
        h, w = self.grid_shape
        pts = triangles.reshape(-1, 3) - CAMERA_POSITION
        if np.any(pts[:, 0] <= 1e-4):  # a corner beside or behind the camera: projections blow up
            return 0, h, 0, w
        u, v = pts[:, 1] / pts[:, 0], pts[:, 2] / pts[:, 0]
        cols = w / 2.0 - u * self._focal - 0.5
        rows = h / 2.0 - v * self._focal - 0.5
        r0 = int(np.clip(np.floor(rows.min()), 0, h))
        r1 = int(np.clip(np.ceil(rows.max()) + 1, 0, h))
        c0 = int(np.clip(np.floor(cols.min()), 0, w))
        c1 = int(np.clip(np.ceil(cols.max()) + 1, 0, w))
        return r0, r1, c0, c1

    def compose(self, diff: np.ndarray, depth: np.ndarray, seed=None) -> RenderResult:
        """The output of ``contact`` -> RenderResult: upsample, scale, blur, add to the background, add noise."""
        if self.render_step > 1:
            size = (self.width, self.height)
            diff = cv2.resize(diff, size, interpolation=cv2.INTER_LINEAR)
            depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
        mask = depth > 0
        image = self.background
        if np.any(mask):
            k = self.blur_ksize
            image = image + cv2.GaussianBlur(self.diff_scale * diff, (k, k), 0)
        return RenderResult(self._add_noise(_truncate(image), seed), depth, mask)

    def _add_noise(self, image: np.ndarray, seed) -> np.ndarray:
        """uint8 image + this renderer's noise (``add_noise``)."""
        return add_noise(image, self.noise_std, seed)

    # -- batches -----------------------------------------------------------------------------------

    def render_many(
        self,
        mesh: trimesh.Trimesh | MeshArrays,
        T_object_sensors: np.ndarray,
        seeds: Sequence[int] | np.ndarray | int | None = 0,
        progress=None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Many sensor poses on one mesh, the mesh frame as the world.

        T_object_sensors (n, 4, 4); seeds: (n,) ints, or an int s for seeds s, s+1, ..., or None (fresh
        entropy). progress: optional callable(k) told each time k more images are done (e.g. tqdm.update).
        -> images (n, H, W, 3) uint8 RGB, masks (n, H, W) bool. Uses ``workers`` processes when n is
        large enough to pay for them. Raises InputError naming the first pose whose object is inside
        the body.
        """
        arrays = mesh_arrays(mesh)
        T = np.asarray(T_object_sensors, dtype=np.float64).reshape(-1, 4, 4)
        n = len(T)
        seed_list = _seed_list(seeds, n)
        images = np.empty((n, self.height, self.width, 3), dtype=np.uint8)
        masks = np.empty((n, self.height, self.width), dtype=bool)
        chunks = _chunks(n, self.workers)
        if self.workers == 1 or len(chunks) == 1:
            for a, b in chunks:
                images[a:b], masks[a:b] = _render_range(self, arrays, T[a:b], seed_list[a:b], a)
                if progress is not None:
                    progress(b - a)
            return images, masks
        pool = self._worker_pool()
        futures = {
            pool.submit(_worker_render, arrays, T[a:b], seed_list[a:b], a): (a, b) for a, b in chunks
        }
        try:
            for future in concurrent.futures.as_completed(futures):
                a, b = futures[future]
                images[a:b], masks[a:b] = future.result()
                if progress is not None:
                    progress(b - a)
        except BaseException:
            from tactile6d.runtime.executor import cancel_unless_interrupted

            cancel_unless_interrupted(futures)
            raise
        return images, masks

    def _worker_pool(self) -> concurrent.futures.ProcessPoolExecutor:
        if self._pool is None:
            from tactile6d.runtime.executor import worker_context

            # spawn, not fork: the parent may hold threads (torch, jax) that fork would copy mid-state;
            # workers that Ctrl-C ends at once, mid-task (tactile6d.executor.worker_context).
            self._pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=self.workers,
                mp_context=worker_context(),
                initializer=_worker_init,
                initargs=(self.background_bgr, dict(self.settings)),
            )
        return self._pool

    def close(self) -> None:
        """End the worker processes of ``render_many``, if any: once their running tasks finish, or at
        once while a Ctrl-C or SIGTERM unwinds (``tactile6d.executor.shutdown_pool``)."""
        if self._pool is not None:
            from tactile6d.runtime.executor import shutdown_pool

            pool, self._pool = self._pool, None
            shutdown_pool(pool)

    def __enter__(self) -> DigitRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        # A pool left open would keep its processes until interpreter exit.
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


def task_renderer(settings: dict, background_bgr: np.ndarray) -> DigitRenderer:
    """The renderer of an executor task: one process (it is already a worker), built from ``settings``
    (a renderer's ``settings``) and the background (H, W, 3) uint8 BGR as read, once per process and kept
    (``runtime.executor.process_cache``) while the two stay the same."""
    import hashlib
    import json

    from tactile6d.runtime.executor import process_cache

    key = ("task renderer", json.dumps(settings, sort_keys=True),
           hashlib.sha1(np.ascontiguousarray(background_bgr).tobytes()).hexdigest())
    return process_cache(key, lambda: DigitRenderer(background_bgr, **settings, workers=1), slot="task renderer")


def add_noise(image: np.ndarray, noise_std: float, seed) -> np.ndarray:
    """(H, W, 3) uint8 image + N(0, noise_std) per pixel and channel, clipped and truncated (TACTO) -> uint8.

    seed: int, SeedSequence or None (fresh entropy). The same (image, noise_std, seed) always gives the
    same output on the same OpenCV build, so a stored noise-free image and its seed reproduce a noisy
    one exactly (tactile6d.sim.database). OpenCV draws the noise (faster than NumPy's generator),
    seeded from ``seed`` through a SeedSequence; this reseeds OpenCV's per-thread global RNG. Truncating
    ``a + n`` equals rounding ``a + n - 0.5``, which is what OpenCV's saturating add does with noise of
    mean -0.5. noise_std <= 0 returns the image unchanged.
    """
    if noise_std <= 0:
        return image
    state = np.random.SeedSequence(seed) if not isinstance(seed, np.random.SeedSequence) else seed
    cv2.setRNGSeed(int(state.generate_state(1)[0] & 0x7FFFFFFF))
    noise = np.empty((image.shape[0], image.shape[1] * image.shape[2]), dtype=np.float32)
    cv2.randn(noise, -0.5, noise_std)
    return cv2.add(image, noise.reshape(image.shape), dtype=cv2.CV_8U)


def load_background_bgr(cfg: Mapping, store) -> np.ndarray:
    """The no-contact background named by ``cfg.render.background`` -> (H, W, 3) uint8 in OpenCV's BGR order.

    cfg: the whole config (its ``render`` section is read); store: a ``tactile6d.data.third_party.DataStore``, which
    checks the file against the data manifest (or downloads it). BGR is what ``DigitRenderer`` takes,
    as TACTO does; ``DigitRenderer.background`` holds the RGB float version it adds imprints to. The
    suffix is there because ``tactile6d.estimator.load_background`` reads the same file in RGB, the
    order of the tactile images the estimator takes. Raises DataError when the file is not a readable image.
    """
    path = store.path(str(cfg["render"]["background"]))
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DataError(f"{path}: not a readable image (config key render.background)")
    return image


def _prepare_background(background: np.ndarray, width: int, height: int) -> np.ndarray:
    """BGR uint8 background -> RGB float32 (height, width, 3), resized with a warning when needed."""
    bg = np.asarray(background)
    if bg.ndim != 3 or bg.shape[2] != 3:
        raise InputError(f"background must be an (H, W, 3) image, got shape {bg.shape}")
    if bg.shape[:2] != (height, width):
        warnings.warn(
            f"background is {bg.shape[1]}x{bg.shape[0]} (W x H), not {width}x{height}: resized",
            stacklevel=3,
        )
        bg = cv2.resize(bg, (width, height), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(bg[..., ::-1]).astype(np.float32)


def _truncate(image: np.ndarray) -> np.ndarray:
    """Clip to 0..255 and drop the fraction, as TACTO's ``astype(np.uint8)`` does."""
    return np.clip(image, 0, 255).astype(np.uint8)


def _seed_list(seeds, n: int) -> list:
    if seeds is None:
        return list(np.random.SeedSequence().spawn(n))
    if np.isscalar(seeds):
        return [int(seeds) + i for i in range(n)]
    seeds = list(seeds)
    if len(seeds) != n:
        raise InputError(f"got {len(seeds)} seeds for {n} sensor poses")
    return seeds


def _chunks(n: int, workers: int) -> list[tuple[int, int]]:
    """Contiguous index ranges: one when a single process is used, else about 4 per worker (load balance)."""
    if n == 0:
        return []
    count = 1 if workers == 1 or n < 8 * workers else min(n, 4 * workers)
    edges = np.linspace(0, n, count + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


# --- worker processes of render_many ----------------------------------------------------------------------
_WORKER: DigitRenderer | None = None


def _worker_init(background: np.ndarray, settings: dict) -> None:
    global _WORKER
    _WORKER = DigitRenderer(background, **settings, workers=1)


def _worker_render(arrays: MeshArrays, T: np.ndarray, seeds: list, offset: int):
    return _render_range(_WORKER, arrays, T, seeds, offset)


def _render_range(renderer: DigitRenderer, arrays: MeshArrays, T: np.ndarray, seeds: list, offset: int):
    """Render poses T (k, 4, 4) of the sensor in the mesh frame -> images (k, H, W, 3), masks (k, H, W)."""
    n = len(T)
    images = np.empty((n, renderer.height, renderer.width, 3), dtype=np.uint8)
    masks = np.empty((n, renderer.height, renderer.width), dtype=bool)
    identity = np.eye(4)
    for i in range(n):
        try:
            result = renderer.render(arrays, identity, T[i], seeds[i])
        except InputError as exc:
            raise InputError(f"sensor pose {offset + i}: {exc}") from exc
        images[i], masks[i] = result.image, result.mask
    return images, masks
