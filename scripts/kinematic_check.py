"""Where a scene set's wrong estimates come from: selection or ranking, and the fit's own floor.

    python scripts/kinematic_check.py --artifacts artifacts --scene-set kinematic
    python scripts/kinematic_check.py --artifacts artifacts --scene-set kinematic rank.refine_normal_weight=0

Reads a finished pipeline's ``scenes/<set>.h5`` and ours' ``hypotheses.h5`` and ``ranked.h5`` (method
``ours``), and prints:

- **selection**: of the scenes whose best ranked pose is 1 cm (ADI) or more off, how many had a
  hypothesis within 1 cm (and 0.5 cm) of the truth among the 50 optimised poses nearest it in position:
  if all, the ranking picked a wrong pose that selection and the fit had made a right one beside;
- **first ranking or final score**: of those scenes, in how many one of the ``rank.candidates`` poses that
  the first ranking (loss and penetration) passes on is within 1 cm once refined: there the final score
  (refined fit, corrections, render-and-compare) preferred a wrong one; in the others the right pose never
  reached the refinement;
- **the fit's floor**: ``steps.rank.rank`` (refinement and render-and-compare, the ``rank`` config with
  the overrides given) started from the true pose alone, through the sensor poses and contacts the set
  gives: the positional error, mean and median (cm), where it ends. On a set whose sensor poses are off
  (kinematic) that is the error a perfect ranking would still leave.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core import metrics
from tactile6d.core.config import compose_config
from tactile6d.core.settings import RankSettings, SensorSettings
from tactile6d.data import layout
from tactile6d.data.hdf5 import read_artifact
from tactile6d.estimation.collision import PenetrationModel
from tactile6d.estimation.rank import load_mesh, load_pieces, rank
from tactile6d.estimation.run_storage import expand_hypotheses, scene_contacts
from tactile6d.evaluation import scoring
from tactile6d.sim.surface_sampling import sample_surface

NEAREST = 50  # hypotheses, nearest the truth in position, whose ADI is measured


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scene-set", default="kinematic")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value for the refinement from the truth")
    args = parser.parse_args(argv)
    cfg = compose_config(args.overrides)
    settings, sensors = RankSettings.from_cfg(cfg.rank), SensorSettings.from_cfg(cfg.sensors)
    art = args.artifacts
    scenes = read_artifact(layout.scenes_file(art, args.scene_set), "scenes")
    run = layout.run_dir(art, args.scene_set, "ours")
    hyp, ranked = read_artifact(run / "hypotheses.h5", "hypotheses"), read_artifact(run / "ranked.h5", "ranked")

    loaded = {}
    wrong, within_1, within_05, refined_within, floor = 0, 0, 0, 0, []
    every_candidate = dataclasses.replace(settings, top_k=settings.candidates)
    for s in tqdm(range(len(scenes["names"])), desc=args.scene_set, unit="scene"):
        obj = str(scenes["objects"][s])
        if obj not in loaded:
            mesh = load_mesh(art, obj)
            loaded[obj] = (PenetrationModel(load_pieces(art, obj)), mesh, sample_surface(mesh),
                           scoring.load_object_reference(art, obj))
        model, mesh, surface, ref = loaded[obj]
        T_true = scenes["T_world_object"][s]
        if ranked["n_poses"][s] and metrics.adi(ref.points, ranked["poses"][s][0], T_true, ref.tree) >= 0.01:
            wrong += 1
            rows = slice(hyp["offsets"][s], hyp["offsets"][s + 1])
            poses, hyp_losses = expand_hypotheses(hyp["translations"][rows], hyp["rotvecs"][rows], hyp["losses"][rows])
            nearest = np.argsort(np.linalg.norm(poses[:, :3, 3] - T_true[:3, 3], axis=1))[:NEAREST]
            best = metrics.adi(ref.points, poses[nearest], T_true, ref.tree).min() if len(nearest) else np.inf
            within_1 += best < 0.01
            within_05 += best < 0.005
            candidates = rank(model, hyp["T_world_sensors"][s], poses, hyp_losses, every_candidate, surface,
                              scene_contacts(hyp, s), mesh, sensors=sensors).poses
            refined_within += bool(len(candidates)) and metrics.adi(ref.points, candidates, T_true, ref.tree).min() < 0.01
        refined = rank(model, hyp["T_world_sensors"][s], T_true[None], np.zeros(1), settings, surface,
                       scene_contacts(hyp, s), mesh, sensors=sensors)
        floor.append(np.linalg.norm(refined.poses[0][:3, 3] - T_true[:3, 3]))
    floor = 100 * np.array(floor)
    print(f"{args.scene_set}: {wrong} of {len(floor)} scenes with the best pose 1 cm or more off; in "
          f"{within_1} of them a hypothesis within 1 cm of the truth (within 0.5 cm: {within_05}); in {refined_within} "
          f"of them one of the {settings.candidates} refined candidates within 1 cm")
    print(f"refined from the true pose ({' '.join(args.overrides) or 'the rank config as it is'}): positional "
          f"error {floor.mean():.2f} cm mean, {np.median(floor):.2f} cm median")
    return 0


if __name__ == "__main__":
    sys.exit(main())
