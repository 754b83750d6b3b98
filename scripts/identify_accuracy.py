"""Identification accuracy and time on a scene set against the library (tune on validation/offaxis only).

    python scripts/identify_accuracy.py --artifacts artifacts --scenes offaxis [key=value ...]

The identify stage's computation (``identification_accuracy.identify_scene_set``) under config overrides, without
writing the stage's metrics: each scene is identified against every object of ``objects.names`` and
``identify.distractors``, with the weights of the calibrate_identify stage (or ``identify.weights=[...]``).
Prints one line of JSON: the scene set, the overrides and the stage's figures (top-1, top-3, per-object
top-1, confusion matrix, seconds per identification, pose metrics of the scenes identified correctly).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.evaluation import scoring
from tactile6d.evaluation.identification_accuracy import identify_scene_set
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", default="offaxis")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    objects = [str(o) for o in cfg.objects.names]
    scenes = read_artifact(layout.scenes_file(args.artifacts, args.scenes), "scenes")
    references = {o: scoring.load_object_reference(args.artifacts, o) for o in objects}
    with Identifier.from_artifacts(objects, args.artifacts, cfg, distractors=list(cfg.identify.distractors)) \
            as identifier, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = identify_scene_set(identifier, scenes, references, desc=f"identify {args.scenes}")
    print(json.dumps({"scenes": args.scenes, "overrides": args.overrides, **out}))
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
