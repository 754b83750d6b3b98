"""Stage encode_database: autoencoder latents of an object's database images and their latent angles.

Reads ``artifacts/databases/<name>.h5`` and ``artifacts/ae/model.pt``. Writes ``artifacts/latents/<name>.h5``
(with ``--distractor``: the database and latents under ``artifacts/distractors/``)
(schema ``latents``): ``latents`` (M, 128), ``latent_nc`` (128,) of the no-contact image, and ``angles``
(M,) = arccos(cos_sim(h, h_nc)) in radians, the angle tactile selection compares (docs/design.md, The method).
"""

from __future__ import annotations

import sys
import time

from tactile6d import autoencoder, layout
from tactile6d.config import parse_stage_args
from tactile6d.database import StoredImages
from tactile6d.errors import exit_on_error
from tactile6d.io import read_artifact, write_artifact
from tactile6d.stage_clock import timed


def main(argv: list[str] | None = None) -> int:
    args, cfg = parse_stage_args(argv, __doc__.splitlines()[0], per_object=True)
    artifacts = args.objects_dir
    db = read_artifact(layout.database_file(artifacts, args.object), "database")
    model, norm, ae_cfg = autoencoder.load_checkpoint(layout.ae_checkpoint(cfg.paths.artifacts_dir))
    start = time.perf_counter()
    background = db["background"]
    latents = autoencoder.encode(model, norm, StoredImages(db), background)
    latent_nc = autoencoder.encode(model, norm, db["no_contact"][None], background)[0]
    angles = autoencoder.latent_angles(latents, latent_nc)
    print(f"{args.object}: {len(latents)} images encoded in {time.perf_counter() - start:.1f} s; "
          f"angles {angles.min():.3f}-{angles.max():.3f} rad (median {float(sorted(angles)[len(angles) // 2]):.3f})")
    write_artifact(
        layout.latents_file(artifacts, args.object),
        "latents",
        {"latents": latents, "latent_nc": latent_nc, "angles": angles},
        attrs={"object": args.object},
        config={"ae": ae_cfg},
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
