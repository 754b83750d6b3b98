"""Where each artifact lives under the artifacts directory (the paths dvc.yaml declares)."""

from __future__ import annotations

from pathlib import Path

# Per-object artifacts live in one folder per kind (``<artifacts>/<kind>/<object>.h5``), so a stage
# that needs one kind for every object can depend on exactly that folder in dvc.yaml.


def distractors_dir(artifacts_dir: str | Path) -> Path:
    """Where the identification library's distractors keep their per-object artifacts: the same layout
    (``objects/``, ``surfaces/``, ``databases/``, ``latents/``) one level down, so that adding distractors
    leaves the folders the evaluation stages depend on untouched (stages run with ``--distractor``)."""
    return Path(artifacts_dir) / "distractors"


def own_dir(artifacts_dir: str | Path) -> Path:
    """Where the user's own objects (config section ``own``: mesh files) keep their per-object artifacts, in
    the same layout one level down, so that adding one re-runs no stage that reads the YCB objects' folders
    (stages run with ``--own``)."""
    return Path(artifacts_dir) / "own"


def third_party_meshes_dir(artifacts_dir: str | Path) -> Path:
    """The meshes copied out of an installed package by stage import_package_meshes (config section ``own_set``)."""
    return Path(artifacts_dir) / "third_party"


def third_party_mesh_file(artifacts_dir: str | Path, name: str, suffix: str) -> Path:
    """The copy of own object ``name``'s packaged mesh, keeping the file's suffix (``.obj``, ``.stl``...)."""
    return third_party_meshes_dir(artifacts_dir) / f"{name}{suffix}"


def object_file(artifacts_dir: str | Path, name: str) -> Path:
    """Cleaned mesh, collision pieces, metric points (stage prepare_object)."""
    return Path(artifacts_dir) / "objects" / f"{name}.h5"


def collision_metrics_file(artifacts_dir: str | Path, name: str) -> Path:
    """How well the collision pieces cover the object (stage prepare_object)."""
    return Path(artifacts_dir) / "metrics" / "collision" / f"{name}.json"


def surface_file(artifacts_dir: str | Path, name: str) -> Path:
    """M surface points and normals (stage sample_surface)."""
    return Path(artifacts_dir) / "surfaces" / f"{name}.h5"


def database_file(artifacts_dir: str | Path, name: str) -> Path:
    """Rendered tactile image of a DIGIT touching each surface point (stage render_database)."""
    return Path(artifacts_dir) / "databases" / f"{name}.h5"


def latents_file(artifacts_dir: str | Path, name: str) -> Path:
    """Autoencoder latents and latent angles of the database images (stage encode_database)."""
    return Path(artifacts_dir) / "latents" / f"{name}.h5"


def training_set_file(artifacts_dir: str | Path) -> Path:
    """Tactile images of superquadric contacts (stage make_training_set)."""
    return Path(artifacts_dir) / "training_set.h5"


def ae_dir(artifacts_dir: str | Path) -> Path:
    """The trained autoencoder, its training curve and quality figures (stage train_ae)."""
    return Path(artifacts_dir) / "ae"


def ae_checkpoint(artifacts_dir: str | Path) -> Path:
    return ae_dir(artifacts_dir) / "model.pt"


def patch_model_file(artifacts_dir: str | Path) -> Path:
    """The contact-patch calibration (stage calibrate_patch)."""
    return Path(artifacts_dir) / "patch" / "model.npz"


def scenes_file(artifacts_dir: str | Path, scene_set: str) -> Path:
    """Scenes with ground truth (stage make_scenes): ``caddeo2023`` or ``validation``."""
    return Path(artifacts_dir) / "scenes" / f"{scene_set}.h5"


def sequences_file(artifacts_dir: str | Path, name: str) -> Path:
    """Tracking sequences with ground truth (stage make_sequences): ``tracking``."""
    return Path(artifacts_dir) / "sequences" / f"{name}.h5"


def run_dir(artifacts_dir: str | Path, scene_set: str, method: str) -> Path:
    """Outputs of select_tuples, optimize, rank for one scene set and method (ours, baseline)."""
    return Path(artifacts_dir) / "runs" / scene_set / method


def metrics_file(artifacts_dir: str | Path, name: str) -> Path:
    """DVC metrics: ``<artifacts>/metrics/<name>.json``."""
    return Path(artifacts_dir) / "metrics" / f"{name}.json"


def identify_calibration_file(artifacts_dir: str | Path) -> Path:
    """The identification score's weights fitted on the validation scenes (stage calibrate_identify)."""
    return Path(artifacts_dir) / "identify" / "calibration.json"


def confidence_model_file(artifacts_dir: str | Path) -> Path:
    """The confidence's logistic model (stage calibrate_confidence; ``confidence.ConfidenceModel``)."""
    return Path(artifacts_dir) / "confidence" / "model.json"
