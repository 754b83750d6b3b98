"""Step 4, rank: the best distinct poses by loss + deepest sensor penetration, optionally re-scored by
surface refinement and by render-and-compare, with what it loads (the object's convex collision pieces
and, for the re-scoring, its mesh and surface samples).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import trimesh

from tactile6d import agreement, collision, layout, ranking
from tactile6d import refine as refinement
from tactile6d.contacts import Contacts, sensors_to_landmark_contacts
from tactile6d.errors import InputError
from tactile6d.io import read_artifact
from tactile6d.meshes import unpack_pieces
from tactile6d.object_artifacts import require
from tactile6d.settings import RankSettings, SensorSettings


def rank(
    model: collision.PenetrationModel,
    T_world_sensors: np.ndarray,
    poses: np.ndarray,
    losses: np.ndarray,
    settings: RankSettings,
    surface=None,
    contacts: Contacts | None = None,
    mesh=None,
    *,
    sensors: SensorSettings,
) -> ranking.RankedPoses:
    """The top-k distinct poses by loss + deepest sensor penetration (the paper's collision-aware ranking).

    model: the object's PenetrationModel; poses (P, 4, 4) ``T_world_object``; losses (P,) m; contacts:
    the sensors' contacts (default: their landmarks, ``contacts.sensors_to_landmark_contacts``); sensors:
    how far ``T_world_sensors`` may be off (``SensorSettings``): that much penetration into a sensor costs
    nothing (``ranking.penetration_cost``), and the refinement then corrects each sensor's pose too.

    With either of these on, the best ``candidates`` distinct poses ranked as above are re-scored
    (neither is in the paper):

    - ``rank.refine`` (``tactile6d.refine``): each pose is refined against ``surface`` (the object's
      ``contact.SurfaceSamples``, required then) and scored ``d + refine_normal_weight * a + deepest
      penetration``, d and a the refined pose's mean point-to-plane residual (m) and normal angle (rad)
      (``refine.surface_losses``); ``losses`` of the result are then ``d + refine_normal_weight * a``.
      With ``rank.refine_patch_points`` > 0 and observed patches, that many points of each patch's
      pressed gel join the fit (``Contacts.patch_points``), each sensor's together weighing
      ``refine_patch_weight`` times its contact point.
    - ``rank.agreement_weight`` > 0 (``tactile6d.agreement``): render-and-compare, when ``contacts`` hold
      the observed patches (source ``patch``; landmark contacts, as the baseline's, have none, and are
      ranked without it). Each pose's predicted contact on every gel is compared with the observed patch
      and ``agreement_weight`` (m) times the agreement cost is added to the score. ``mesh`` (the object,
      ``trimesh.Trimesh`` or ``render.MeshArrays``) is required then.
    """
    pieces = model.pieces
    contacts = contacts if contacts is not None else sensors_to_landmark_contacts(T_world_sensors)
    if settings.refine and surface is None:
        raise InputError("rank.refine needs the object's surface samples")
    compare = settings.uses_agreement and contacts.observed
    if compare and mesh is None:
        raise InputError("rank.agreement_weight > 0 needs the object's mesh to compare with the observed patches")
    first = ranking.rank_poses(
        poses,
        losses,
        partial(collision.poses_to_fcl_depths, model, T_world_sensor=T_world_sensors),
        top_k=int(settings.candidates if settings.refine or compare else settings.top_k),
        tol_translation=float(settings.dedup_translation),
        tol_rotation=float(np.radians(settings.dedup_rotation)),
        depth_bounds=(
            partial(collision.poses_to_vertex_depth_bounds, pieces, T_world_sensor=T_world_sensors),
            partial(collision.poses_to_box_depth_bounds, pieces, T_world_sensor=T_world_sensors),
        ),
        batch=int(settings.batch),
        allowance=sensors.contact_sigma,
    )
    if not (settings.refine or compare):
        return first
    candidates, new_losses, depths, n_scored = first.poses, first.losses, first.penetrations, first.n_scored
    scored_depths, correction_cost = depths, 0.0
    seen = None  # (P, L, 4, 4) the object as each corrected sensor sees it, when the sensors are corrected
    if settings.refine:
        s, n = contacts.points, contacts.normals
        w, offset = float(settings.refine_normal_weight), contacts.offsets(settings.refine_offset)
        extra, owners = contacts.patch_points(T_world_sensors, int(settings.refine_patch_points))
        # Each sensor's patch points together weigh refine_patch_weight (residual weights add in squares).
        per_sensor = np.bincount(owners, minlength=len(s))[owners]
        extra_w = float(settings.refine_patch_weight) / np.sqrt(np.maximum(per_sensor, 1))
        if not sensors.exact:
            sigma_contact, sigma_angle = sensors.correction_sigmas
            candidates, seen = refinement.refine_poses_and_sensors(
                surface, candidates, s, n, sigma_contact, sigma_angle, n_iterations=int(settings.refine_iterations),
                normal_weight=w, offset=offset, patch_points=extra, patch_weights=extra_w, patch_owners=owners)
            correction_cost = refinement.sensor_corrections_cost(candidates, seen, s, sigma_contact, sigma_angle)
        else:
            candidates = refinement.refine_poses(surface, candidates, s, n, int(settings.refine_iterations), w,
                                                 offset, patch_points=extra, patch_weights=extra_w)
        distance, angle = refinement.surface_losses(surface, candidates if seen is None else seen, s, n, w, offset)
        new_losses = distance + w * angle
        # Reported: the penetrations through the sensor poses as given; scored: through the corrected ones.
        depths = collision.poses_to_penetrations(model, candidates, T_world_sensors)
        scored_depths = depths if seen is None else seen_penetrations(model, seen, T_world_sensors)
        n_scored += len(candidates)
    scores = new_losses + ranking.penetration_cost(scored_depths, sensors.contact_sigma)
    scores = scores + settings.pose_correction_weight * correction_cost
    if compare:
        scores = scores + settings.agreement_weight * agreement_cost(
            mesh, candidates if seen is None else seen, T_world_sensors, contacts, settings)
    kept = ranking.distinct_in_order(
        candidates, np.lexsort((np.arange(len(scores)), scores)), float(settings.dedup_translation),
        float(np.radians(settings.dedup_rotation)), int(settings.top_k),
    )
    return ranking.RankedPoses(candidates[kept], scores[kept], new_losses[kept], depths[kept], first.index[kept],
                               n_scored)


def seen_penetrations(model: collision.PenetrationModel, seen: np.ndarray, T_world_sensors: np.ndarray) -> np.ndarray:
    """(P, L) m: each sensor's penetration by the object as that sensor sees it, seen (P, L, 4, 4)."""
    return np.stack([collision.poses_to_penetrations(model, seen[:, i], T_world_sensors[i : i + 1])[:, 0]
                     for i in range(len(T_world_sensors))], axis=1)


def agreement_cost(mesh, poses: np.ndarray, T_world_sensors: np.ndarray, contacts: Contacts,
                   settings: RankSettings) -> np.ndarray:
    """Render-and-compare cost (P,) of poses (P, 4, 4) against the observed patches of ``contacts``:
    ``agreement.agreement_to_cost`` of the terms on the ray grid of ``rank.agreement_step`` pixels, a
    block being pressed when at least half of its pixels are in the observed mask. Poses (P, L, 4, 4):
    the object as each sensor sees it (``refine.refine_poses_and_sensors``)."""
    step = int(settings.agreement_step)
    observed_mask = agreement.image_to_grid(contacts.masks, step) >= 0.5
    observed_depth = agreement.image_to_grid(contacts.depths, step)
    margin = float(settings.agreement_free_margin)
    if poses.ndim == 4:
        per_sensor = [agreement.poses_to_agreement(mesh, poses[:, i], T_world_sensors[i : i + 1], observed_mask[i : i + 1],
                                                   observed_depth[i : i + 1], step, margin)
                      for i in range(len(T_world_sensors))]
        terms = {key: np.concatenate([t[key] for t in per_sensor], axis=1) for key in per_sensor[0]}
    else:
        terms = agreement.poses_to_agreement(mesh, poses, T_world_sensors, observed_mask, observed_depth, step, margin)
    return agreement.agreement_to_cost(
        terms,
        mask_weight=float(settings.agreement_mask_weight),
        depth_weight=float(settings.agreement_depth_weight),
        free_area_weight=float(settings.agreement_free_area_weight),
        free_depth_weight=float(settings.agreement_free_depth_weight),
    )


def load_pieces(artifacts_dir: str | Path, name: str) -> collision.ConvexPieces:
    """The object's convex collision pieces (stage prepare_object)."""
    path = require(layout.object_file(artifacts_dir, name), "prepare_object", name)
    return collision.vertices_to_pieces([v for v, _ in unpack_pieces(read_artifact(path, "object").data)])


def load_mesh(artifacts_dir: str | Path, name: str) -> trimesh.Trimesh:
    """The object's clean mesh (stage prepare_object), object frame: what render-and-compare ray-casts and
    ``rank.refine`` samples (``contact.sample_surface``)."""
    path = require(layout.object_file(artifacts_dir, name), "prepare_object", name)
    art = read_artifact(path, "object")
    return trimesh.Trimesh(np.asarray(art["vertices"]), np.asarray(art["faces"]), process=False)
