"""How much of each image agrees with a no-contact image: its own unit's, and other units'.

    python scripts/unit_agreement.py --artifacts artifacts --scenes validation offaxis variation kinematic caddeo2023 \
        --other digit/tacto/bg_digit_240_320.jpg
    python scripts/unit_agreement.py --artifacts ART --scenes validation --other digit/caddeo2023/background.png \
        render.background=digit/tacto/bg_digit_240_320.jpg

For every image of the scene sets, the share of its blocks that follow the fit of its light against a
no-contact image (``photometric.LightFit.agreement``): against its own unit's (the set's own no-contact
images where it has them, else ``render.background``, the one the set was rendered over: pass the override
for a set made with another), against each sensor's pixel median over the set (``--background
from-scenes``), and against each ``--other`` unit's, also mirrored left-right, up-down and turned half a turn
(as another unit's LEDs may be laid out). Prints per set and no-contact image the agreement's minimum, 5th
percentile, median and maximum, over the image and over its rim (``LightFit.rim_agreement``), and how many
images ``LightFit.from_another_unit`` flags (``photometric.MIN_AGREEMENT``). A diagnostic: it writes
nothing. About 10 ms an image and no-contact image on the 2-core machine.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.perception.encode import load_background  # noqa: E402
from tactile6d.perception.photometric import background_from_images, fit_light  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

TURNS = {"": lambda b: b, ", mirrored left-right": lambda b: b[:, ::-1], ", mirrored up-down": lambda b: b[::-1],
         ", turned half a turn": lambda b: b[::-1, ::-1]}


def agreements(images: np.ndarray, backgrounds: np.ndarray) -> np.ndarray:
    """(n, 3) each image (n, H, W, 3)'s agreement with its no-contact image (n, H, W, 3): over the image, over
    its rim, and whether ``LightFit.from_another_unit`` (1 or 0)."""
    fits = [fit_light(im, np.ascontiguousarray(bg)) for im, bg in zip(images, backgrounds)]
    return np.array([(f.agreement, f.rim_agreement, f.from_another_unit) for f in fits], dtype=np.float64)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="+", required=True)
    parser.add_argument("--other", action="append", default=[], help="another unit's no-contact image, data-relative "
                        "(repeat for more)")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (render.background: the unit "
                        "the sets were rendered over)")
    args = parse_with_overrides(parser, argv)
    cfg = compose_config(args.overrides)
    default = load_background(cfg)
    others = {path: load_background(compose_config([*args.overrides, f"render.background={path}"]))
              for path in args.other}
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        images = np.asarray(scenes["images"])
        own = np.asarray(scenes["backgrounds"]) if "backgrounds" in scenes else np.broadcast_to(default, images.shape)
        flat = images.reshape(-1, *images.shape[2:])
        # Each sensor's pixel median over the set, as ``tactile6d estimate --background from-scenes`` makes it.
        medians = np.stack([background_from_images(images[:, i]) for i in range(images.shape[1])])
        rows = [("its own unit's", agreements(flat, own.reshape(flat.shape))),
                ("each sensor's median over the set", agreements(flat, np.broadcast_to(medians, images.shape).reshape(flat.shape)))]
        for path, background in others.items():
            for turn, f in TURNS.items():
                rows.append((f"{path}{turn}", agreements(flat, np.broadcast_to(f(background), flat.shape))))
        for label, a in rows:
            spread = "; ".join(f"{part} min {x.min():.3f}, 5 % {np.percentile(x, 5):.3f}, median {np.median(x):.3f}, "
                               f"max {x.max():.3f}" for part, x in (("image", a[:, 0]), ("rim", a[:, 1])))
            print(f"{scene_set:12s} against {label}: agreement {spread}; taken for another unit's: "
                  f"{int(a[:, 2].sum())} of {len(a)}", flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
