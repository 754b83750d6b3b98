"""``tactile6d fidelity``: render the paper's 120 sensor contacts and compare with the paper's own images.

For every sensor i of every triplet in the data directory's ``caddeo2023/triplets/<obj>/triplet_<k>/``
(the manifest's ``triplets:<obj>`` groups), the object mesh ``ycb/<obj>/textured_simple.obj`` (loaded and
cleaned as prepare_object does) is placed at the ground truth (translation (0.1, 0, 0.2) m, identity
rotation), the DIGIT at line i of ``poses_sensors.txt``, and the rendering is compared with
``Image_heatmap_<i>.png`` (contact-mask IoU, correlation of the difference images; tactile6d.evaluation.fidelity).
Prints one line per object and, last, one JSON object; writes a montage PNG.

    tactile6d fidelity [--out PATH] [--montage-rows N] [--seed S] [key=value ...]

``key=value`` are config overrides (Hydra syntax), e.g. ``render.render_step=1``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from tactile6d.cli import description
from tactile6d.core.config import compose_config, section_to_dict
from tactile6d.core.errors import DataError
from tactile6d.core.geometry import make_pose
from tactile6d.data.hdf5 import read_scene_dir
from tactile6d.data.third_party import DataStore, group_files, group_names
from tactile6d.evaluation import fidelity
from tactile6d.sim import meshes
from tactile6d.sim.render import DigitRenderer, MeshArrays, load_background_bgr, mesh_arrays

GROUND_TRUTH = make_pose(np.eye(3), [0.1, 0.0, 0.2])  # the paper's T_world_object for every triplet


def triplet_folders(store: DataStore) -> list[tuple[str, Path]]:
    """(object, verified triplet folder) for every triplet of the paper, in object then folder order."""
    folders = []
    for group in group_names():
        if group.startswith("triplets:"):
            store.paths(group)  # verifies (or downloads) every file of the object's triplets
            relpaths = sorted({str(Path(rel).parent) for rel in group_files(group)})
            folders += [(group.split(":", 1)[1], store.root / rel) for rel in relpaths]
    if not folders:
        raise DataError("the data manifest lists no triplets of the paper")
    return folders


def load_object(store: DataStore, obj: str) -> MeshArrays:
    """The YCB mesh of ``obj``, cleaned as stage prepare_object cleans it, as the renderer's arrays."""
    mesh, _ = meshes.clean_mesh(meshes.load_mesh_file(store.path(f"ycb/{obj}/textured_simple.obj")))
    return mesh_arrays(mesh)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d fidelity", description=description(__doc__))
    parser.add_argument("--out", type=Path, default=Path("artifacts/fidelity/montage.png"), help="montage PNG path")
    parser.add_argument("--montage-rows", type=int, default=6, help="sensors shown in the montage")
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the first sensor")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value, e.g. render.render_step=1")
    args = parser.parse_args(argv)

    cfg = compose_config(args.overrides)
    store = DataStore(cfg.paths)
    renderer = DigitRenderer.from_config(cfg.render, load_background_bgr(cfg, store), workers=1)
    background_rgb = renderer.background  # what the renderer adds the imprint to (RGB)
    scenes = [(obj, folder, *read_scene_dir(folder)) for obj, folder in triplet_folders(store)]
    sensors = [(obj, folder, i, poses[i], images[i]) for obj, folder, poses, images in scenes for i in range(len(poses))]
    montage_picks = set(np.linspace(0, len(sensors) - 1, args.montage_rows).round().astype(int).tolist())

    rows, montage_rows, meshes_by_name = [], [], {}
    for k, (obj, folder, i, T_world_sensor, paper) in enumerate(tqdm(sensors, desc="fidelity", unit="image")):
        if obj not in meshes_by_name:
            meshes_by_name = {obj: load_object(store, obj)}  # one at a time: sensors come grouped by object
        ours = renderer.render(meshes_by_name[obj], GROUND_TRUTH, T_world_sensor, seed=args.seed + k).image
        scores = fidelity.compare(paper, ours, background_rgb)  # both RGB: the paper's PNGs are RGB
        rows.append({"object": obj, "sensor": f"{folder.name}/{i}", **scores})
        if k in montage_picks:
            montage_rows.append((f"{obj} {folder.name}/{i}", paper, ours))

    for obj in sorted({r["object"] for r in rows}):
        mine = [r for r in rows if r["object"] == obj]
        ious = np.array([r["iou"] for r in mine])
        corrs = np.array([r["corr"] for r in mine])
        print(
            f"{obj:<22} n={len(mine):<3} IoU median {np.median(ious):.3f} min {ious.min():.3f}   "
            f"corr median {np.nanmedian(corrs):.3f} min {np.nanmin(corrs):.3f}"
        )

    args.out.parent.mkdir(parents=True, exist_ok=True)
    image = fidelity.montage(montage_rows, background_rgb)
    if not cv2.imwrite(str(args.out), image[..., ::-1]):
        raise DataError(f"cannot write {args.out}")
    ious = np.array([r["iou"] for r in rows])
    corrs = np.array([r["corr"] for r in rows])
    worst = rows[int(np.argmin(ious))]
    render_cfg = section_to_dict(cfg, "render")
    summary = {
        "n": len(rows),
        "median_iou": round(float(np.median(ious)), 4),
        "mean_iou": round(float(ious.mean()), 4),
        "min_iou": round(float(ious.min()), 4),
        "worst": f"{worst['object']}/{worst['sensor']}",
        "median_corr": round(float(np.nanmedian(corrs)), 4),
        "mean_corr": round(float(np.nanmean(corrs)), 4),
        "mask_rule": {"blur_ksize": fidelity.MASK_BLUR_KSIZE, "threshold": fidelity.MASK_THRESHOLD},
        "render": {k: render_cfg[k] for k in ("render_step", "light_intensity", "noise_std")},
        "montage": str(args.out),
    }
    print(json.dumps(summary))
    return 0
