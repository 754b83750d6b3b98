"""Does a change to the selection keep every selection identification makes, and how long do they take?

    python scripts/selection_check.py dump --artifacts artifacts --scenes caddeo2023 offaxis:20 --out before.npz
    (change tactile6d/estimation/select.py)
    python scripts/selection_check.py dump --artifacts artifacts --scenes caddeo2023 offaxis:20 --out after.npz
    python scripts/selection_check.py compare before.npz after.npz

``dump`` reads each scene of the sets (``name`` or ``name:count`` for the first ``count`` scenes) once,
as the identifier does, and selects tuples for it with every library object (``objects.names`` and
``identify.distractors``) under the ``identify.screen`` settings, and with the true object under the full
settings. It writes every selection (tuples, errors, delta_d, capped, or the NoMatch message) to
``--out`` and prints the seconds spent selecting, split into the wrong objects' screens, the true
object's screen and the true object's full selection. ``compare`` counts the selections whose tuples,
errors, delta_d, capped or NoMatch differ between two dumps, and exits 1 if any does.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config
from tactile6d.core.errors import NoMatch
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.runtime.script_args import parse_with_overrides
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402

FIELDS = ("tuples", "errors", "delta_d", "capped")


def dump(args) -> int:
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    identifier = Identifier.from_artifacts([str(o) for o in cfg.objects.names], args.artifacts, cfg, calibrated=False,
                                           distractors=[str(d) for d in cfg.identify.distractors])
    found, seconds = {}, {"wrong objects, screen": 0.0, "true object, screen": 0.0, "true object, full": 0.0}
    for spec in args.scenes:
        name, _, count = spec.partition(":")
        scenes = read_artifact(layout.scenes_file(args.artifacts, name), "scenes")
        n = min(int(count or len(scenes["names"])), len(scenes["names"]))
        for s in tqdm(range(n), desc=f"select {name}", unit="scene"):
            T, truth = scenes["T_world_sensors"][s], str(scenes["objects"][s])
            encoding = identifier.encode(T, scenes["images"][s])
            for obj in identifier.names:
                runs = [("screen", identifier.screened[obj])] + ([("full", identifier.full[obj])] if obj == truth else [])
                for mode, est in runs:
                    angles = None if encoding.latents is None else np.asarray(est.encoder.angles(encoding.latents), np.float64)
                    key = f"{name}/{s}/{obj}/{mode}"
                    start = time.perf_counter()
                    try:
                        chosen = est.select(encoding.contacts, angles)
                    except NoMatch as exc:
                        found[f"{key}/no_match"] = np.array(str(exc))
                    else:
                        for field in FIELDS:
                            found[f"{key}/{field}"] = np.asarray(getattr(chosen, field))
                    label = ("true object" if obj == truth else "wrong objects") + ", " + mode
                    seconds[label] += time.perf_counter() - start
    np.savez_compressed(args.out, **found)
    print(", ".join(f"{k} {v:.2f} s" for k, v in seconds.items()))
    return 0


def compare(args) -> int:
    before, after = np.load(args.before), np.load(args.after)
    selections = {key.rsplit("/", 1)[0] for key in before.files}
    if selections != {key.rsplit("/", 1)[0] for key in after.files}:
        print("the dumps are of different selections")
        return 1
    differ = {field: 0 for field in FIELDS + ("no_match",)}
    for key in sorted(selections):
        for field in differ:
            name = f"{key}/{field}"
            if (name in before.files) != (name in after.files) or (
                    name in before.files and not np.array_equal(before[name], after[name])):
                differ[field] += 1
    print(f"{len(selections)} selections; differing: " + ", ".join(f"{k} {v}" for k, v in differ.items()))
    return int(any(differ.values()))


def main() -> int:
    warnings.simplefilter("ignore")  # widened delta_h warnings, one per sensor and object
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("dump")
    d.add_argument("--artifacts", default="artifacts")
    d.add_argument("--scenes", nargs="+", required=True, help="scene sets, name or name:count")
    d.add_argument("--out", required=True)
    d.add_argument("overrides", nargs="*", help="config overrides key=value")
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    args = parse_with_overrides(parser)
    return dump(args) if args.command == "dump" else compare(args)


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
