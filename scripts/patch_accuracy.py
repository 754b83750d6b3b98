"""Accuracy and speed of tactile6d.perception.contact_patch on simulated contacts: contact point, normal, mask, press depth.

Contact sets (all rendered by tactile6d.sim.render.DigitRenderer with its default settings, noise included):

- ``ycb-standard``: YCB objects touched as the validation scenes touch them (sensor axis along the
  inward face normal, gel apex pressed 1.5-2.0 mm, random roll) over the paper's no-contact image.
- ``ycb-tacto-unit``: the same contacts rendered over TACTO's no-contact image of another DIGIT unit, and
  estimated with that image as the sensor's own background.
- ``ycb-offaxis``: YCB objects touched off-centre (gel point up to 4 mm from the apex in y and z) and
  tilted (sensor axis up to 20 deg from the normal, random axis), deepest press 1.5-2.0 mm.
- ``sq-offaxis``: random superquadrics (spheres, ellipsoids, boxes, edges, corners), same off-centre and
  tilted placement.
- ``validation``, ``offaxis``: the pipeline's generated scene sets (``--scenes``), when present.

Two ground truths: ``axis`` = the surface point the sensor axis was placed on and its face normal (the
scene convention; only for square placements), ``deepest`` = tactile6d.perception.contact_patch's own definition applied to
the renderer's true press depth (the band-weighted mean surface point of the deepest press) with the
object's true normals there. ``landmark`` rows are the old assumption (contact at
sensor.CONTACT_POINT, normal along -x) measured against the same truth.

Run: TACTILE6D_DATA=../shared/data OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/patch_accuracy.py
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np
import trimesh

from tactile6d.core import sensor
from tactile6d.core.errors import InputError
from tactile6d.core.geometry import invert_pose
from tactile6d.perception import contact_patch
from tactile6d.sim import meshes
from tactile6d.sim.render import DigitRenderer
from tactile6d.sim.surface_sampling import sample_surface_random

OBJECTS = ("002_master_chef_can", "004_sugar_box", "006_mustard_bottle", "007_tuna_fish_can", "008_pudding_box",
           "011_banana", "019_pitcher_base", "021_bleach_cleanser", "036_wood_block", "040_large_marker")


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def mesh_normals_at(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Smooth (vertex-interpolated, as the renderer shades) outward normals at the closest surface points."""
    closest, _, tri = trimesh.proximity.closest_point(mesh, points)
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], closest)
    n = np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[mesh.faces[tri]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def surface_distance_fn(mesh: trimesh.Trimesh, T_object_sensor: np.ndarray):
    """sensor-frame point (3,) -> distance (m) to the mesh surface."""
    R, t = T_object_sensor[:3, :3], T_object_sensor[:3, 3]
    return lambda p: float(trimesh.proximity.closest_point(mesh, (R @ p + t)[None])[1][0])


def deepest_truth(depth: np.ndarray, normal_fn, top_band: float, max_pixels: int = 400):
    """The patch definition of the contact applied to a true depth map -> point (3,), normal (3,).

    normal_fn: sensor-frame points (n, 3) -> true unit normals (n, 3). The band's pixels are subsampled
    evenly to at most ``max_pixels`` for the normals (the point uses them all).
    """
    point, _ = contact_patch.depth_to_contact(depth, None, top_band)
    dmax = float(depth.max())
    w = np.clip(depth - dmax * (1.0 - top_band), 0.0, None)
    idx = np.flatnonzero(w)
    idx = idx[:: max(1, len(idx) // max_pixels)]
    pts = contact_patch.depth_to_points(depth).reshape(-1, 3)[idx]
    normal = w.ravel()[idx] @ normal_fn(pts)
    return point, normal / np.linalg.norm(normal)


TOP_BAND = contact_patch.PatchModel.__dataclass_fields__["top_band"].default

# Design variants measured by --ablation: PatchModel settings changed from the defaults (refitted).
VARIANTS = {
    "default": {},
    "no convex hull": {"convex": False},
    "no erosion": {"erode": 0},
    "mask smoothing 3 px": {"mask_sigma": 3.0, "grow_level": 3.5},
    "regression smoothing 3 px": {"sigma": 3.0},
    "polynomial degree 4": {"degree": 4},
}


class Case:
    """One tactile image to estimate, with its truths (sensor frame)."""

    def __init__(self, name, image, no_contact, truths, true_depth=None, to_surface=None):
        self.name, self.image, self.no_contact = name, image, no_contact
        self.truths = truths  # {"deepest" or "axis": (point (3,), normal (3,))}
        self.true_depth, self.to_surface = true_depth, to_surface


def evaluate(cases: list[Case], model: contact_patch.PatchModel) -> tuple[dict, list]:
    """-> {set: {metric: [values]}}, per-image times (s)."""
    rows: dict[str, dict[str, list]] = {}
    times = []

    def add(name, key, value):
        rows.setdefault(name, {}).setdefault(key, []).append(value)

    for case in cases:
        t = time.perf_counter()
        res = contact_patch.image_to_patch(case.image, case.no_contact, model)
        times.append(time.perf_counter() - t)
        add(case.name, "missed", float(not res.contact))
        if not res.contact:
            continue
        for truth, (point, normal) in case.truths.items():
            add(case.name, f"point_mm[{truth}]", 1e3 * float(np.linalg.norm(res.point - point)))
            add(case.name, f"normal_deg[{truth}]", angle_deg(res.normal, normal))
            add(case.name, f"landmark_point_mm[{truth}]", 1e3 * float(np.linalg.norm(sensor.CONTACT_POINT - point)))
            add(case.name, f"landmark_normal_deg[{truth}]", angle_deg(np.array([-1.0, 0.0, 0.0]), normal))
        if case.to_surface is not None:
            add(case.name, "off_surface_mm", 1e3 * float(case.to_surface(res.point)))
        if case.true_depth is not None:
            m = case.true_depth > 0
            add(case.name, "mask_iou", float((res.mask & m).sum() / max((res.mask | m).sum(), 1)))
            add(case.name, "max_depth_err_mm", 1e3 * abs(float(res.depth.max() - case.true_depth.max())))
    return rows, times


def report(rows: dict, times: list) -> None:
    print(f"{'set':16s} {'metric':28s} {'n':>4s} {'median':>8s} {'p90':>8s}")
    for name, metrics in rows.items():
        for key, values in metrics.items():
            v = np.asarray(values, dtype=float)
            if key == "missed":
                print(f"{name:16s} {'no contact found':28s} {len(v):4d} {int(v.sum()):8d}")
                continue
            print(f"{name:16s} {key:28s} {len(v):4d} {np.median(v):8.3f} {np.percentile(v, 90):8.3f}")
    t = 1e3 * np.asarray(times)
    print(f"time per image: median {np.median(t):.1f} ms, p90 {np.percentile(t, 90):.1f} ms over {len(t)} images "
          "(one process, OPENBLAS_NUM_THREADS=1)")


def report_ablation(results: dict) -> None:
    sets = ("ycb-offaxis", "sq-offaxis")
    print("ablation (medians / p90 on " + " and ".join(sets) + ")")
    print(f"{'variant':28s} " + " ".join(f"{s + ' ' + m:>30s}" for s in sets for m in ("point mm", "normal deg", "IoU")))
    for variant, rows in results.items():
        cells = []
        for s in sets:
            for key in ("point_mm[deepest]", "normal_deg[deepest]", "mask_iou"):
                v = np.asarray(rows.get(s, {}).get(key, [np.nan]))
                cells.append(f"{np.median(v):13.3f} / {np.percentile(v, 90):6.3f}")
        print(f"{variant:28s} " + " ".join(f"{c:>30s}" for c in cells))


def ycb_contacts(mesh, n, rng, renderer, offaxis: bool):
    """n sensor poses T_object_sensor on the mesh with their surface point and face normal (object frame)."""
    out = []
    tries = 0
    while len(out) < n and tries < 20 * n:
        tries += 1
        p, face = sample_surface_random(mesh, 1, rng)
        p, nrm = p[0], mesh.face_normals[face[0]]
        depth = rng.uniform(0.0015, 0.0020)
        if offaxis:
            T = contact_patch.tilted_sensor_pose(p, nrm, rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi),
                                         rng.uniform(0.0, np.deg2rad(20.0)), rng.uniform(-0.004, 0.004, 2))
            T = contact_patch.press_to_depth(renderer, mesh, T, depth)
            if T is None:
                continue
        else:
            T = sensor.sensor_poses_touching(p, nrm, rng.uniform(-np.pi, np.pi), depth)
        try:
            renderer.contact(mesh, invert_pose(T))
        except InputError:
            continue  # the object would enter the sensor body: not a contact a hand makes
        out.append((T, p, nrm))
    return out


def make_cases(args, data: Path) -> list[Case]:
    """All contact sets of the module docstring, rendered, with their truths."""
    paper = DigitRenderer.from_default_config(cv2.imread(str(data / "digit/caddeo2023/background.png")))
    tacto = DigitRenderer.from_default_config(cv2.imread(str(data / "digit/tacto/bg_digit_240_320.jpg")))
    rng = np.random.default_rng([args.seed, 1])  # a stream apart from the calibration's
    nc_paper = paper.no_contact(seed=int(rng.integers(2**31)))
    nc_tacto = tacto.no_contact(seed=int(rng.integers(2**31)))
    cases: list[Case] = []
    for obj in args.objects:
        mesh, _ = meshes.clean_mesh(meshes.load_mesh_file(data / "ycb" / obj / "textured_simple.obj"))
        for offaxis in (False, True):
            for T, p, nrm in ycb_contacts(mesh, args.per_object, rng, paper, offaxis):
                R, t = T[:3, :3], T[:3, 3]
                normal_fn = lambda pts, R=R, t=t, mesh=mesh: mesh_normals_at(mesh, pts @ R.T + t) @ R
                seed = int(rng.integers(2**31))
                rendered = paper.render(mesh, np.eye(4), T, seed=seed)
                truths = {"deepest": deepest_truth(rendered.depth, normal_fn, TOP_BAND)}
                to_surface = surface_distance_fn(mesh, T)
                if offaxis:
                    cases.append(Case("ycb-offaxis", rendered.image, nc_paper, truths, rendered.depth, to_surface))
                    continue
                truths["axis"] = ((p - t) @ R, nrm @ R)
                cases.append(Case("ycb-standard", rendered.image, nc_paper, truths, rendered.depth, to_surface))
                other = tacto.render(mesh, np.eye(4), T, seed=seed)
                cases.append(Case("ycb-tacto-unit", other.image, nc_tacto, truths, other.depth, to_surface))
        print(f"  {obj}: contacts rendered", flush=True)

    presses = contact_patch.sample_presses(args.superquadrics, rng, paper, max_tilt=np.deg2rad(20.0), max_offset=0.004,
                                   depth_range=(0.0015, 0.0020))
    images, depths, normals = contact_patch.render_presses(paper, presses, seed=int(rng.integers(2**31)))
    mesh, shape = None, None
    for press, image, depth, nrm in zip(presses, images, depths, normals):
        if press.shape is not shape:
            shape, mesh = press.shape, contact_patch.shape_to_mesh(press.shape)
        truths = {"deepest": contact_patch.depth_to_contact(depth, nrm.astype(np.float64), TOP_BAND)}
        cases.append(Case("sq-offaxis", image, nc_paper, truths, depth, surface_distance_fn(mesh, press.T_object_sensor)))

    for path in map(Path, args.scenes):
        if not path.is_file():
            print(f"scene set {path} not found, skipped")
            continue
        from tactile6d.data.hdf5 import read_artifact
        from tactile6d.sim.scenes import scene_set_from_artifact

        scenes = scene_set_from_artifact(read_artifact(path, "scenes"))
        ycb = {}
        for s in range(len(scenes)):
            obj = str(scenes.objects[s])
            if obj not in ycb and (data / "ycb" / obj).is_dir():
                ycb[obj] = meshes.clean_mesh(meshes.load_mesh_file(data / "ycb" / obj / "textured_simple.obj"))[0]
            for i in range(scenes.T_world_sensors.shape[1]):
                T_sensor_world = invert_pose(scenes.T_world_sensors[s, i])
                p = T_sensor_world[:3, :3] @ scenes.contact_points[s, i] + T_sensor_world[:3, 3]
                n = T_sensor_world[:3, :3] @ scenes.contact_normals[s, i]
                T_object_sensor = invert_pose(scenes.T_world_object[s]) @ scenes.T_world_sensors[s, i]
                to_surface = surface_distance_fn(ycb[obj], T_object_sensor) if obj in ycb else None
                cases.append(Case(path.stem, scenes.images[s, i], nc_paper, {"axis": (p, n)}, None, to_surface))
        print(f"scene set {path.stem}: {len(scenes)} scenes from {path}")
    return cases


def run(args):
    data = Path(os.environ.get("TACTILE6D_DATA", "../shared/data"))
    cases = make_cases(args, data)
    if args.ablation:
        cal = contact_patch.calibration_set(args.presses, seed=args.seed)
        results = {}
        for variant, settings in VARIANTS.items():
            model = contact_patch.fit_model(cal[0], cal[3], cal[2], cal[1], seed=args.seed, **settings)
            results[variant] = evaluate(cases, model)[0]
            print(f"  variant {variant!r} evaluated", flush=True)
        report_ablation(results)
        return
    if args.model:
        model = contact_patch.load_model(args.model)
        print(f"calibration: loaded {args.model}")
    else:
        t = time.perf_counter()
        model = contact_patch.calibrate(args.presses, seed=args.seed)
        print(f"calibration: {args.presses} simulated presses, {time.perf_counter() - t:.1f} s")
    report(*evaluate(cases, model))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=list(OBJECTS))
    parser.add_argument("--per-object", type=int, default=6, help="contacts per object and per YCB set")
    parser.add_argument("--superquadrics", type=int, default=60, help="off-centre, tilted superquadric presses")
    parser.add_argument("--presses", type=int, default=60, help="calibration presses (contact_patch.calibrate)")
    parser.add_argument("--model", default=None, help="a saved calibration (contact_patch.save_model) instead of calibrating")
    parser.add_argument("--scenes", nargs="*", default=["artifacts/scenes/validation.h5", "artifacts/scenes/offaxis.h5"],
                        help="scene sets of the pipeline to measure on (their true contact point and normal)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ablation", action="store_true", help="compare the design variants (VARIANTS) instead")
    run(parser.parse_args(argv))


if __name__ == "__main__":
    main()
