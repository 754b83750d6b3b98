"""Would more features of each object's screened estimate tell the objects apart better? (tune on generated sets only)

    python scripts/identify_feature_study.py dump --artifacts artifacts --scenes validation offaxis --out identify_study [key=value ...]
    python scripts/identify_feature_study.py fit --fit validation --on validation_s3 offaxis

``dump`` screens every scene of each set against the whole library (``objects.names`` and
``identify.distractors``), as the identifier does, and writes ``<out>/features_<set>.npz``:
for every scene and object the ``CANDIDATE_FEATURES`` below (NaN: the object does not match), the true
object's index and the library's names. It is the slow part (the screen of 40 scenes x 34 objects takes
about 4 minutes on the 2-core machine).

``fit`` fits the conditional-logit weights (``identity_model.fit_weights``) for each feature set of
``FEATURE_SETS`` and prints, as JSON lines, the top-1 and top-3 on every ``--on`` set: with weights fitted
on the ``--fit`` sets' dumps, or, without ``--fit``, on all the other ``--on`` sets (leave one set out;
the first weights printed are those of the first set's fit).
Never pass the test set (caddeo2023) to ``--fit``; look at it with ``--on`` only after a decision.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation import identity_model, render_and_compare
from tactile6d.estimation.identifier import Identifier
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.perception.inputs import check_sensor_poses

# Per scene and object, of the object's screened estimate (lower should mean "more likely the object"):
CANDIDATE_FEATURES = (
    "loss",            # mm, the best pose's loss (identity_model.FEATURES)
    "penetration",     # mm, its deepest press into a sensor body (identity_model.FEATURES)
    "agreement",       # its render-and-compare cost (identity_model.FEATURES)
    "mask",            # 1 - IoU of rendered and observed patches, mean over sensors
    "depth",           # mm, depth residual inside the patches, mean over sensors
    "free_area",       # share of the gel pressed where the image shows no contact, mean over sensors
    "free_depth",      # mm, press into free gel, mean over sensors
    "mask_worst",      # 1 - IoU of the worst sensor
    "tuple_error",     # mm, the best database tuple's mean pair-distance error (selection)
    "delta_h",         # rad, the latent-angle threshold the sensors needed, mean (widened when the
                       # database has no point whose latent angle is that close to the image's)
    "omega_share",     # -log of the database's share within that threshold, mean over sensors
    "loss_median",     # mm, the median loss of the ranked poses
    "spread_ratio",    # log(object diameter / largest distance between the contacts): an object much
                       # larger than the contacts' spread is an unlikely one to touch at random
)

FEATURE_SETS = {
    "current": ["loss", "penetration", "agreement"],
    "agreement terms": ["loss", "penetration", "mask", "depth", "free_area", "free_depth"],
    **{f"current + {f}": ["loss", "penetration", "agreement", f]
       for f in ("mask_worst", "tuple_error", "delta_h", "omega_share", "loss_median", "spread_ratio")},
    "current + delta_h + omega_share": ["loss", "penetration", "agreement", "delta_h", "omega_share"],
    "current + tuple_error + spread_ratio": ["loss", "penetration", "agreement", "tuple_error", "spread_ratio"],
}


def candidate_features(ident: Identifier, name: str, T: np.ndarray, candidate) -> np.ndarray:
    """(len(CANDIDATE_FEATURES),) of one matched candidate."""
    est = ident.screened[name]
    estimate = candidate.estimate
    rank = est.settings.rank
    step = int(rank.agreement_step)
    observed_mask = render_and_compare.image_to_grid(estimate.contacts.masks, step) >= 0.5
    observed_depth = render_and_compare.image_to_grid(estimate.contacts.depths, step)
    terms = render_and_compare.poses_to_agreement(est.mesh, estimate.best[None], check_sensor_poses(T), observed_mask,
                                         observed_depth, step, float(rank.agreement_free_margin))
    sel = estimate.selection
    diameter = float(np.linalg.norm(est.points.max(axis=0) - est.points.min(axis=0)))
    p = estimate.contacts.points
    spread = float(np.max(np.linalg.norm(p[:, None] - p[None], axis=-1)))
    return np.array([
        *candidate.features,
        float(np.mean(1.0 - terms["iou"][0])),
        1e3 * float(np.mean(terms["depth_residual"][0])),
        float(np.mean(terms["free_space_area"][0])),
        1e3 * float(np.mean(terms["free_space_depth"][0])),
        float(np.max(1.0 - terms["iou"][0])),
        1e3 * float(np.min(sel.errors)),
        float(np.nanmean(sel.delta_h)),
        float(np.mean(-np.log(np.maximum(sel.omega_sizes, 1) / len(est.points)))),
        1e3 * float(np.median(estimate.losses)),
        float(np.log(diameter / max(spread, 1e-3))),
    ])


def dump(args) -> None:
    cfg = compose_config(args.overrides)
    use_cpu_devices_for(str(cfg.optimize.solver), int(cfg.optimize.cpu_devices))
    objects = [str(o) for o in cfg.objects.names]
    with Identifier.from_artifacts(objects, args.artifacts, cfg, distractors=list(cfg.identify.distractors),
                                   calibrated=False) as ident, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for scene_set in args.scenes:
            scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
            n = len(scenes["names"])
            features = np.full((n, len(ident.names), len(CANDIDATE_FEATURES)), np.nan)
            for s in tqdm(range(n), desc=f"dump {scene_set}", unit="scene"):
                T = scenes["T_world_sensors"][s]
                found, _ = ident.candidates(T, scenes["images"][s])
                for o, candidate in enumerate(found):
                    if candidate.matched:
                        features[s, o] = candidate_features(ident, candidate.name, T, candidate)
            truth = np.array([ident.names.index(str(o)) for o in scenes["objects"]])
            out = Path(args.out) / f"features_{scene_set}.npz"
            out.parent.mkdir(parents=True, exist_ok=True)
            np.savez(out, features=features, truth=truth, names=np.array(ident.names),
                     feature_names=np.array(CANDIDATE_FEATURES))
            print(f"wrote {out}", file=sys.stderr)


def top_k(features: np.ndarray, truth: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    scores = identity_model.features_to_scores(features, weights)
    rows = np.arange(len(truth))
    rank = (scores < scores[rows, truth][:, None]).sum(axis=1)  # ties count for the truth
    return float(np.mean(rank == 0)), float(np.mean(rank < 3))


def fit(args) -> None:
    def load(scene_set):
        data = np.load(Path(args.out) / f"features_{scene_set}.npz")
        return data["features"], data["truth"]

    sets = {s: load(s) for s in args.on}
    # --fit names the one set to fit on; without it, each --on set is scored with weights fitted on all
    # the others (leave one set out), which fits on more, and harder, scenes than one set alone.
    training = {s: list(args.fit) if args.fit else [o for o in args.on if o != s] for s in args.on}
    fitted = {name: load(name) for name in {n for names in training.values() for n in names}}
    for label, chosen in FEATURE_SETS.items():
        columns = [CANDIDATE_FEATURES.index(f) for f in chosen]
        row = {"features": label}
        tops = {}
        for s, (f, t) in sets.items():
            features = np.concatenate([fitted[n][0][..., columns] for n in training[s]])
            truth = np.concatenate([fitted[n][1] for n in training[s]])
            weights = identity_model.fit_weights(features, truth)
            tops[s] = top_k(f[..., columns], t, weights)
            row.setdefault("weights", [round(float(w), 3) for w in weights])
        row.update({s: [round(100 * a, 1), round(100 * b, 1)] for s, (a, b) in tops.items()})
        row["mean_top1"] = round(100 * float(np.mean([a for a, _ in tops.values()])), 2)
        print(json.dumps(row))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    d = sub.add_parser("dump", help="screen scene sets and write each object's features")
    d.add_argument("--artifacts", default="artifacts")
    d.add_argument("--scenes", nargs="+", default=["validation", "offaxis"])
    d.add_argument("--out", default="identify_study", help="folder of the dumps (not under a stage's outputs)")
    d.add_argument("overrides", nargs="*")
    f = sub.add_parser("fit", help="fit weights on one set's dump and score feature sets on others")
    f.add_argument("--out", default="identify_study", help="folder of the dumps")
    f.add_argument("--fit", nargs="+", default=None, help="the sets to fit on (default: leave each --on set out in turn)")
    f.add_argument("--on", nargs="+", default=["offaxis"])
    args = parser.parse_args()
    dump(args) if args.command == "dump" else fit(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
