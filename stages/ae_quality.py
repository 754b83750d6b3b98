"""Stage ae_quality: how well the autoencoder's latent angle tells contacts apart, on objects it never saw.

Reads every object's ``latents``, ``surfaces`` and ``objects`` artifacts, the ``caddeo2023`` scenes, the
checkpoint and ``artifacts/ae/train.json``. Writes ``artifacts/metrics/ae.json`` (DVC metrics) and
``artifacts/ae/angles_by_type.png``:
- ``train_seconds`` and the held-out reconstruction loss on superquadric images;
- the latent angle of the database points per contact type (the contact classifier of
  tactile6d.sim.contact_types), and ``auroc_flat_edge`` / ``auroc_edge_corner``: the AUROC of the angle as a score
  separating flat from edge and edge from corner contacts (larger for the flatter kind: a flat press
  changes more of the image), over all objects pooled and (``..._within_object``) over pairs of
  database points of the same object only, which is how selection uses the angle;
- ``triplet_angle_gap_median``: for each sensor of the paper's 40 triplets, the gap between its image's
  angle and the angle of the database point nearest its true contact point (same object), median over
  the 120 sensors (and its 90th percentile), to compare with ``select.delta_h``. (Not read here, so that
  changing delta_h does not re-run this stage.)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from tactile6d.core import metrics  # noqa: E402
from tactile6d.core.errors import exit_on_error  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact, write_json  # noqa: E402
from tactile6d.evaluation.latent_gaps import triplet_gaps  # noqa: E402
from tactile6d.perception import autoencoder  # noqa: E402
from tactile6d.runtime.stage_args import parse_stage_args  # noqa: E402
from tactile6d.runtime.stage_clock import timed  # noqa: E402
from tactile6d.sim import contact_types, surface_sampling  # noqa: E402


def database_types(artifacts: str, name: str, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    obj = read_artifact(layout.object_file(artifacts, name), "object")
    mesh = trimesh.Trimesh(obj["vertices"], obj["faces"], process=False)
    return contact_types.classify_contacts(surface_sampling.sample_surface(mesh), points, normals)


def plot_angles(by_type: dict[str, np.ndarray], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6, 3.5))
    kinds = [k for k in contact_types.CONTACT_TYPES if len(by_type[k])]
    ax.boxplot([by_type[k] for k in kinds], showfliers=False)
    ax.set_xticks(range(1, len(kinds) + 1), [f"{k}\n(n={len(by_type[k])})" for k in kinds])
    ax.set_ylabel("latent angle to no contact (rad)")
    ax.set_title("Database points of the YCB objects, by contact type")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    artifacts = cfg.paths.artifacts_dir
    names = list(cfg.objects.names)
    angles, points, types = {}, {}, {}
    for name in names:
        surface = read_artifact(layout.surface_file(artifacts, name), "surface")
        angles[name] = read_artifact(layout.latents_file(artifacts, name), "latents")["angles"]
        points[name] = surface["points"]
        types[name] = database_types(artifacts, name, surface["points"], surface["normals"])
    all_angles, all_types = np.concatenate(list(angles.values())), np.concatenate(list(types.values()))
    all_objects = np.concatenate([np.full(len(types[name]), name) for name in names])
    by_type = {kind: all_angles[all_types == code] for code, kind in enumerate(contact_types.CONTACT_TYPES)}
    objects_by_type = {kind: all_objects[all_types == code] for code, kind in enumerate(contact_types.CONTACT_TYPES)}

    def auroc_within_objects(positive: str, negative: str) -> float:
        return metrics.auroc_within_groups(by_type[positive], by_type[negative],
                                           objects_by_type[positive], objects_by_type[negative])

    model, norm, _ = autoencoder.load_checkpoint(layout.ae_checkpoint(artifacts))
    background = read_artifact(layout.database_file(artifacts, names[0]), "database")["background"]
    gaps = triplet_gaps(artifacts, angles, points, model, norm, background)
    train = json.loads((layout.ae_dir(artifacts) / "train.json").read_text())

    figures = {
        "train_seconds": train["train_seconds"],
        "heldout_recon_loss": train["final_val_loss"],
        "auroc_flat_edge": metrics.auroc(by_type["flat"], by_type["edge"]),
        "auroc_edge_corner": metrics.auroc(by_type["edge"], by_type["corner"]),
        "auroc_flat_edge_within_object": auroc_within_objects("flat", "edge"),
        "auroc_edge_corner_within_object": auroc_within_objects("edge", "corner"),
        "triplet_angle_gap_median": float(np.median(gaps)) if gaps.size else float("nan"),
        "triplet_angle_gap_p90": float(np.quantile(gaps, 0.9)) if gaps.size else float("nan"),
        "angle_median_by_type": {k: float(np.median(v)) if len(v) else float("nan") for k, v in by_type.items()},
        "count_by_type": {k: int(len(v)) for k, v in by_type.items()},
    }
    write_json(layout.metrics_file(artifacts, "ae"), figures)
    plot_angles(by_type, layout.ae_dir(artifacts) / "angles_by_type.png")
    print("ae_quality: " + ", ".join(f"{k} {v:.3f}" for k, v in figures.items() if isinstance(v, float)))
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
