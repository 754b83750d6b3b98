"""Accuracy and speed of tactile6d.patch on simulated contacts: contact point, normal, mask, press depth.

Contact sets (all rendered by tactile6d.render.DigitRenderer with its default settings, noise included):

- ``ycb-standard``: YCB objects touched as the validation scenes touch them (sensor axis along the
  inward face normal, gel apex pressed 1.5-2.0 mm, random roll) over the paper's no-contact image.
- ``ycb-tacto-unit``: the same contacts rendered over TACTO's no-contact image of another DIGIT unit, and
  estimated with that image as the sensor's own background.
- ``ycb-offaxis``: YCB objects touched off-centre (gel point up to 4 mm from the apex in y and z) and
  tilted (sensor axis up to 20 deg from the normal, random axis), deepest press 1.5-2.0 mm.
- ``sq-offaxis``: random superquadrics (spheres, ellipsoids, boxes, edges, corners), same off-centre and
  tilted placement.
- ``validation``: the pipeline's validation scenes (artifacts/scenes/validation.h5), when present.

Two ground truths: ``axis`` = the surface point the sensor axis was placed on and its face normal (the
scene convention; only for square placements), ``deepest`` = tactile6d.patch's own definition applied to
the renderer's true press depth (the band-weighted mean surface point of the deepest press) with the
object's true normals there. ``landmark`` rows are the old assumption (contact at
sensor.CONTACT_POINT, normal along -x) measured against the same truth.

Run: TACTILE6D_DATA=/work/shared/data OPENBLAS_NUM_THREADS=1 .venv/bin/python scripts/patch_accuracy.py
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np
import trimesh

from tactile6d import meshes, patch, sensor
from tactile6d.errors import InputError
from tactile6d.geometry import invert_pose
from tactile6d.render import DigitRenderer
from tactile6d.surface import sample_surface_random

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
    point, _ = patch.depth_to_contact(depth, None, top_band)
    dmax = float(depth.max())
    w = np.clip(depth - dmax * (1.0 - top_band), 0.0, None)
    idx = np.flatnonzero(w)
    idx = idx[:: max(1, len(idx) // max_pixels)]
    pts = patch.depth_to_points(depth).reshape(-1, 3)[idx]
    normal = w.ravel()[idx] @ normal_fn(pts)
    return point, normal / np.linalg.norm(normal)


class Collector:
    """Per-set lists of errors."""

    def __init__(self):
        self.rows: dict[str, dict[str, list]] = {}
        self.times: list[float] = []

    def add(self, name: str, key: str, value: float):
        self.rows.setdefault(name, {}).setdefault(key, []).append(value)

    def estimate(self, image, no_contact, model):
        t = time.perf_counter()
        res = patch.image_to_patch(image, no_contact, model)
        self.times.append(time.perf_counter() - t)
        return res

    def score(self, name, res, truth_point, truth_normal, true_depth=None, truth="deepest", to_surface=None):
        """Errors of one estimate (sensor frame) against one truth. to_surface: sensor-frame point (3,) ->
        its distance (m) to the object's surface, for the off-surface error."""
        if truth == "deepest" or true_depth is None:
            self.add(name, "missed", float(not res.contact))
        if not res.contact:
            return
        self.add(name, f"point_mm[{truth}]", 1e3 * float(np.linalg.norm(res.point - truth_point)))
        self.add(name, f"normal_deg[{truth}]", angle_deg(res.normal, truth_normal))
        self.add(name, f"landmark_point_mm[{truth}]", 1e3 * float(np.linalg.norm(sensor.CONTACT_POINT - truth_point)))
        self.add(name, f"landmark_normal_deg[{truth}]", angle_deg(np.array([-1.0, 0.0, 0.0]), truth_normal))
        if to_surface is not None:
            self.add(name, "off_surface_mm", 1e3 * float(to_surface(res.point)))
        if true_depth is not None and truth == "deepest":
            m = true_depth > 0
            self.add(name, "mask_iou", float((res.mask & m).sum() / max((res.mask | m).sum(), 1)))
            self.add(name, "max_depth_err_mm", 1e3 * abs(float(res.depth.max() - true_depth.max())))

    def report(self):
        print(f"{'set':16s} {'metric':28s} {'n':>4s} {'median':>8s} {'p90':>8s}")
        for name, metrics in self.rows.items():
            for key, values in metrics.items():
                v = np.asarray(values, dtype=float)
                if key == "missed":
                    print(f"{name:16s} {'no contact found':28s} {len(v):4d} {int(v.sum()):8d}")
                    continue
                print(f"{name:16s} {key:28s} {len(v):4d} {np.median(v):8.3f} {np.percentile(v, 90):8.3f}")
        t = 1e3 * np.asarray(self.times)
        print(f"time per image: median {np.median(t):.1f} ms, p90 {np.percentile(t, 90):.1f} ms over {len(t)} images "
              "(one process, OPENBLAS_NUM_THREADS=1)")


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
            T = patch.tilted_sensor_pose(p, nrm, rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi),
                                         rng.uniform(0.0, np.deg2rad(20.0)), rng.uniform(-0.004, 0.004, 2))
            T = patch.press_to_depth(renderer, mesh, T, depth)
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


def run(args):
    data = Path(os.environ.get("TACTILE6D_DATA", "../shared/data"))
    paper_bg = cv2.imread(str(data / "digit/caddeo2023/background.png"))
    tacto_bg = cv2.imread(str(data / "digit/tacto/bg_digit_240_320.jpg"))
    paper = DigitRenderer(paper_bg)
    tacto = DigitRenderer(tacto_bg)
    rng = np.random.default_rng([args.seed, 1])  # a stream apart from the calibration's

    if args.model:
        model = patch.load_model(args.model)
        print(f"calibration: loaded {args.model}")
    else:
        t = time.perf_counter()
        model = patch.calibrate(args.presses, seed=args.seed)
        print(f"calibration: {args.presses} simulated presses, {time.perf_counter() - t:.1f} s")

    col = Collector()
    nc_paper = paper.no_contact(seed=int(rng.integers(2**31)))
    nc_tacto = tacto.no_contact(seed=int(rng.integers(2**31)))
    for obj in args.objects:
        mesh, _ = meshes.clean_mesh(meshes.load_mesh_file(data / "ycb" / obj / "textured_simple.obj"))
        normal_fn_obj = lambda pts_obj, mesh=mesh: mesh_normals_at(mesh, pts_obj)  # noqa: E731
        for offaxis in (False, True):
            for T, p, nrm in ycb_contacts(mesh, args.per_object, rng, paper, offaxis):
                R, t = T[:3, :3], T[:3, 3]
                to_obj = lambda pts, R=R, t=t: pts @ R.T + t  # noqa: E731
                normal_fn = lambda pts, R=R, to_obj=to_obj: normal_fn_obj(to_obj(pts)) @ R  # noqa: E731
                seed = int(rng.integers(2**31))
                res_true = paper.render(mesh, np.eye(4), T, seed=seed)
                tp, tn = deepest_truth(res_true.depth, normal_fn, model.top_band)
                name = "ycb-offaxis" if offaxis else "ycb-standard"
                est = col.estimate(res_true.image, nc_paper, model)
                col.score(name, est, tp, tn, res_true.depth, to_surface=surface_distance_fn(mesh, T))
                if not offaxis:
                    p_s, n_s = (p - t) @ R, nrm @ R
                    col.score(name, est, p_s, n_s, true_depth=res_true.depth, truth="axis")
                    other = tacto.render(mesh, np.eye(4), T, seed=seed)
                    est = col.estimate(other.image, nc_tacto, model)
                    col.score("ycb-tacto-unit", est, tp, tn, other.depth)
        print(f"  {obj} done", flush=True)

    presses = patch.sample_presses(args.superquadrics, rng, paper, max_tilt=np.deg2rad(20.0), max_offset=0.004,
                                   depth_range=(0.0015, 0.0020))
    images, depths, normals = patch.render_presses(paper, presses, seed=int(rng.integers(2**31)))
    mesh, shape = None, None
    for press, image, depth, nrm in zip(presses, images, depths, normals):
        if press.shape is not shape:
            shape, mesh = press.shape, patch.shape_to_mesh(press.shape)
        tp, tn = patch.depth_to_contact(depth, nrm.astype(np.float64), model.top_band)
        col.score("sq-offaxis", col.estimate(image, nc_paper, model), tp, tn, depth,
                  to_surface=surface_distance_fn(mesh, press.T_object_sensor))

    validation = Path(args.validation)
    if validation.is_file():
        from tactile6d.io import read_artifact
        from tactile6d.scenes import scene_set_from_artifact

        scenes = scene_set_from_artifact(read_artifact(validation, "scenes"))
        ycb = {}
        for s in range(len(scenes)):
            obj = str(scenes.objects[s])
            if obj not in ycb and (data / "ycb" / obj).is_dir():
                ycb[obj] = meshes.clean_mesh(meshes.load_mesh_file(data / "ycb" / obj / "textured_simple.obj"))[0]
            for i in range(scenes.T_world_sensors.shape[1]):
                T_sensor_world = invert_pose(scenes.T_world_sensors[s, i])
                p = T_sensor_world[:3, :3] @ scenes.contact_points[s, i] + T_sensor_world[:3, 3]
                n = T_sensor_world[:3, :3] @ scenes.contact_normals[s, i]
                est = col.estimate(scenes.images[s, i], nc_paper, model)
                T_object_sensor = invert_pose(scenes.T_world_object[s]) @ scenes.T_world_sensors[s, i]
                to_surface = surface_distance_fn(ycb[obj], T_object_sensor) if obj in ycb else None
                col.score("validation", est, p, n, truth="axis", to_surface=to_surface)
        print(f"validation scenes: {len(scenes)} from {validation}")
    else:
        print(f"validation scenes: {validation} not found, skipped")
    col.report()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=list(OBJECTS))
    parser.add_argument("--per-object", type=int, default=6, help="contacts per object and per YCB set")
    parser.add_argument("--superquadrics", type=int, default=60, help="off-centre, tilted superquadric presses")
    parser.add_argument("--presses", type=int, default=60, help="calibration presses (patch.calibrate)")
    parser.add_argument("--model", default=None, help="a saved calibration (patch.save_model) instead of calibrating")
    parser.add_argument("--validation", default="/work/repro/artifacts/scenes/validation.h5")
    parser.add_argument("--seed", type=int, default=0)
    run(parser.parse_args(argv))


if __name__ == "__main__":
    main()
