"""A user's mesh file as a tactile6d object: read in its declared units, checked, repaired where a repair
is safe (and reported), refused with one clear error otherwise, so that no database is built on garbage.

A robotics user's object is usually an STL in millimetres from CAD, or an OBJ/PLY/GLB from a scan. What
is checked, in this order:

1. **A mesh at all**: a file trimesh cannot read, or one without triangles, is a ``MeshError``.
2. **Units**: the file's coordinates times ``UNITS[units]`` times ``scale`` must give an object whose
   longest side lies between ``MIN_SIDE`` and ``MAX_SIDE`` (a DIGIT's gel is 2 x 3 cm; a hand holds
   objects of a few centimetres to a metre). Otherwise the error names the size it would have and the
   units that would make it plausible (a CAD file in millimetres declared as metres is 1000 times too big).
3. **Degenerate and duplicate faces** (zero area, or the same three vertices twice): dropped, reported.
4. **Several bodies**: tactile6d estimates one rigid object. Loose pieces that together hold under
   ``LOOSE_AREA`` of the surface (scan debris) are dropped and reported; two or more real bodies are
   an error.
5. **Holes**: a surface that is not closed is closed with ``trimesh.repair.fill_holes`` and reported;
   one that stays open (non-manifold edges, holes too large to fill) is an error, since the contact
   types, the collision geometry and the inside/outside tests need a closed surface.

The mesh returned is in metres, in the file's frame moved by ``offset`` (metres, after scaling).

``MeshSource`` is one entry of config section ``own`` (the user's own objects: name -> mesh file, units,
scale, offset), checked; ``own_objects(cfg)`` gives them all.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from tactile6d.core.errors import ConfigError, MeshError
from tactile6d.sim.meshes import load_mesh_file

# Length of one file unit in metres.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
# The longest side of an object a hand's DIGITs can hold and touch, metres.
MIN_SIDE, MAX_SIDE = 0.005, 1.5
# Loose pieces holding less than this share of the surface area together are debris, not a second body.
LOOSE_AREA = 0.01


@dataclass
class ImportReport:
    """What was read and what was done to it: the file, its declared units and scale, face counts before and
    after, the object's extents (m) and one line per repair."""

    path: str
    units: str
    scale: float
    faces_in: int
    faces: int = 0
    extents_m: list[float] = field(default_factory=list)
    repairs: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return dict(vars(self))


# An own object's name is a file name of its artifacts and part of DVC stage names (prepare_own@<name>).
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
SOURCE_KEYS = ("mesh", "units", "scale", "offset")


@dataclass(frozen=True)
class MeshSource:
    """A user's object as config section ``own`` declares it: its name, the mesh file (absolute, or relative
    to the directory the stages run in, the repository root), the file's length unit (a key of ``UNITS``),
    a scale on top of it and an offset in metres added after scaling."""

    name: str
    mesh: Path
    units: str
    scale: float = 1.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_config(cls, name: str, entry: Mapping) -> MeshSource:
        """``own.<name>`` -> its source; ConfigError naming the key for a bad name, an unknown or missing key,
        unknown units, a scale that is not positive or an offset that is not three numbers."""
        where = f"own.{name}"
        if not NAME_PATTERN.fullmatch(str(name)):
            raise ConfigError(f"{where}: an object's name may hold letters, digits, '_', '.' and '-' only, and "
                              "must start with a letter or digit (it names files and DVC stages)")
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{where}: expected a mapping with keys {', '.join(SOURCE_KEYS)}, got {entry!r}")
        unknown = sorted(set(map(str, entry)) - set(SOURCE_KEYS))
        if unknown:
            raise ConfigError(f"{where}: unknown key{'s' * (len(unknown) > 1)} {', '.join(unknown)}; "
                              f"an entry has {', '.join(SOURCE_KEYS)}")
        for key in ("mesh", "units"):
            if entry.get(key) in (None, ""):
                raise ConfigError(f"{where}.{key} is missing")
        units = str(entry["units"])
        if units not in UNITS:
            raise ConfigError(f"{where}.units: {units!r} unknown; one of {', '.join(UNITS)}")
        scale = float(entry.get("scale", 1.0))
        if not np.isfinite(scale) or scale <= 0:
            raise ConfigError(f"{where}.scale must be a positive number, got {entry.get('scale')!r}")
        offset = np.asarray(list(entry.get("offset", (0.0, 0.0, 0.0))), dtype=np.float64)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise ConfigError(f"{where}.offset must be three numbers (metres), got {entry.get('offset')!r}")
        return cls(str(name), Path(str(entry["mesh"])), units, scale, tuple(float(v) for v in offset))

    def load(self) -> tuple[trimesh.Trimesh, ImportReport]:
        """The mesh in metres, checked and repaired, and the report (``import_mesh``)."""
        return import_mesh(self.mesh, self.units, self.scale, self.offset)


def own_objects(cfg) -> dict[str, MeshSource]:
    """Config section ``own`` (absent or empty: no own objects), each entry checked (``MeshSource.from_config``)."""
    section = cfg.get("own") if hasattr(cfg, "get") else None
    return {str(name): MeshSource.from_config(str(name), entry) for name, entry in (section or {}).items()}


def check_units(extents: np.ndarray, units: str, scale: float, path: str | Path) -> None:
    """MeshError when the object's longest side (``extents`` in file units) in ``units`` times ``scale`` is not
    between ``MIN_SIDE`` and ``MAX_SIDE``, naming the units that would make it plausible."""
    if units not in UNITS:
        raise MeshError(f"units {units!r} unknown; one of {', '.join(UNITS)}")
    longest = float(np.max(extents))
    size = longest * UNITS[units] * scale
    if MIN_SIDE <= size <= MAX_SIDE:
        return
    # Units in which the object would have a hand-held size of 2-50 cm.
    sizes = {u: longest * metres * scale for u, metres in UNITS.items()}
    plausible = [(u, metres) for u, metres in sizes.items() if 0.02 <= metres <= 0.5]
    hint = "".join(f" Declared as {u!r} it would be {_length(metres)}." for u, metres in plausible)
    raise MeshError(f"{path}: in {units} (scale {scale:g}) the object's longest side is {_length(size)}, outside "
                    f"{_length(MIN_SIDE)}-{_length(MAX_SIDE)}: wrong units?{hint.rstrip('.')}")


def _length(metres: float) -> str:
    return f"{metres * 1000:.3g} mm" if metres < 0.01 else f"{metres * 100:.3g} cm" if metres < 1 else f"{metres:.3g} m"


def import_mesh(path: str | Path, units: str, scale: float = 1.0,
                offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[trimesh.Trimesh, ImportReport]:
    """Read, check and repair a user's mesh (module docstring) -> (mesh in metres, what was done)."""
    raw = load_mesh_file(path)  # file units; MeshError for a missing file or one that is not a mesh
    report = ImportReport(str(path), units, float(scale), int(len(raw.faces)))
    check_units(raw.extents, units, scale, path)
    mesh = trimesh.Trimesh(raw.vertices * UNITS[units] * scale + np.asarray(offset, dtype=np.float64), raw.faces,
                           process=False)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)  # a scan's UV seams split vertices
    for name, keep in (("degenerate", lambda: mesh.nondegenerate_faces(height=1e-12)),
                       ("duplicate", mesh.unique_faces)):
        mask = _as_mask(keep(), len(mesh.faces))
        dropped = int(np.count_nonzero(~mask))
        if dropped:
            mesh.update_faces(mask)
            report.repairs.append(f"dropped {dropped} {name} face{'s' * (dropped > 1)}")
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise MeshError(f"{path}: no triangle of non-zero area")
    mesh = _one_body(mesh, report, path)
    if not mesh.is_watertight:
        trimesh.repair.fill_holes(mesh)
        if not mesh.is_watertight:
            raise MeshError(f"{path}: the surface is not closed and filling its holes does not close it "
                            f"({_open_edges(mesh)} edges bound one face only or more than two): close it in a "
                            "modelling tool; contact types, collision and inside tests need a closed surface")
        report.repairs.append("closed its holes (trimesh.repair.fill_holes)")
    trimesh.repair.fix_winding(mesh)
    if mesh.volume < 0:
        mesh.invert()
        report.repairs.append("turned its faces outward")
    report.faces, report.extents_m = int(len(mesh.faces)), [float(e) for e in mesh.extents]
    return mesh, report


def _one_body(mesh: trimesh.Trimesh, report: ImportReport, path) -> trimesh.Trimesh:
    """The mesh as one body: loose pieces under ``LOOSE_AREA`` of the area dropped (reported); MeshError for
    two or more bodies larger than that."""
    bodies = mesh.split(only_watertight=False)
    if len(bodies) <= 1:
        return mesh
    areas = np.array([b.area for b in bodies])
    order = np.argsort(-areas)
    loose = areas[order[1:]].sum() / areas.sum()
    if loose >= LOOSE_AREA:
        shares = ", ".join(f"{100 * a / areas.sum():.0f} %" for a in areas[order[:4]])
        raise MeshError(f"{path}: {len(bodies)} separate bodies (their shares of the surface: {shares}"
                        f"{', ...' if len(bodies) > 4 else ''}); tactile6d estimates one rigid object: join them "
                        "or keep one in a modelling tool")
    report.repairs.append(f"dropped {len(bodies) - 1} loose piece{'s' * (len(bodies) > 2)} "
                          f"({100 * loose:.2g} % of the surface)")
    return bodies[order[0]]


def _as_mask(keep: np.ndarray, n: int) -> np.ndarray:
    """trimesh's face selections (a boolean mask or indices) as a boolean mask of n faces."""
    keep = np.asarray(keep)
    if keep.dtype == bool:
        return keep
    mask = np.zeros(n, dtype=bool)
    mask[keep] = True
    return mask


def _open_edges(mesh: trimesh.Trimesh) -> int:
    """Edges not shared by exactly two faces."""
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return int(np.count_nonzero(counts != 2))
