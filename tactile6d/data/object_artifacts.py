"""Reading one object's stage artifacts by name, without DVC: the first thing every caller of the
estimator does, and the usual place for a first-run error, so a missing file names the command that
makes it.

The loaders of artifacts that need heavier modules live beside the step that uses them: the latent
angles and the no-contact image in ``perception.encode``, the collision pieces and the refinement surface
in ``estimation.rank``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactile6d.core.errors import ArtifactError
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact

# The per-object stages as dvc.yaml names them for the identification library's distractors, whose
# artifacts live under ``layout.distractors_dir``: one stage each for the whole library.
DISTRACTOR_STAGES = {"prepare_object": "prepare_distractors", "sample_surface": "sample_distractors",
                     "render_database": "render_distractors", "encode_database": "encode_distractors"}


def require(path: Path, stage: str, name: str | None = None) -> Path:
    """``path`` if it is a file; else an ArtifactError naming the DVC stage that makes it (for object
    ``name`` when the stage runs per object; a distractor's stage makes the whole library)."""
    if not path.is_file():
        if name is not None and path.parent.parent.name == layout.distractors_dir("").name:
            stage, name = DISTRACTOR_STAGES.get(stage, stage), None
        target = stage if name is None else f"{stage}@{name}"
        raise ArtifactError(f"{path}: missing; make it with `dvc repro {target}` (or `dvc repro` for all)")
    return path


def load_surface_points(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The object's M database points (M, 3), object frame, m (stage sample_surface)."""
    path = require(layout.surface_file(artifacts_dir, name), "sample_surface", name)
    return np.asarray(read_artifact(path, "surface")["points"], dtype=np.float64)


def load_surface_normals(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The database points' outward unit normals (M, 3), object frame (stage sample_surface)."""
    path = require(layout.surface_file(artifacts_dir, name), "sample_surface", name)
    return np.asarray(read_artifact(path, "surface")["normals"], dtype=np.float64)
