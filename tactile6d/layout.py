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


def database_file(artifacts_dir: str | Path, name: str) -> Path:
    """Rendered tactile image of a DIGIT touching each surface point (stage render_database)."""
    return object_dir(artifacts_dir, name) / "database.h5"


def latents_file(artifacts_dir: str | Path, name: str) -> Path:
    """Autoencoder latents and latent angles of the database images (stage encode_database)."""
    return object_dir(artifacts_dir, name) / "latents.h5"


def training_set_file(artifacts_dir: str | Path) -> Path:
    """Tactile images of superquadric contacts (stage make_training_set)."""
    return Path(artifacts_dir) / "training_set.h5"


def ae_dir(artifacts_dir: str | Path) -> Path:
    """The trained autoencoder, its training curve and quality figures (stage train_ae)."""
    return Path(artifacts_dir) / "ae"


def ae_checkpoint(artifacts_dir: str | Path) -> Path:
    return ae_dir(artifacts_dir) / "model.pt"


def scenes_file(artifacts_dir: str | Path, scene_set: str) -> Path:
    """Scenes with ground truth (stage make_scenes): ``caddeo2023`` or ``validation``."""
    return Path(artifacts_dir) / "scenes" / f"{scene_set}.h5"


def run_dir(artifacts_dir: str | Path, scene_set: str, method: str) -> Path:
    """Outputs of select_tuples, optimize, rank for one scene set and method (ours, baseline)."""
    return Path(artifacts_dir) / "runs" / scene_set / method


def metrics_file(artifacts_dir: str | Path, name: str) -> Path:
    """DVC metrics: ``<artifacts>/metrics/<name>.json``."""
    return Path(artifacts_dir) / "metrics" / f"{name}.json"
