"""Object meshes: loading, cleaning, unit checks, built-in primitives, collision geometry.

All meshes are ``trimesh.Trimesh`` in metres, in the object's own frame (for YCB objects the frame
of the YCB-Video mesh file; docs/design.md, Conventions).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import trimesh

from tactile6d.core.errors import MeshError

# A DIGIT gel is 20 x 30 mm: objects are expected between a few millimetres and a couple of metres.
MIN_EXTENT, MAX_EXTENT = 0.005, 2.0
# Beyond these the units are certainly wrong (a YCB mesh in millimetres spans 100-250 "metres").
HARD_MIN_EXTENT, HARD_MAX_EXTENT = 0.001, 10.0


def load_mesh_file(path: str | Path, scale: float = 1.0) -> trimesh.Trimesh:
    """Read a mesh file (OBJ, STL, PLY, ...) as one triangle mesh, scaled by ``scale``.

    Only geometry is kept: texture coordinates and per-vertex normals split vertices along UV seams,
    which would make a closed scan look open, so vertices at the same position are merged.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file {path} not found")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # missing .mtl / texture files are irrelevant here
            loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(f"cannot read mesh {path}: {' '.join(str(exc).split())}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"mesh {path} has no triangles")
    mesh = trimesh.Trimesh(vertices=np.asarray(loaded.vertices, dtype=np.float64) * scale,
                           faces=np.asarray(loaded.faces), process=False)
    return mesh


def clean_mesh(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, dict]:
    """Merge duplicate vertices, drop duplicate and degenerate faces, orient the faces outward.

    Returns the cleaned mesh and a report (counts before/after, watertightness). A mesh that stays
    open (040_large_marker has non-manifold seams) is kept: sampling and rendering need only
    consistent outward normals; the collision geometry is made watertight separately.
    """
    report = {"vertices_in": int(len(mesh.vertices)), "faces_in": int(len(mesh.faces))}
    mesh = mesh.copy()
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    mesh.update_faces(mesh.unique_faces())
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-12))
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0 or mesh.area <= 0:
        raise MeshError("mesh is degenerate: no triangle of non-zero area")
    if not mesh.is_watertight:
        trimesh.repair.fill_holes(mesh)
    trimesh.repair.fix_winding(mesh)
    # Outward orientation: a closed (or nearly closed) surface wound inward has negative volume.
    if mesh.volume < 0:
        mesh.invert()
    report.update(
        vertices=int(len(mesh.vertices)),
        faces=int(len(mesh.faces)),
        watertight=bool(mesh.is_watertight),
        area_m2=float(mesh.area),
        volume_m3=float(mesh.volume),
    )
    return mesh, report


def check_units(mesh: trimesh.Trimesh, name: str = "mesh") -> None:
    """Fail on extents that only wrong units explain; warn on extents unusual for a DIGIT contact."""
    extents = mesh.extents
    largest = float(extents.max())
    if largest > HARD_MAX_EXTENT:
        raise MeshError(
            f"{name}: largest extent is {largest:.4g} m; the mesh looks like it is in millimetres "
            f"(set prepare.scale=0.001)"
        )
    if largest < HARD_MIN_EXTENT:
        raise MeshError(f"{name}: largest extent is {largest:.3g} m; wrong units? (set prepare.scale)")
    if largest > MAX_EXTENT or extents.min() < MIN_EXTENT:
        warnings.warn(
            f"{name}: extents {np.round(extents, 4).tolist()} m lie outside {MIN_EXTENT}-{MAX_EXTENT} m; check the units",
            stacklevel=2,
        )


# --- built-in primitives ------------------------------------------------------------------------

def _rounded_box(extents: tuple[float, float, float], radius: float) -> trimesh.Trimesh:
    """A box with all edges and corners rounded: the hull of 8 spheres at the inner box's corners."""
    inner = np.asarray(extents) / 2.0 - radius
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * inner
    points = (sphere.vertices[None, :, :] + corners[:, None, :]).reshape(-1, 3)
    return trimesh.convex.convex_hull(points)


def _primitives() -> dict:
    return {
        "prim_box": lambda: trimesh.creation.box(extents=(0.10, 0.06, 0.04)),
        "prim_cylinder": lambda: trimesh.creation.cylinder(radius=0.03, height=0.10, sections=96),
        "prim_sphere": lambda: trimesh.creation.icosphere(subdivisions=5, radius=0.04),
        "prim_rounded_box": lambda: _rounded_box((0.08, 0.06, 0.05), 0.008),
    }


PRIMITIVE_NAMES = tuple(_primitives())

# Procedural shapes ``shape_<k>`` (k = 0, 1, 2, ...): distractors of YCB-like size for identification over a
# library (docs/identification.md). Shape k is drawn from a generator seeded with k alone, so a library
# of any size is reproducible and adding shapes leaves the others as they were.
PROCEDURAL_PREFIX = "shape_"
PROCEDURAL_KINDS = ("box", "rounded_box", "cylinder", "capsule", "ellipsoid", "prism", "superquadric")
# Extents (metres) like the YCB objects': the longest side 6-22 cm (a tuna can's 8.5 cm to a bleach
# bottle's 25 cm), the others shorter by up to these ratios, none under 2 cm (a marker is 1.8 cm thick).
_LONGEST_RANGE, _RATIO_RANGE, _MIN_SIDE = (0.06, 0.22), (0.35, 1.0), 0.02


def is_procedural(name: str) -> bool:
    """True for ``shape_<k>``, k a non-negative integer written without leading zeros."""
    index = name[len(PROCEDURAL_PREFIX):]
    return name.startswith(PROCEDURAL_PREFIX) and index.isdigit() and str(int(index)) == index


def is_primitive(name: str) -> bool:
    """True for the objects made in code: the built-in primitives and the procedural shapes."""
    return name in PRIMITIVE_NAMES or is_procedural(name)


def procedural_shape(index: int) -> tuple[str, np.ndarray, trimesh.Trimesh]:
    """Procedural shape number ``index`` -> (kind, extents (3,) metres, mesh centred at its origin).

    The kind is one of ``PROCEDURAL_KINDS`` (uniformly); the longest side lies along x.
    A rounded box's radius is 3-10 mm (at most a third of its shortest side), a prism has 3 to 8 sides,
    a superquadric's exponents are 0.3-1.5 (from box-like to pinched).
    """
    rng = np.random.default_rng(index)
    kind = PROCEDURAL_KINDS[rng.integers(len(PROCEDURAL_KINDS))]
    longest = rng.uniform(*_LONGEST_RANGE)
    middle = max(longest * rng.uniform(*_RATIO_RANGE), _MIN_SIDE)
    shortest = max(middle * rng.uniform(*_RATIO_RANGE), _MIN_SIDE)
    x, y, z = longest, middle, shortest
    if kind == "box":
        mesh = trimesh.creation.box(extents=(x, y, z))
    elif kind == "rounded_box":
        mesh = _rounded_box((x, y, z), min(rng.uniform(0.003, 0.010), z / 3))
    elif kind in ("cylinder", "prism", "capsule"):
        # Round (or polygonal) cross-section of the two shorter sides' mean diameter, axis along x.
        radius = (y + z) / 4
        if kind == "capsule":
            mesh = trimesh.creation.capsule(height=x - 2 * radius, radius=radius, count=(48, 48))
        else:
            sections = 96 if kind == "cylinder" else int(rng.integers(3, 9))
            mesh = trimesh.creation.cylinder(radius=radius, height=x, sections=sections)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    elif kind == "ellipsoid":
        mesh = trimesh.creation.icosphere(subdivisions=5)
        mesh.apply_scale((x / 2, y / 2, z / 2))
    else:
        from tactile6d.sim.superquadrics import Superquadric, superquadric_mesh

        e1, e2 = rng.uniform(0.3, 1.5, size=2)
        mesh = superquadric_mesh(Superquadric(x / 2, y / 2, z / 2, float(e1), float(e2)), max_edge=0.004, max_turn=0.1)
    # The mesh's own extents: a polygon's width across flats and an ellipsoid's tessellation fall short
    # of the drawn sizes by up to half of them.
    return kind, np.ptp(np.asarray(mesh.vertices), axis=0), mesh


def make_primitive(name: str) -> trimesh.Trimesh:
    """An object made in code by name (``PRIMITIVE_NAMES`` or ``shape_<k>``), centred at its origin, in metres."""
    if is_procedural(name):
        mesh = procedural_shape(int(name[len(PROCEDURAL_PREFIX):]))[2]
    else:
        makers = _primitives()
        if name not in makers:
            raise MeshError(f"unknown primitive {name!r}; known: {', '.join(PRIMITIVE_NAMES)} and "
                            f"{PROCEDURAL_PREFIX}<k> (procedural shape k = 0, 1, 2, ...)")
        mesh = makers[name]()
    return trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=True)


# --- collision geometry ---------------------------------------------------------------------------

ConvexPieces = list[tuple[np.ndarray, np.ndarray]]  # [(vertices (V,3), faces (F,3)), ...]


def convex_pieces_coacd(mesh: trimesh.Trimesh, threshold: float, max_pieces: int, seed: int) -> ConvexPieces:
    """Approximate convex decomposition with CoACD (handles open meshes by remeshing them first)."""
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        threshold=threshold,
        max_convex_hull=max_pieces,
        seed=seed,
    )
    return [_hull(np.asarray(v)) for v, _ in parts]


def convex_pieces_from_files(paths: list[Path]) -> ConvexPieces:
    """The convex hull of each file's vertices: what PhysX cooked from the paper's collision files."""
    return [_hull(load_mesh_file(p).vertices) for p in paths]


def _hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hull = trimesh.convex.convex_hull(points)
    return np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int64)


def pack_pieces(pieces: ConvexPieces) -> dict[str, np.ndarray]:
    """Concatenate convex pieces into flat arrays with offsets (for HDF5; read back by
    ``data.object_artifacts.load_collision_vertices``)."""
    vertices = np.concatenate([v for v, _ in pieces])
    faces = np.concatenate([f for _, f in pieces])
    return {
        "collision_vertices": vertices,
        "collision_faces": faces,
        "collision_vertex_offsets": np.cumsum([0] + [len(v) for v, _ in pieces]),
        "collision_face_offsets": np.cumsum([0] + [len(f) for _, f in pieces]),
    }


_HALF_SPACE_BLOCK = 2**22  # points x faces per half-space test (32 MB of float64)


def points_in_convex_pieces(points: np.ndarray, pieces: ConvexPieces) -> np.ndarray:
    """(n, 3) -> (n,) bool: inside at least one convex piece (half-space test on each hull)."""
    points = np.asarray(points, dtype=np.float64)
    inside = np.zeros(len(points), dtype=bool)
    for vertices, faces in pieces:
        hull = trimesh.Trimesh(vertices, faces, process=False)
        normals, origins = hull.face_normals, vertices[faces[:, 0]]
        offsets = np.einsum("fk,fk->f", normals, origins)
        # In chunks of points: a finely tessellated hull (a sphere's has 20 000 faces) against 200 000
        # points would be a 30 GB matrix at once.
        step = max(1, _HALF_SPACE_BLOCK // len(faces))
        for a in range(0, len(points), step):
            inside[a:a + step] |= np.all(points[a:a + step] @ normals.T <= offsets + 1e-9, axis=1)
    return inside


def collision_fidelity(mesh: trimesh.Trimesh, pieces: ConvexPieces, n: int, rng: np.random.Generator) -> dict:
    """How well convex pieces cover an object, by Monte Carlo over the mesh's bounding box.

    ``excess``: volume inside the pieces but outside the object, over the object's volume (false
    collisions: a sensor touching the real surface is reported as penetrating);
    ``missing``: volume of the object outside every piece, over its volume (missed penetrations).
    The object's inside is decided by ray parity, so it needs a watertight mesh; for an open mesh the
    figures are approximate.
    """
    lo, hi = mesh.bounds
    pad = 0.05 * (hi - lo)
    samples = rng.uniform(lo - pad, hi + pad, size=(n, 3))
    in_mesh = mesh.contains(samples)
    in_pieces = points_in_convex_pieces(samples, pieces)
    mesh_count = max(int(in_mesh.sum()), 1)
    return {
        "excess": float((in_pieces & ~in_mesh).sum() / mesh_count),
        "missing": float((in_mesh & ~in_pieces).sum() / mesh_count),
        "n_pieces": len(pieces),
    }
