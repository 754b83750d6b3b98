"""Would re-estimating the top contenders in full pick the right object more often? (tune on validation/offaxis only)

    python scripts/identify_rerank_check.py --artifacts artifacts --scenes offaxis --top 3 [key=value ...]

For each scene of the set, against the whole library (``objects.names`` and ``identify.distractors``):
the screen's ranking, as the identifier makes it (calibrated weights), and a re-ranking of its first
``--top`` objects by the same weights applied to the features of their full-settings estimates
(``identifier.full``, the estimate ``refine_best`` makes for the winner only); the others keep their
place. Prints one line of JSON: top-1 and top-3 of both rankings, the scenes where they differ (true
object, screen's first, re-ranked first) and the seconds the extra estimates took per scene.
"""

from __future__ import annotations

import argparse
import json
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
from tactile6d.estimation import identity_model
from tactile6d.estimation.identifier import Identifier, estimate_encoded
from tactile6d.estimation.optimize import use_cpu_devices_for


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", default="offaxis")
    parser.add_argument("--top", type=int, default=3, help="how many of the screen's first objects to re-estimate")
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args()
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    objects = [str(o) for o in cfg.objects.names]
    scenes = read_artifact(layout.scenes_file(args.artifacts, args.scenes), "scenes")
    ranks = {"screen": [], "reranked": []}
    changed, extra_s = [], []
    with Identifier.from_artifacts(objects, args.artifacts, cfg, distractors=list(cfg.identify.distractors)) as ident, \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for s in tqdm(range(len(scenes["names"])), desc=f"rerank {args.scenes}", unit="scene"):
            truth = str(scenes["objects"][s])
            T = scenes["T_world_sensors"][s]
            found, encoding = ident.candidates(T, scenes["images"][s])
            scores = identity_model.features_to_scores(np.stack([c.features for c in found]), ident.weights)
            order = list(np.lexsort((np.arange(len(found)), scores)))  # scores: lower is better, inf: no match
            t0 = time.perf_counter()
            full_scores = {}
            for i in order[:args.top]:
                if not found[i].matched:
                    continue
                try:
                    estimate = estimate_encoded(ident.full[found[i].name], T, encoding)
                except NoMatch:
                    continue
                features = ident.features(ident.full[found[i].name], T, estimate)
                full_scores[i] = float(identity_model.features_to_scores(features[None], ident.weights)[0])
            extra_s.append(time.perf_counter() - t0)
            head = sorted(order[:args.top], key=lambda i: (full_scores.get(i, np.inf), order.index(i)))
            reranked = head + order[args.top:]
            names = {"screen": [found[i].name for i in order], "reranked": [found[i].name for i in reranked]}
            for key in ranks:
                ranks[key].append(names[key].index(truth))
            if names["screen"][0] != names["reranked"][0]:
                changed.append({"scene": str(scenes["names"][s]), "truth": truth, "screen": names["screen"][0],
                                "reranked": names["reranked"][0]})
    out = {"scenes": args.scenes, "top": args.top, "overrides": args.overrides, "n_scenes": len(ranks["screen"]),
           **{f"{key}_top{k}": float(np.mean(np.array(r) < k)) for key, r in ranks.items() for k in (1, 3)},
           "changed": changed, "extra_s_median": float(np.median(extra_s)) if extra_s else float("nan")}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
