"""Another DIGIT unit: what its own no-contact image is worth, and what the estimate gives without it.

    python -m stages.make_scenes --params params.yaml --scene-set validation render.background=digit/tacto/bg_digit_240_320.jpg paths.artifacts_dir=ART
    python scripts/unit_background.py --artifacts ART --scenes validation --background digit/tacto/bg_digit_240_320.jpg

The first command renders a set over another unit's no-contact image (TACTO's, in the data directory; ART a
scratch directory holding links to ``artifacts/``' folders but its own ``scenes/``). This estimates every scene
with the default estimator three ways: with that unit's no-contact image (``--background``, read as the
renderer reads it), with none (the estimator's default, the paper's unit), and with each sensor's no-contact
image estimated from all the set's images (``photometric.background_from_images``, as ``tactile6d estimate
--background from-scenes`` does). Prints per set and way the positional error of the best pose, mean (median) cm,
how many are over 1 cm off, and the estimated no-contact images' RMS difference from the unit's own (grey
levels). A diagnostic: it writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.data.third_party import DataStore  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.perception.photometric import background_from_images  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.render import DigitRenderer, load_background_bgr  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True, help="scene sets rendered over the other unit")
    parser.add_argument("--background", required=True, help="the other unit's no-contact image, data-relative "
                        "(the render.background the sets were made with)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)  # the estimator's default no-contact image stays the config's
    # The unit's own no-contact image exactly as the renderer put it under the images (RGB, resized).
    unit = compose_config([*args.overrides, f"render.background={args.background}"])
    renderer = DigitRenderer.from_config(unit.render, load_background_bgr(unit, DataStore(unit.paths)), workers=1)
    own = np.clip(np.rint(renderer.background), 0, 255).astype(np.uint8)
    estimators: dict[str, Estimator] = {}
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        images = np.asarray(scenes["images"])
        from_scenes = np.stack([background_from_images(images[:, i]) for i in range(images.shape[1])])
        rms = float(np.sqrt(np.mean((from_scenes.astype(np.float64) - own[None]) ** 2)))
        for way, backgrounds in (("own", own), ("none", None), ("from-scenes", from_scenes)):
            errors = []
            for s in range(len(scenes["names"])):
                obj = str(scenes["objects"][s])
                if obj not in estimators:
                    estimators[obj] = Estimator.from_artifacts(obj, args.artifacts, cfg)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # the light warnings of the unit not given its own image
                    best = estimators[obj].estimate(scenes["T_world_sensors"][s], images[s], backgrounds).best
                errors.append(100 * float(np.linalg.norm(best[:3, 3] - scenes["T_world_object"][s][:3, 3])))
            e = np.array(errors)
            note = f", no-contact images {rms:.1f} grey levels RMS from the unit's own" if way == "from-scenes" else ""
            print(f"{scene_set:12s} {way:12s} {e.mean():.2f} ({np.median(e):.2f}) cm, {int((e > 1).sum())} over 1 cm{note}",
                  flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
