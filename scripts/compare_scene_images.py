"""Two renderings of the same scenes compared image by image, as `tactile6d fidelity` compares the paper's.

    python scripts/compare_scene_images.py artifacts/scenes/validation.h5 ART/scenes/validation_tacto.h5
    python scripts/compare_scene_images.py artifacts/sequences/tracking.h5 ART/sequences/tracking.h5

Both files must hold the same scenes, or sequences (objects and poses; e.g. a set and its rendering by TACTO,
``scripts/tacto_scenes.py``). Each sensor's two images are compared through their
difference from the set's no-contact image (``tactile6d.evaluation.fidelity.compare_imprints``: IoU of the contact
masks, correlation of the blurred differences); a pair in which neither image shows contact is left out of the
IoU. Prints one JSON line: the median and 10th percentile of both over the pairs, the share of pairs whose masks
disagree on whether there is contact at all, and the median over the pairs with contact of how strong the second
image's press is against the first's (the ratio of their mean absolute blurred differences over both masks:
correlation and IoU alone would not see one renderer's light brighter than the other's). With ``--patch-model``
(a run's ``artifacts/patch/model.npz``) it also reads both images' contact patches as the estimator does
(``contact_patch.image_to_patch``) and gives how far apart their contact points (mm) and normals (deg) are, median
and 90th percentile over the pairs where both show contact. ``--montage PATH`` also draws the first sensor of
``--rows`` scenes spread over the set (``fidelity.montage``: the second file's imprint, the first's, their
difference; ``--names`` titles them); nothing else is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data.hdf5 import read_artifact  # noqa: E402
from tactile6d.evaluation import fidelity  # noqa: E402
from tactile6d.perception import contact_patch  # noqa: E402
from tactile6d.perception.encode import load_background  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402


def compare_sets(a: dict, b: dict, background: np.ndarray, patch_model=None) -> dict:
    """Scene or sequence sets a and b (mappings with ``images`` (..., H, W, 3) and the poses) of the same scenes
    -> the summary printed (module docstring); patch_model: a ``contact_patch.PatchModel``, or None to leave the
    patches out."""
    for key in ("T_world_object", "T_world_sensors"):
        if not np.array_equal(np.asarray(a[key]), np.asarray(b[key])):
            raise SystemExit(f"the two sets are not the same scenes: their {key} differ")
    ious, corrs, scales, contact_disagrees, apart = [], [], [], 0, []
    for image_a, image_b in zip(np.asarray(a["images"]).reshape(-1, *a["images"].shape[-3:]),
                                np.asarray(b["images"]).reshape(-1, *b["images"].shape[-3:])):
        pair = fidelity.compare_imprints(image_a, image_b, background)
        contact_disagrees += pair["touched"][0] != pair["touched"][1]
        if any(pair["touched"]):
            ious.append(pair["iou"])
            scales.append(pair["strength"])
        corrs.append(pair["corr"])
        if patch_model is not None:
            patches = (contact_patch.image_to_patch(image_a, background, patch_model),
                       contact_patch.image_to_patch(image_b, background, patch_model))
            if patches[0].contact and patches[1].contact:
                cosine = float(np.clip(patches[0].normal @ patches[1].normal, -1.0, 1.0))
                apart.append((1000.0 * np.linalg.norm(patches[0].point - patches[1].point),
                              np.degrees(np.arccos(cosine))))
    ious, corrs = np.array(ious), np.array(corrs)
    patch_rows = {}
    if apart:
        points, normals = np.array(apart).T
        patch_rows = {"contact_point_mm_median": round(float(np.median(points)), 3),
                      "contact_point_mm_p90": round(float(np.percentile(points, 90)), 3),
                      "normal_deg_median": round(float(np.median(normals)), 3),
                      "normal_deg_p90": round(float(np.percentile(normals, 90)), 3)}
    return {"pairs": len(corrs), "iou_median": round(float(np.median(ious)), 3),
            "iou_p10": round(float(np.percentile(ious, 10)), 3), "corr_median": round(float(np.nanmedian(corrs)), 3),
            "corr_p10": round(float(np.nanpercentile(corrs, 10)), 3),
            "contact_disagrees": round(contact_disagrees / len(corrs), 3),
            "strength_ratio_median": round(float(np.median(scales)), 3), **patch_rows}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="a scenes or sequences artifact")
    parser.add_argument("second", type=Path, help="the same scenes or sequences rendered otherwise")
    parser.add_argument("--montage", type=Path, help="write a picture of a few pairs here (.png or .jpg)")
    parser.add_argument("--rows", type=int, default=4, help="scenes in the montage")
    parser.add_argument("--names", nargs=2, default=["second", "first"], help="the second's and the first's titles")
    parser.add_argument("--patch-model", type=Path,
                        help="also compare the contact patches read (a run's artifacts/patch/model.npz)")
    args = parser.parse_args()
    with h5py.File(args.first, "r") as f:
        schema = str(f.attrs.get("schema", ""))  # read_artifact checks it below
    a, b = read_artifact(args.first, schema), read_artifact(args.second, schema)
    background = load_background({**a.config, "paths": compose_config([]).paths})
    patch_model = contact_patch.load_model(args.patch_model) if args.patch_model else None
    print(json.dumps({"first": str(args.first), "second": str(args.second),
                      **compare_sets(a, b, background, patch_model)}))
    if args.montage:
        write_montage(args.montage, a, b, background, args.rows, tuple(args.names))
    return 0


def write_montage(path: Path, a, b, background: np.ndarray, rows: int, names: tuple[str, str]) -> None:
    """The first sensor of ``rows`` scenes spread evenly over the set: b's imprint, a's, b - a (RGB in, the file
    written as RGB)."""
    first_sensor = np.asarray(a["images"]).reshape(-1, *a["images"].shape[-4:])[:, 0]
    other = np.asarray(b["images"]).reshape(-1, *b["images"].shape[-4:])[:, 0]
    picked = np.linspace(0, len(first_sensor) - 1, rows).round().astype(int)
    objects = np.asarray(a["objects"]).reshape(-1)
    label = [str(o.decode() if isinstance(o, bytes) else o) for o in objects]
    per_object = len(first_sensor) // len(label)
    image = fidelity.montage([(f"{label[i // per_object]} #{i}", other[i], first_sensor[i]) for i in picked],
                             background, names=names)
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    raise SystemExit(main())
