"""Stage calibrate_patch: the contact-patch calibration that reads contact points and normals from images.

Renders ``contact_patch.n_presses`` simulated presses of random superquadrics with the DIGIT model of config
section ``render`` over a flat grey background and fits the colour-to-normal regression
(``tactile6d.patch.calibrate``). Writes ``artifacts/patch/model.npz`` (``contact_patch.save_model``), which the
estimator loads for ``select.contacts=patch``.
"""

from __future__ import annotations

import sys
import time

from tactile6d.core.errors import exit_on_error
from tactile6d.data import layout
from tactile6d.perception import contact_patch
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    t0 = time.perf_counter()
    renderer = contact_patch.calibration_renderer(cfg.render)
    model = contact_patch.calibrate(int(cfg.patch.n_presses), int(cfg.patch.seed), renderer)
    path = layout.patch_model_file(cfg.paths.artifacts_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    contact_patch.save_model(model, path)
    print(f"calibrated on {cfg.patch.n_presses} presses in {time.perf_counter() - t0:.1f} s -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
