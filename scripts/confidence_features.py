"""How the confidence's features were chosen (docs/confidence.md), re-measured on a finished pipeline.

    python scripts/confidence_features.py --artifacts artifacts

Reads ours' ``ranked.h5`` and the ``eval/<set>.json`` of validation, offaxis, variation and kinematic,
and the confidence stage's own scenes (``confidence/fit.json``: each scene's ranked scores and distances).
Distances between ranked poses are measured as the estimator does (``confidence.distances_from_best`` on
``confidence.spread_points`` of the surface). Prints, AUROC for "ADI of the best pose < 1 cm":

1. each candidate feature alone, per set: the best rival's relative score gap (rival: farther than 1 cm),
   the top poses' spread, the best pose's score per sensor;
2. the model with and without the score per sensor beside the other two (rival at 1 cm), fitted on
   validation, variation and kinematic and judged on offaxis;
3. the model as the pipeline fits it (on the confidence scenes) for each rival distance, judged on its own
   scenes and on validation, offaxis and kinematic.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.data.object_artifacts import load_surface_points
from tactile6d.estimation import confidence

SETS = ("validation", "offaxis", "variation", "kinematic")
RIVAL_DISTANCES = (0.003, 0.005, 0.0075, 0.01)  # m


def set_rows(artifacts: str, scene_set: str) -> list[tuple[np.ndarray, np.ndarray, int, float]]:
    """Per ranked scene of ours on a set: (scores (K,), distances from the best (K,) m, L, ADI of the best m)."""
    ranked = read_artifact(layout.run_dir(artifacts, scene_set, "ours") / "ranked.h5", "ranked")
    per_scene = json.loads((Path(artifacts) / "eval" / f"{scene_set}.json").read_text())["ours"]["per_scene"]
    points, rows = {}, []
    for s, name in enumerate(ranked["names"].tolist()):
        obj, n = str(ranked["objects"][s]), int(ranked["n_poses"][s])
        if n:
            if obj not in points:
                points[obj] = confidence.spread_points(load_surface_points(artifacts, obj))
            distances = confidence.distances_from_best(points[obj], ranked["poses"][s][:n])
            rows.append((ranked["scores"][s][:n], distances, ranked["T_world_sensors"].shape[1], per_scene[name]["adi"][0]))
    return rows


def fit_rows(artifacts: str) -> list[tuple[np.ndarray, np.ndarray, int, float]]:
    """The confidence stage's own scenes, from its fit.json (L = 3, as conf/confidence draws them)."""
    fit = json.loads((Path(artifacts) / "confidence" / "fit.json").read_text())
    return [(np.array(v["scores"]), np.array(v["distances_m"]), 3, v["adi_m"]) for v in fit.values()]


def candidate_features(rows, rival: float, with_score: bool = False) -> np.ndarray:
    """(N, 2 or 3): log10 relative gap of the best rival farther than ``rival`` m (none: 10), the spread (cm),
    and with_score the best pose's log10 score per sensor."""
    out = []
    for scores, distances, n_sensors, _ in rows:
        gaps = (scores[distances > rival] - scores[0]) / max(scores[0], np.finfo(float).tiny)
        gap = gaps.min() if gaps.size else confidence.RIVAL_GAP_MAX
        x = [np.log10(np.clip(gap, confidence.RIVAL_GAP_MIN, confidence.RIVAL_GAP_MAX)), 100 * distances.max()]
        out.append(x + ([np.log10(max(scores[0], 1e-9) / n_sensors)] if with_score else []))
    return np.array(out)


def right(rows) -> np.ndarray:
    return np.array([adi < confidence.SUCCESS_ADI for *_, adi in rows])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    art = parser.parse_args(argv).artifacts
    sets = {name: set_rows(art, name) for name in SETS}

    print("1. each feature alone (AUROC; wrong of scenes):")
    for name, rows in sets.items():
        x, ok = candidate_features(rows, 0.01, with_score=True), right(rows)
        # larger gap: more likely right; larger spread or score: less
        figures = [confidence.auroc(sign * x[:, i], ok) for i, sign in enumerate((1, -1, -1))]
        print(f"   {name:10s} ({int((~ok).sum())} of {len(ok)}): rival gap {figures[0]:.3f}, spread {figures[1]:.3f}, "
              f"score per sensor {figures[2]:.3f}")

    print("2. fitted on validation, variation and kinematic, judged on offaxis (rival at 1 cm):")
    train = [r for name in ("validation", "variation", "kinematic") for r in sets[name]]
    for with_score in (False, True):
        model = confidence.fit_model(candidate_features(train, 0.01, with_score), right(train), 0.25)
        p = model.probability(candidate_features(sets["offaxis"], 0.01, with_score))
        print(f"   {'with' if with_score else 'without'} the score per sensor: offaxis AUROC "
              f"{confidence.auroc(p, right(sets['offaxis'])):.3f}")

    print("3. fitted on the confidence scenes, per rival distance (AUROC on its own scenes and on each set):")
    own = fit_rows(art)
    for rival in RIVAL_DISTANCES:
        model = confidence.fit_model(candidate_features(own, rival), right(own), 0.25)
        judged = {"own": own, **{k: sets[k] for k in ("validation", "offaxis", "kinematic")}}
        print(f"   {100 * rival:g} cm: " + ", ".join(
            f"{k} {confidence.auroc(model.probability(candidate_features(rows, rival)), right(rows)):.3f}"
            for k, rows in judged.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
