"""Step 4, rank: the best distinct poses by loss + deepest sensor penetration, with what it loads (the
object's convex collision pieces and, for ``rank.refine``, its surface samples).
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import trimesh

from tactile6d import collision, layout, ranking
from tactile6d import refine as refinement
from tactile6d.contact import SurfaceSamples, sample_surface
from tactile6d.errors import InputError
from tactile6d.io import read_artifact
from tactile6d.meshes import unpack_pieces
from tactile6d.object_artifacts import require
from tactile6d.sensor import contact_normals, contact_points
from tactile6d.settings import RankSettings


def rank(
    model: collision.PenetrationModel,
    T_world_sensors: np.ndarray,
    poses: np.ndarray,
    losses: np.ndarray,
    settings: RankSettings,
    surface=None,
) -> ranking.RankedPoses:
    """The top-k distinct poses by loss + deepest sensor penetration (the paper's collision-aware ranking).

    model: the object's PenetrationModel; poses (P, 4, 4) ``T_world_object``; losses (P,) m.

    With ``rank.refine`` (not in the paper; ``tactile6d.refine``): the best ``refine_candidates``
    distinct poses are ranked as above, each is refined against ``surface`` (the object's
    ``contact.SurfaceSamples``, required then), and the refined poses are ranked again by
    ``d + refine_normal_weight * a + deepest penetration``, d and a the refined pose's mean
    point-to-plane residual (m) and normal angle (rad) (``refine.surface_losses``); ``losses`` of
    the result are then ``d + refine_normal_weight * a``.
    """
    pieces = model.pieces
    if settings.refine and surface is None:
        raise InputError("rank.refine needs the object's surface samples")
    first = ranking.rank_poses(
        poses,
        losses,
        partial(collision.poses_to_penetrations, model, T_world_sensor=T_world_sensors),
        top_k=int(settings.refine_candidates if settings.refine else settings.top_k),
        tol_translation=float(settings.dedup_translation),
        tol_rotation=float(np.radians(settings.dedup_rotation)),
        depth_bounds=(
            partial(collision.poses_to_vertex_depth_bounds, pieces, T_world_sensor=T_world_sensors),
            partial(collision.poses_to_box_depth_bounds, pieces, T_world_sensor=T_world_sensors),
        ),
        batch=int(settings.batch),
    )
    if not settings.refine:
        return first
    s, n = contact_points(T_world_sensors), contact_normals(T_world_sensors)
    w, offset = float(settings.refine_normal_weight), float(settings.refine_offset)
    refined = refinement.refine_poses(surface, first.poses, s, n, int(settings.refine_iterations), w, offset)
    distance, angle = refinement.surface_losses(surface, refined, s, n, w, offset)
    new_losses = distance + w * angle
    depths = collision.poses_to_penetrations(model, refined, T_world_sensors)
    scores = new_losses + depths.max(axis=1)
    kept = ranking.distinct_in_order(
        refined, np.lexsort((np.arange(len(scores)), scores)), float(settings.dedup_translation),
        float(np.radians(settings.dedup_rotation)), int(settings.top_k),
    )
    return ranking.RankedPoses(refined[kept], scores[kept], new_losses[kept], depths[kept], first.index[kept],
                               first.n_scored + len(refined))


def load_pieces(artifacts_dir: str | Path, name: str) -> collision.ConvexPieces:
    """The object's convex collision pieces (stage prepare_object)."""
    path = require(layout.object_file(artifacts_dir, name), "prepare_object", name)
    return collision.vertices_to_pieces([v for v, _ in unpack_pieces(read_artifact(path, "object").data)])


def load_refine_surface(artifacts_dir: str | Path, name: str) -> SurfaceSamples:
    """The object's clean mesh (stage prepare_object) as ``contact.SurfaceSamples`` (1 mm samples with
    face normals), the surface ``rank.refine`` fits the sensors' contacts to."""
    path = require(layout.object_file(artifacts_dir, name), "prepare_object", name)
    art = read_artifact(path, "object")
    return sample_surface(trimesh.Trimesh(np.asarray(art["vertices"]), np.asarray(art["faces"]), process=False))
