"""``tactile6d fidelity``: render the paper's 120 sensor contacts and compare with the paper's own images.

For every sensor i of every triplet in ``<data>/caddeo2023/triplets/<obj>/triplet_<k>/``, the object mesh
``<data>/ycb/<obj>/textured_simple.obj`` is placed at the ground truth (translation (0.1, 0, 0.2) m,
identity rotation), the DIGIT at line i of ``poses_sensors.txt``, and the rendering is compared with
``Image_heatmap_<i>.png`` (contact-mask IoU, correlation of the difference images; tactile6d.fidelity).
Prints one line per object and, last, one JSON object; writes a montage PNG.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import cv2
import numpy as np
import trimesh
from omegaconf import OmegaConf
from tqdm import tqdm

from tactile6d import fidelity
from tactile6d.errors import ConfigError, DataError
from tactile6d.geometry import make_pose, text_to_poses
from tactile6d.render import DigitRenderer, mesh_arrays

REPO = Path(__file__).resolve().parents[2]
RENDER_CONFIG = REPO / "conf" / "render" / "default.yaml"
GROUND_TRUTH = make_pose(np.eye(3), [0.1, 0.0, 0.2])  # the paper's T_world_object for every triplet


def default_data_dir() -> Path:
    """$TACTILE6D_DATA, else ``../shared/data`` beside the repository."""
    env = os.environ.get("TACTILE6D_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def load_render_config(path: Path | str = RENDER_CONFIG, overrides: list[str] | tuple[str, ...] = ()) -> dict:
    """The render config section as a dict, with ``key=value`` overrides applied to existing keys."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"render config {path} not found")
    config = OmegaConf.load(path)
    for item in overrides:
        key, sep, _ = item.partition("=")
        if not sep or key not in config:
            raise ConfigError(f"override {item!r}: expected key=value with a key of {path}")
    config = OmegaConf.merge(config, OmegaConf.from_dotlist(list(overrides)))
    return OmegaConf.to_container(config, resolve=True)


def read_image(path: Path, rgb: bool) -> np.ndarray:
    """An 8-bit colour image; RGB when ``rgb`` else OpenCV's BGR. DataError when missing or unreadable."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DataError(f"cannot read image {path}")
    return image[..., ::-1] if rgb else image


def load_mesh(path: Path) -> trimesh.Trimesh:
    """A YCB ``textured_simple.obj`` with its UV-seam duplicates merged (smooth normals need it)."""
    if not path.is_file():
        raise DataError(f"mesh {path} not found")
    mesh = trimesh.load(str(path), force="mesh")
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return mesh


def paper_sensors(data_dir: Path) -> list[tuple[str, Path, int, np.ndarray]]:
    """(object, triplet folder, sensor index, T_world_sensor (4, 4)) for every sensor of the paper's triplets."""
    root = data_dir / "caddeo2023" / "triplets"
    if not root.is_dir():
        raise DataError(f"no paper triplets at {root} (set --data-dir or TACTILE6D_DATA)")
    sensors = []
    for folder in sorted(root.glob("*/triplet_*")):
        poses = text_to_poses((folder / "poses_sensors.txt").read_text())
        sensors += [(folder.parent.name, folder, i, poses[i]) for i in range(len(poses))]
    return sensors


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="tactile6d fidelity", description=__doc__.split("\n")[0])
    parser.add_argument(
        "--data-dir", type=Path, default=None, help="data directory (default: $TACTILE6D_DATA or ../shared/data)"
    )
    parser.add_argument("--out", type=Path, default=Path("artifacts/fidelity/montage.png"), help="montage PNG path")
    parser.add_argument("--config", type=Path, default=RENDER_CONFIG, help="render config YAML")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="override a render config key"
    )
    parser.add_argument("--montage-rows", type=int, default=6, help="sensors shown in the montage")
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the first sensor")
    args = parser.parse_args(argv)

    data_dir = args.data_dir or default_data_dir()
    config = load_render_config(args.config, args.overrides)
    background_bgr = read_image(data_dir / config["background"], rgb=False)
    renderer = DigitRenderer.from_config(config, background_bgr, workers=1)
    background_rgb = renderer.background  # what the renderer adds the imprint to (RGB)
    sensors = paper_sensors(data_dir)
    montage_picks = set(np.linspace(0, len(sensors) - 1, args.montage_rows).round().astype(int).tolist())

    rows, montage_rows, meshes = [], [], {}
    for k, (obj, folder, i, T_world_sensor) in enumerate(tqdm(sensors, desc="fidelity", unit="image")):
        if obj not in meshes:
            meshes = {obj: mesh_arrays(load_mesh(data_dir / "ycb" / obj / "textured_simple.obj"))}
        ours = renderer.render(meshes[obj], GROUND_TRUTH, T_world_sensor, seed=args.seed + k).image
        paper = read_image(folder / f"Image_heatmap_{i}.png", rgb=True)  # the paper's PNGs are RGB
        scores = fidelity.compare(paper, ours, background_rgb)
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
    summary = {
        "n": len(rows),
        "median_iou": round(float(np.median(ious)), 4),
        "mean_iou": round(float(ious.mean()), 4),
        "min_iou": round(float(ious.min()), 4),
        "worst": f"{worst['object']}/{worst['sensor']}",
        "median_corr": round(float(np.nanmedian(corrs)), 4),
        "mean_corr": round(float(np.nanmean(corrs)), 4),
        "mask_rule": {"blur_ksize": fidelity.MASK_BLUR_KSIZE, "threshold": fidelity.MASK_THRESHOLD},
        "render": {k: config[k] for k in ("render_step", "light_intensity", "noise_std")},
        "montage": str(args.out),
    }
    print(json.dumps(summary))
    return 0
