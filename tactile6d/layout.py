"""Where each artifact lives under the artifacts directory (the paths dvc.yaml declares)."""

from __future__ import annotations

from pathlib import Path


def object_dir(artifacts_dir: str | Path, name: str) -> Path:
    """Per-object artifacts: ``<artifacts>/objects/<name>/``."""
    return Path(artifacts_dir) / "objects" / name


def object_file(artifacts_dir: str | Path, name: str) -> Path:
    """Cleaned mesh, collision pieces, metric points (stage prepare_object)."""
    return object_dir(artifacts_dir, name) / "object.h5"


def collision_metrics_file(artifacts_dir: str | Path, name: str) -> Path:
    """How well the collision pieces cover the object (stage prepare_object)."""
    return object_dir(artifacts_dir, name) / "collision.json"


def surface_file(artifacts_dir: str | Path, name: str) -> Path:
    """M surface points and normals (stage sample_surface)."""
    return object_dir(artifacts_dir, name) / "surface.h5"
