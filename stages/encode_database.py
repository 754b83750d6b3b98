"""Stage encode_database: autoencoder latents of an object's database images and their latent angles.

Reads ``artifacts/databases/<name>.h5`` and ``artifacts/ae/model.pt``. Writes ``artifacts/latents/<name>.h5``
(with ``--distractor``, or ``--distractors`` for the whole identification library in one run: the
databases and latents under ``artifacts/distractors/``)
(schema ``latents``): ``latents`` (M, 128), ``latent_nc`` (128,) of the no-contact image, and ``angles``
(M,) = arccos(cos_sim(h, h_nc)) in radians, the angle tactile selection compares (docs/design.md, The method).
"""

from __future__ import annotations

import sys
import time

from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_artifact
from tactile6d.perception import autoencoder
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim.database import StoredImages


def encode_object(name: str, artifacts, model, norm, ae_cfg: dict) -> None:
    """Write ``artifacts/latents/<name>.h5`` under ``artifacts`` from the object's database there."""
    db = read_artifact(layout.database_file(artifacts, name), "database")
    start = time.perf_counter()
    background = db["background"]
    latents = autoencoder.encode(model, norm, StoredImages(db), background)
    latent_nc = autoencoder.encode(model, norm, db["no_contact"][None], background)[0]
    angles = autoencoder.latent_angles(latents, latent_nc)
    print(f"{name}: {len(latents)} images encoded in {time.perf_counter() - start:.1f} s; "
          f"angles {angles.min():.3f}-{angles.max():.3f} rad (median {float(sorted(angles)[len(angles) // 2]):.3f})")
    write_artifact(
        layout.latents_file(artifacts, name),
        "latents",
        {"latents": latents, "latent_nc": latent_nc, "angles": angles},
        attrs={"object": name},
        config={"ae": ae_cfg},
    )


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    model, norm, ae_cfg = autoencoder.load_checkpoint(layout.ae_checkpoint(cfg.paths.artifacts_dir))
    for name in args.names:
        encode_object(name, args.objects_dir, model, norm, ae_cfg)
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
