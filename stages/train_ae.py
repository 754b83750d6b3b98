"""Stage train_ae: train the object-agnostic autoencoder on the superquadric training set only.

Reads ``artifacts/training_set.h5`` and config section ``ae``. With ``ae.rank_weight`` > 0 the loss also
orders the latent angles by the training images' contact types (tactile6d.perception.autoencoder). Writes
``artifacts/ae/model.pt`` (weights, normalisation, config, history), ``artifacts/ae/training_curve.csv``
(DVC plot: losses per epoch) and ``artifacts/ae/train.json`` (training time and final losses).
"""

from __future__ import annotations

import sys
import time

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact, write_json, write_text
from tactile6d.perception import autoencoder
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import contact_types
from tactile6d.sim.database import StoredImages


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    artifacts = cfg.paths.artifacts_dir
    training_set = read_artifact(layout.training_set_file(artifacts), "training_set")
    images = StoredImages(training_set)
    sharpness = None
    if autoencoder.AEConfig.from_cfg(section_to_dict(cfg, "ae")).rank_weight > 0.0:
        sharpness = contact_types.sharpness_ranks(training_set["contact_types"])
    start = time.perf_counter()
    model, norm, history = autoencoder.train(images, training_set["background"], section_to_dict(cfg, "ae"),
                                             seed=int(cfg.ae.seed), sharpness=sharpness,
                                             no_contact=training_set["no_contact"])
    seconds = time.perf_counter() - start
    autoencoder.save_checkpoint(layout.ae_checkpoint(artifacts), model, norm, section_to_dict(cfg, "ae"), history)

    out = layout.ae_dir(artifacts)
    rows = ["epoch,train_loss,val_loss,rank_loss"] + [
        f"{e + 1},{t:.6g},{v:.6g},{r:.6g}"
        for e, (t, v, r) in enumerate(zip(history["train_loss"], history["val_loss"], history["rank_loss"]))
    ]
    write_text(out / "training_curve.csv", "\n".join(rows) + "\n")
    write_json(out / "train.json", {
        "train_seconds": seconds,
        "cpu_seconds": float(sum(history["cpu_seconds"])),
        "n_train": history["n_train"],
        "n_val": history["n_val"],
        "final_train_loss": history["train_loss"][-1],
        "final_val_loss": history["val_loss"][-1],
        "final_rank_loss": history["rank_loss"][-1],
        "device": history["device"],
    })
    print(f"train_ae: {len(images)} images, {len(history['train_loss'])} epochs in {seconds:.0f} s, "
          f"val loss {history['val_loss'][-1]:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
