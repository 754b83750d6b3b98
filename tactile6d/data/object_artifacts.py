"""Reading one object's stage artifacts by name, without DVC: the first thing every caller of the
estimator does, and the usual place for a first-run error, so a missing file names the command that
makes it.

Every per-object loader is here, and they share one cache (``read_object_artifact``): a file is read once
per process however many loaders, stages or estimators ask for it, and read again when it has been
re-made since. The arrays handed out are that cache's, so they are read-only; a caller that needs to
change one copies it. What callers build from them (collision models, surface samples, encoders) is
theirs to keep.
"""

from __future__ import annotations

import difflib
import functools
from pathlib import Path

import numpy as np
import trimesh

from tactile6d.core.errors import ArtifactError
from tactile6d.data import layout
from tactile6d.data.hdf5 import Artifact, read_artifact

# The per-object stages as dvc.yaml names them for the identification library's distractors, whose
# artifacts live under ``layout.distractors_dir``: one stage each for the whole library.
DISTRACTOR_STAGES = {"prepare_object": "prepare_distractors", "sample_surface": "sample_distractors",
                     "render_database": "render_distractors", "encode_database": "encode_distractors"}
# The per-object stages as dvc.yaml names them for your own objects (config section ``own``), whose artifacts
# live under ``layout.own_dir``: one stage each per object, ``<stage>@<name>``.
OWN_STAGES = {"prepare_object": "prepare_own", "sample_surface": "sample_own", "render_database": "render_own",
              "encode_database": "encode_own"}
# How many artifact files the cache keeps (three per object: object, surface and latents; the identification
# library has 10 objects and 8 distractors).
CACHED_FILES = 64


def require(path: Path, stage: str, name: str | None = None) -> Path:
    """``path`` if it is a file; else an ArtifactError naming the DVC stage that makes it (for object
    ``name`` when the stage runs per object; a distractor's stage makes the whole library), the name of an
    object with that artifact when ``name`` looks like a misspelling of it, or the artifacts directory when
    there is none."""
    if not path.is_file():
        library = path.parent.parent  # artifacts/, or its folder of distractors or of your own objects
        kind = library.name if library.name in (layout.distractors_dir("").name, layout.own_dir("").name) else None
        root = library.parent if kind else library
        if not root.is_dir():
            raise ArtifactError(f"{root}: no such artifacts directory; make the artifacts with `make reproduce` (or "
                                "`dvc repro`), or pass the folder that holds them")
        if name is not None and kind == layout.distractors_dir("").name:
            stage, name = DISTRACTOR_STAGES.get(stage, stage), None
        elif name is not None and kind == layout.own_dir("").name:
            stage = OWN_STAGES.get(stage, stage)
        target = stage if name is None else f"{stage}@{name}"
        raise ArtifactError(f"{path}: missing{_spelling_hint(path)}; make it with `dvc repro {target}` (or "
                            "`dvc repro` for all)")
    return path


def _spelling_hint(path: Path) -> str:
    """`` (did you mean '<name>'? ...)`` when a file beside ``path`` has a name close to its name, else ``""``."""
    others = sorted(p.stem for p in path.parent.glob(f"*{path.suffix}")) if path.parent.is_dir() else []
    close = difflib.get_close_matches(path.stem, others, n=1, cutoff=0.8)
    if not close:
        return ""
    return f" (did you mean {close[0]!r}? {path.parent} has {len(others)}: {', '.join(others)})"


def read_object_artifact(path: Path, schema: str, stage: str, name: str) -> Artifact:
    """The artifact at ``path`` (``require``'d, then ``hdf5.read_artifact``'d), from the cache when the file
    is unchanged since it was read (same size and modification time)."""
    stat = require(Path(path), stage, name).stat()
    return _read_cached(str(Path(path).resolve()), schema, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=CACHED_FILES)
def _read_cached(path: str, schema: str, mtime_ns: int, size: int) -> Artifact:
    artifact = read_artifact(path, schema)
    for array in artifact.data.values():
        if isinstance(array, np.ndarray):
            array.flags.writeable = False  # shared by every caller
    return artifact


def clear_cache() -> None:
    """Forget every cached artifact (tests; freeing memory)."""
    _read_cached.cache_clear()


def load_surface_points(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The object's M database points (M, 3), object frame, m (stage sample_surface)."""
    art = read_object_artifact(layout.surface_file(artifacts_dir, name), "surface", "sample_surface", name)
    return np.asarray(art["points"], dtype=np.float64)


def load_surface_normals(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The database points' outward unit normals (M, 3), object frame (stage sample_surface)."""
    art = read_object_artifact(layout.surface_file(artifacts_dir, name), "surface", "sample_surface", name)
    return np.asarray(art["normals"], dtype=np.float64)


def load_database_angles(artifacts_dir: str | Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The database images' latent angles (M,) rad and the no-contact latent (128,) (stage encode_database)."""
    art = read_object_artifact(layout.latents_file(artifacts_dir, name), "latents", "encode_database", name)
    return np.asarray(art["angles"], dtype=np.float64), np.asarray(art["latent_nc"], dtype=np.float32)


def _object(artifacts_dir: str | Path, name: str) -> Artifact:
    return read_object_artifact(layout.object_file(artifacts_dir, name), "object", "prepare_object", name)


def load_mesh(artifacts_dir: str | Path, name: str) -> trimesh.Trimesh:
    """The object's clean mesh (stage prepare_object), object frame, m: what the scenes are rendered from,
    render-and-compare ray-casts and ``refine`` samples (``surface_sampling.sample_surface``)."""
    art = _object(artifacts_dir, name)
    return trimesh.Trimesh(np.asarray(art["vertices"]), np.asarray(art["faces"]), process=False)


def load_metric_points(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The points the pose errors are measured on (N, 3), object frame, m (stage prepare_object)."""
    return np.asarray(_object(artifacts_dir, name)["metric_points"])


def load_collision_vertices(artifacts_dir: str | Path, name: str) -> list[np.ndarray]:
    """The vertices (V_k, 3) m of each of the object's convex collision pieces, as ``sim.meshes.pack_pieces``
    stored them (stage prepare_object): each piece is their convex hull (``collision.vertices_to_pieces``)."""
    data = _object(artifacts_dir, name).data
    offsets = data["collision_vertex_offsets"]
    return [data["collision_vertices"][offsets[k]: offsets[k + 1]] for k in range(len(offsets) - 1)]
