"""Which wrong estimates are poses the contacts cannot tell from the truth? Each one's near-symmetry share.

    python scripts/symmetric_confusions.py --artifacts artifacts --scenes validation offaxis variation kinematic \
        [--sequences 9] [override ...]

Every scene of the sets is estimated as stage rank does (images and each sensor's no-contact image, the
default settings); for each best pose over ``--wrong-cm`` off, ``tactile6d.evaluation.symmetry`` measures
how much of the object's surface the estimate puts where the truth has it, as the estimator refines the
truth through the sensor poses given (``scripts/pose_floor.py``'s floor: through poses off by millimetres the
truth itself is never matched within 1 mm), over the whole surface and near the contacts, and names the
case: a symmetry of the object (no touch anywhere tells them apart), alike where touched (these contacts do
not), or other. Per set it prints how many of the scenes each kind holds and
how much of the set's mean positional error they make (their errors summed over all the set's scenes), and
the mean over the rest. ``--sequences K``: also every K-th frame of the tracking sequences
(``artifacts/sequences/tracking.h5``), estimated from scratch through the sensor poses the hand reports.
A diagnostic: it changes nothing and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.core.geometry import invert_pose, transform_points  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.estimation.estimator import Estimator  # noqa: E402
from tactile6d.evaluation import symmetry  # noqa: E402
from tactile6d.perception.contacts import UntouchedSensorWarning  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.scenes import scene_backgrounds  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def rotation_deg(D: np.ndarray) -> float:
    """The angle (deg) of the rotation part of D (4, 4)."""
    return float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0))))


def rotation_axis(D: np.ndarray) -> np.ndarray:
    """The unit axis (3,) of the rotation part of D (4, 4), in D's own frame (the object's); any for no turn."""
    R = np.asarray(D, dtype=np.float64)[:3, :3]
    w, v = np.linalg.eig(R)
    return np.real(v[:, np.argmin(np.abs(w - 1.0))])


class Classifier:
    """Each object's mesh and surface samples, loaded once; ``case`` classifies one estimate."""

    def __init__(self, artifacts: str, cfg):
        self.artifacts, self.cfg = artifacts, cfg
        self.estimators: dict[str, Estimator] = {}
        self.samples: dict[str, np.ndarray] = {}

    def estimator(self, obj: str) -> Estimator:
        if obj not in self.estimators:
            self.estimators[obj] = Estimator.from_artifacts(obj, self.artifacts, self.cfg)
            self.samples[obj] = symmetry.surface_samples(self.estimators[obj].mesh)
        return self.estimators[obj]

    def case(self, obj: str, T: np.ndarray, images, backgrounds, truth: np.ndarray, wrong_cm: float) -> dict:
        est = self.estimator(obj)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UntouchedSensorWarning)
            estimate = est.estimate(T, images, backgrounds)
        error_cm = float(100 * np.linalg.norm(estimate.best[:3, 3] - truth[:3, 3]))
        turn = symmetry.relative_pose(estimate.best, truth)
        out = {"object": obj, "error_cm": error_cm, "rotation_deg": rotation_deg(turn), "axis": rotation_axis(turn)}
        if error_cm <= wrong_cm:
            return out
        # Compared with the truth as the estimator refines it (pose_floor.py's floor), not the truth itself:
        # through sensor poses off by millimetres even the right pose is, and a turn of it would then never
        # put the surface within SURFACE_TOL of the truth's.
        floor = est.rank(T, truth[None], np.zeros(1), estimate.contacts).poses[0]
        D = symmetry.relative_pose(estimate.best, floor)
        touched = np.asarray(estimate.contacts.touching, dtype=bool)
        contacts = transform_points(invert_pose(floor), np.asarray(estimate.contacts.points)[touched])
        out["surface"] = symmetry.surface_share(est.mesh, self.samples[obj], D)
        out["at_contacts"] = symmetry.contact_share(est.mesh, self.samples[obj], D, contacts)
        out["kind"] = symmetry.confusion_kind(out["surface"], out["at_contacts"])
        return out


def report(name: str, cases: list[dict]) -> str:
    """One set's line: per kind, its scenes and the positional error they add to the set's mean."""
    n = len(cases)
    errors = np.array([c["error_cm"] for c in cases])
    kinds = Counter(c.get("kind") for c in cases if "kind" in c)
    parts = [f"{name}: {n} estimates, mean {errors.mean():.2f} cm (median {np.median(errors):.2f})"]
    for kind in symmetry.KINDS:
        added = sum(c["error_cm"] for c in cases if c.get("kind") == kind) / n
        parts.append(f"{kind} {kinds.get(kind, 0)} (+{added:.2f} cm of the mean)")
    rest = [c["error_cm"] for c in cases if c.get("kind") not in symmetry.KINDS[:2]]
    parts.append(f"mean over the others {np.mean(rest):.2f} cm (median {np.median(rest):.2f})")
    return "; ".join(parts)


def print_case(label: str, c: dict) -> None:
    x, y, z = np.abs(c["axis"])
    line = (f"{label} {c['object']:22s} {c['error_cm']:6.2f} cm, turned {c['rotation_deg']:5.1f} deg about "
            f"(+-{x:.2f}, +-{y:.2f}, +-{z:.2f})")
    if "kind" in c:
        line += (f"  surface on surface: {100 * c['surface']:5.1f} % of the object, {100 * c['at_contacts']:5.1f} %"
                 f" near the contacts -> {c['kind']}")
    print(line, flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts")
    parser.add_argument("--scenes", nargs="*", default=[], help="scene sets (artifacts/scenes/<set>.h5)")
    parser.add_argument("--sequences", type=int, default=0, metavar="K",
                        help="also every K-th frame of the tracking sequences (0: none)")
    parser.add_argument("--wrong-cm", type=float, default=1.0, help="a best pose this far from the truth is wrong")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = parse_with_overrides(parser, argv)
    classifier = Classifier(args.artifacts, compose_config(args.overrides))
    for scene_set in args.scenes:
        scenes = read_artifact(layout.scenes_file(args.artifacts, scene_set), "scenes")
        cases = []
        for s in range(len(scenes["names"])):
            cases.append(classifier.case(str(scenes["objects"][s]), np.asarray(scenes["T_world_sensors"][s]),
                                         scenes["images"][s], scene_backgrounds(scenes, s),
                                         np.asarray(scenes["T_world_object"][s]), args.wrong_cm))
            print_case(f"{scene_set} {s:3d}", cases[-1])
        print(report(scene_set, cases), flush=True)
    if args.sequences > 0:
        seq = read_artifact(layout.sequences_file(args.artifacts, "tracking"), "sequences")
        by_object = defaultdict(list)
        for q in range(len(seq["objects"])):
            obj = str(seq["objects"][q])
            for f in range(0, len(seq["T_world_sensors"][q]), args.sequences):
                case = classifier.case(obj, np.asarray(seq["T_world_sensors"][q][f]), seq["images"][q][f], None,
                                       np.asarray(seq["T_world_object"][q][f]), args.wrong_cm)
                by_object[obj].append(case)
                print_case(f"sequence {q} frame {f:3d}", case)
        print(report("tracking sequences", [c for cases in by_object.values() for c in cases]), flush=True)
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
