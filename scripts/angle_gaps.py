"""How far each sensor's latent angle lies from that of the database point at its true contact.

    python scripts/angle_gaps.py --artifacts artifacts --scenes validation
    python scripts/angle_gaps.py --artifacts artifacts --scenes offaxis --centre   # select.centre_images

For every sensor of the scene set: the gap between its image's latent angle and the angle of the
database point nearest its true contact (``tactile6d.latent_gaps.triplet_gaps``, which the ``ae_quality``
stage runs on caddeo2023). Prints one JSON line: the median and 90th percentile of the gap (rad), and
the share of sensors whose gap is under ``select.delta_h``, i.e. whose true contact point survives the
tactile selection's first threshold. Reads the artifacts of the pipeline (checkpoint, latents,
surfaces, scenes); writes nothing. Compare autoencoders by running it after each ``dvc exp run``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config
from tactile6d.core.settings import SelectSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.evaluation.latent_gaps import triplet_gaps
from tactile6d.perception import autoencoder
from tactile6d.perception.encode import centre_images, load_patch_model, read_contacts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", default="validation", help="scene set: validation, offaxis or caddeo2023")
    parser.add_argument("--centre", action="store_true",
                        help="move each image's contact (read from its patch) to the image centre first")
    parser.add_argument("overrides", nargs="*", help="config overrides (objects, select.delta_h)")
    args = parser.parse_args()
    cfg = compose_config(args.overrides)
    names = list(cfg.objects.names)
    angles = {n: read_artifact(layout.latents_file(args.artifacts, n), "latents")["angles"] for n in names}
    points = {n: read_artifact(layout.surface_file(args.artifacts, n), "surface")["points"] for n in names}
    model, norm, _ = autoencoder.load_checkpoint(layout.ae_checkpoint(args.artifacts))
    background = read_artifact(layout.database_file(args.artifacts, names[0]), "database")["background"]
    prepare = None
    if args.centre:
        settings = SelectSettings.from_cfg({**cfg.select, "method": "ours", "contacts": "patch"})
        patch_model = load_patch_model(args.artifacts)

        def prepare(images, T_world_sensors):
            contacts = read_contacts(settings, T_world_sensors, images, background, patch_model)
            return centre_images(images, background, contacts, T_world_sensors)

    gaps = triplet_gaps(args.artifacts, angles, points, model, norm, background, args.scenes, prepare)
    delta_h = float(cfg.select.delta_h)
    print(json.dumps({"scenes": args.scenes, "centred": args.centre, "sensors": int(gaps.size), "gap_median": float(np.median(gaps)),
                      "gap_p90": float(np.quantile(gaps, 0.9)), "delta_h": delta_h,
                      "share_under_delta_h": float(np.mean(gaps < delta_h))}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
