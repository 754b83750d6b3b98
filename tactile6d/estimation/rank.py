"""Collision-aware ranking of pose hypotheses (docs/design.md, The method).

Score ``R_j = E_j + max_i d_ij``: the optimiser's loss plus the deepest penetration of the object at
pose j into any sensor's body. Near-duplicate poses (translations within ``tol_translation`` and
rotations within ``tol_rotation`` of a better-scored pose) are collapsed, then the ``top_k`` lowest
scores are returned, best first.

Only the poses that can still enter the top k are scored (branch and bound). Each pose carries a
lower bound on its score, at first its loss (depths are >= 0). A batch of the poses with the lowest
bounds is taken at a time: a pose whose bound came from the loss gets the first (cheapest) depth
bound function applied, one with the first bound gets the second, and so on; one with all bounds
gets its exact depths. This stops as soon as no unscored pose's bound is below the k-th best distinct
score so far: no unscored pose can then beat it, nor (coming later in score order) hide one of the top
k as its duplicate. The result is the same as scoring every pose (checked against a brute-force
ranking in tests/test_collision.py), provided every bound is a true lower bound. A pose's depths are
the depth function's, raised to the bounds already computed for it (so the function may leave the
bounds out, as ``collision.poses_to_fcl_depths`` does). Ties in score are broken by input position.

``rank`` is step 4 of an estimate, as the estimator and the rank stage call it: the best distinct poses by
loss + deepest sensor penetration, optionally re-scored by surface refinement and by render-and-compare.
What it needs of the object (its convex collision pieces and, for the re-scoring, its mesh and surface
samples) is loaded by ``data.object_artifacts``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from tactile6d.core.errors import InputError
from tactile6d.core.geometry import rotation_angle
from tactile6d.core.settings import RankSettings, SensorSettings
from tactile6d.estimation import collision
from tactile6d.estimation import refine as refinement
from tactile6d.estimation import render_and_compare
from tactile6d.perception.contacts import Contacts, sensors_to_landmark_contacts


@dataclass(frozen=True)
class RankedPoses:
    """The top k distinct poses, best first.

    poses (K, 4, 4) ``T_world_object``; scores (K,) m; losses (K,) m; penetrations (K, L) m;
    index (K,) positions in the ranked input; n_scored how many poses had their depths computed.
    """

    poses: np.ndarray
    scores: np.ndarray
    losses: np.ndarray
    penetrations: np.ndarray
    index: np.ndarray
    n_scored: int


def distinct_in_order(poses: np.ndarray, order: np.ndarray, tol_translation: float, tol_rotation: float, limit: int) -> list[int]:
    """Greedy de-duplication: walk ``order`` (indices into poses (P, 4, 4)) and keep a pose unless it
    is within tol_translation (m) and tol_rotation (rad) of one already kept; stop at ``limit`` kept.
    Returns the kept indices, in walking order.

    Vectorised over the walk: each pose kept strikes out at once every later pose that duplicates it, so
    the cost is one array operation per kept pose, not one per pose walked (the optimiser's hypotheses
    come in tight clusters, so most poses walked are duplicates). Same decisions, bit for bit, as the
    pose-by-pose walk (``tests/test_collision.py``'s reference).
    """
    order = np.asarray(order, dtype=np.int64).reshape(-1)
    translations = poses[order, :3, 3]
    rotations = poses[order, :3, :3]
    free = np.ones(len(order), dtype=bool)  # not a duplicate of a pose kept so far
    kept: list[int] = []
    start = 0
    while len(kept) < limit:
        ahead = np.flatnonzero(free[start:])
        if ahead.size == 0:
            break
        at = start + int(ahead[0])
        kept.append(int(order[at]))
        start = at + 1
        later = start + ahead[1:] - ahead[0] - 1  # the free positions after this one
        near_t = later[np.linalg.norm(translations[at] - translations[later], axis=1) <= tol_translation]
        if near_t.size:
            free[near_t[rotation_angle(rotations[at], rotations[near_t]) <= tol_rotation]] = False
    return kept


def penetration_cost(depths: np.ndarray, allowance: float = 0.0) -> np.ndarray:
    """(P, L) penetration depths (m) -> (P,) what a pose's score pays for them: the deepest, less
    ``allowance`` (the sensor poses' expected error: a true pose seen through sensor poses off by a
    millimetre penetrates a sensor by about that much), never below 0."""
    return np.maximum(np.asarray(depths).max(axis=1) - allowance, 0.0)


def rank_poses(
    poses: np.ndarray,
    losses: np.ndarray,
    penetrations: Callable[[np.ndarray], np.ndarray],
    top_k: int,
    tol_translation: float,
    tol_rotation: float,
    depth_bounds: Sequence[Callable[[np.ndarray], np.ndarray]] = (),
    batch: int = 256,
    allowance: float = 0.0,
) -> RankedPoses:
    """The top_k distinct poses by R = E + max(max_i d_i - allowance, 0), scoring only the poses that can
    make it.

    poses (P, 4, 4), losses (P,) m, penetrations: a function (B, 4, 4) -> (B, L) depths in metres
    (e.g. ``functools.partial(collision.poses_to_fcl_depths, model, T_world_sensor=...)``), which are
    raised to the pose's bounds; top_k, tol_translation m, tol_rotation rad, depth_bounds: functions
    (B, 4, 4) -> (B, L) lower bounds on the depths, cheapest first; batch: poses handled per step;
    allowance: m of penetration that costs nothing (``penetration_cost``). The depths returned are the
    penetrations themselves.
    """
    poses = np.asarray(poses, dtype=np.float64)
    losses = np.asarray(losses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or losses.shape != poses.shape[:1] or poses.shape[0] == 0:
        raise InputError(f"need poses (P, 4, 4) and losses (P,) with P >= 1, got {poses.shape}, {losses.shape}")
    if top_k < 1:
        raise InputError(f"top_k must be >= 1, got {top_k}")
    n_levels = len(depth_bounds)
    key = losses.copy()  # lower bound on each pose's score
    level = np.zeros(len(losses), dtype=np.int64)  # bounds applied so far; n_levels + 1 = scored
    lower = None  # (P, L) the largest depth bound computed so far for each pose and sensor
    scored = np.zeros(0, dtype=np.int64)
    depth_rows, scores = [], np.zeros(0)
    kept: list[int] = []
    while True:
        threshold = scores[kept[-1]] if len(kept) == top_k else np.inf
        open_ = np.flatnonzero((level <= n_levels) & (key < threshold))
        if open_.size == 0:
            break
        if open_.size > batch:
            # The batch lowest bounds, ties by input position.
            open_ = open_[np.lexsort((open_, key[open_]))[:batch]]
        # Each pose in the batch moves one step: to its next bound, or (all bounds known) to its depths.
        at = level[open_]
        for lvl in range(n_levels):
            chunk = open_[at == lvl]
            if chunk.size:
                bound = np.asarray(depth_bounds[lvl](poses[chunk]), dtype=np.float64)
                if lower is None:
                    lower = np.zeros((len(poses), bound.shape[1]))
                lower[chunk] = np.maximum(lower[chunk], bound)
                key[chunk] = np.maximum(key[chunk], losses[chunk] + penetration_cost(bound, allowance))
                level[chunk] = lvl + 1
        chunk = open_[at == n_levels]
        if chunk.size:
            depths = np.asarray(penetrations(poses[chunk]), dtype=np.float64)
            if lower is not None:
                depths = np.maximum(depths, lower[chunk])
            level[chunk] = n_levels + 1
            depth_rows.append(depths)
            scored = np.concatenate([scored, chunk])
            scores = np.concatenate([scores, losses[chunk] + penetration_cost(depths, allowance)])
            # Positions into `scored`, best score first, ties by input position.
            kept = distinct_in_order(poses[scored], np.lexsort((scored, scores)), tol_translation, tol_rotation, top_k)
    depths = np.concatenate(depth_rows)
    return RankedPoses(
        poses=poses[scored[kept]],
        scores=scores[kept],
        losses=losses[scored[kept]],
        penetrations=depths[kept],
        index=scored[kept],
        n_scored=len(scored),
    )


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
) -> RankedPoses:
    """The top-k distinct poses by loss + deepest sensor penetration (the paper's collision-aware ranking).

    model: the object's PenetrationModel; poses (P, 4, 4) ``T_world_object``; losses (P,) m; contacts:
    the sensors' contacts (default: their landmarks, ``contacts.sensors_to_landmark_contacts``); sensors:
    how far ``T_world_sensors`` may be off (``SensorSettings``): that much penetration into a sensor costs
    nothing (``penetration_cost``), and the refinement then corrects each sensor's pose too.

    With either of these on, the best ``candidates`` distinct poses ranked as above are re-scored
    (neither is in the paper):

    - ``refine`` (``tactile6d.estimation.refine``): each pose is refined against ``surface`` (the object's
      ``surface_sampling.SurfaceSamples``, required then) and scored ``d + w_n * a + deepest
      penetration``, d and a the refined pose's mean point-to-plane residual (m) and normal angle (rad)
      (``refine.surface_losses``), w_n the normals' weight (``RankSettings.surface_normal_weight``: 0 by default
      where the patches' points are fitted); ``losses`` of the result are then ``d + w_n * a``.
      With ``refine_patch_points`` > 0 and observed patches, that many points of each patch's
      pressed gel join the fit (``Contacts.patch_points``), each sensor's together weighing
      ``refine_patch_weight`` times its contact point.
    - ``agreement_weight`` > 0 (``tactile6d.estimation.render_and_compare``): render-and-compare, when ``contacts`` hold
      the observed patches (source ``patch``; landmark contacts, as the baseline's, have none, and are
      ranked without it). Each pose's predicted contact on every gel is compared with the observed patch
      and ``agreement_weight`` (m) times the agreement cost is added to the score. ``mesh`` (the object,
      ``trimesh.Trimesh`` or ``render.MeshArrays``) is required then.
    """
    pieces = model.pieces
    contacts = contacts if contacts is not None else sensors_to_landmark_contacts(T_world_sensors)
    if settings.refine and surface is None:
        raise InputError("refine needs the object's surface samples")
    compare = settings.uses_agreement and contacts.observed
    if compare and mesh is None:
        raise InputError("agreement_weight > 0 needs the object's mesh to compare with the observed patches")
    first = rank_poses(
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
    if settings.refine:
        refined = refine_and_score(model, surface, mesh if compare else None, candidates, T_world_sensors, contacts,
                                   settings, sensors, int(settings.refine_iterations))
        candidates, new_losses, scores = refined.poses, refined.losses, refined.scores
        # Reported: the penetrations through the sensor poses as given; scored: through the corrected ones.
        depths = refined.depths if sensors.exact else collision.poses_to_penetrations(model, candidates, T_world_sensors)
        n_scored += len(candidates)
    else:  # render-and-compare alone
        scores = new_losses + penetration_cost(depths, sensors.contact_sigma)
        scores = scores + settings.agreement_weight * agreement_cost(mesh, candidates, T_world_sensors, contacts, settings)
    kept = distinct_in_order(
        candidates, np.lexsort((np.arange(len(scores)), scores)), float(settings.dedup_translation),
        float(np.radians(settings.dedup_rotation)), int(settings.top_k),
    )
    return RankedPoses(candidates[kept], scores[kept], new_losses[kept], depths[kept], first.index[kept], n_scored)


@dataclass(frozen=True)
class RefinedScores:
    """Candidates refined against the touching sensors' contacts and scored term by term (``refine_and_score``).

    poses (P, 4, 4) the refined ``T_world_object``; scores (P,) m; losses (P,) m, ``d + w_n * a`` (``rank``);
    distance (P,) m, d alone (the mean point-to-plane residual); depths (P, L) m, each sensor's penetration as
    scored (through its corrected pose when it touches and the sensors are corrected); agreement (P,), the
    render-and-compare cost before its weight (0 when not computed).
    """

    poses: np.ndarray
    scores: np.ndarray
    losses: np.ndarray
    distance: np.ndarray
    depths: np.ndarray
    agreement: np.ndarray


def refine_and_score(model: collision.PenetrationModel, surface, mesh, poses: np.ndarray, T_world_sensors: np.ndarray,
                     contacts: Contacts, settings: RankSettings, sensors: SensorSettings, n_iterations: int) -> RefinedScores:
    """The ranking's re-scoring of candidate poses (P, 4, 4), as ``rank`` and the tracker's updates score them.

    Each pose is refined against the touching sensors' contacts and patches (``refine``; with the sensors'
    expected error, each touching sensor's pose corrected beside it, ``n_iterations`` steps; with
    ``refine_free_weight``, also kept off the gel the patches leave untouched) and scored (``score_refined``) through
    every sensor: ``d + w_n * a + penetration_cost(depths) + pose_correction_weight *
    corrections``, plus ``agreement_weight`` times render-and-compare when ``mesh`` is given and the contacts
    hold observed patches (a sensor whose image shows no contact pays for a pose that presses it). surface: the
    object's surface samples; mesh: its mesh, or None to leave render-and-compare out.
    """
    # Refined against the sensors the object touches; scored below through every sensor.
    fit, touched, on = touching_fit(surface, contacts, settings)
    extra, owners = touched.patch_points(T_world_sensors[on], int(settings.refine_patch_points))
    # Each sensor's patch points together weigh refine_patch_weight (residual weights add in squares).
    extra_w = _per_sensor_weights(owners, len(on), float(settings.refine_patch_weight))
    free, free_owners = {}, None  # the untouched gel's one-sided rows, with rank.refine_free_weight
    if settings.refine_free_weight > 0:
        points, free_owners = touched.free_points(T_world_sensors[on], int(settings.refine_free_stride))
        free = dict(free_points=points, free_margin=float(settings.agreement_free_margin),
                    free_weights=_per_sensor_weights(free_owners, len(on), float(settings.refine_free_weight)))
    seen = None  # (P, L, 4, 4) the object as each corrected sensor sees it
    if not sensors.exact:
        sigma_contact, sigma_angle = sensors.correction_sigmas
        poses, seen_touched = refinement.refine_poses_and_sensors(
            fit, poses, sigma_contact, sigma_angle, n_iterations=n_iterations, patch_points=extra,
            patch_weights=extra_w, patch_owners=owners, free_owners=free_owners, **free)
        seen = seen_touched
        if touched is not contacts:  # a sensor the object does not touch has no correction to see it through
            seen = np.repeat(poses[:, None], len(contacts.points), axis=1)
            seen[:, on] = seen_touched
    else:
        poses = refinement.refine_poses(fit, poses, n_iterations, patch_points=extra, patch_weights=extra_w, **free)
    return score_refined(model, fit, mesh, poses, seen, T_world_sensors, contacts, settings, sensors)


def touching_fit(surface, contacts: Contacts, settings: RankSettings) -> tuple[refinement.SurfaceFit, Contacts, np.ndarray]:
    """What the refinement fits: the ``SurfaceFit`` of the sensors the object touches (``Contacts.touching``),
    their contacts, and their indices (K,) among all sensors. The contact normals weigh
    ``settings.surface_normal_weight``: less, or nothing, where the patches' points are fitted beside them."""
    on = np.flatnonzero(contacts.touching)
    touched = contacts if len(on) == len(contacts.points) else contacts.of_sensors(on)
    normal_weight = settings.surface_normal_weight(fits_patch_points(contacts, settings))
    fit = refinement.SurfaceFit(surface, touched.points, touched.normals, normal_weight,
                                touched.offsets(settings.refine_offset))
    return fit, touched, on


def fits_patch_points(contacts: Contacts, settings: RankSettings) -> bool:
    """Whether the refinement fits the observed patches' points beside the contact points: observed patches, some
    sensor's point read from its image (where no image shows contact every sensor keeps its landmark and no patch
    point is fitted), and ``refine_patch_points`` > 0."""
    return bool(contacts.observed and contacts.from_patch.any() and settings.refine_patch_points > 0)


def _per_sensor_weights(owners: np.ndarray, n_sensors: int, weight: float) -> np.ndarray:
    """Residual weights (M,) of points owned by sensors owners (M,) such that each sensor's points together
    weigh ``weight`` (residual weights add in squares)."""
    per_sensor = np.bincount(owners, minlength=n_sensors)[owners]
    return weight / np.sqrt(np.maximum(per_sensor, 1))


def score_refined(model: collision.PenetrationModel, fit: refinement.SurfaceFit, mesh, poses: np.ndarray,
                  seen: np.ndarray | None, T_world_sensors: np.ndarray, contacts: Contacts, settings: RankSettings,
                  sensors: SensorSettings) -> RefinedScores:
    """The score of ``refine_and_score`` for poses (P, 4, 4) as they stand, not refined again.

    seen (P, L, 4, 4): the object as each sensor sees it (its correction included, ``refine_poses_and_sensors``),
    or None for exact sensor poses; fit: the touching sensors' (``touching_fit``). Also scores poses seen through
    corrections of another origin: ``scripts/oracle_corrections.py`` scores the truth through the sensors' true
    errors.
    """
    on = np.flatnonzero(contacts.touching)
    w = fit.normal_weight
    distance, angle = refinement.surface_losses(fit, poses if seen is None else seen[:, on])
    losses = distance + w * angle
    correction_cost = 0.0
    if seen is None:
        depths = collision.poses_to_penetrations(model, poses, T_world_sensors)
    else:
        depths = seen_penetrations(model, seen, T_world_sensors)
        sigma_contact, sigma_angle = sensors.correction_sigmas
        correction_cost = refinement.sensor_corrections_cost(poses, seen[:, on], fit.points, sigma_contact, sigma_angle)
    scores = losses + penetration_cost(depths, sensors.contact_sigma)
    scores = scores + settings.pose_correction_weight * correction_cost
    agreement = np.zeros(len(poses))
    if mesh is not None and contacts.observed:
        agreement = agreement_cost(mesh, poses if seen is None else seen, T_world_sensors, contacts, settings)
        scores = scores + settings.agreement_weight * agreement
    return RefinedScores(poses, scores, losses, distance, depths, agreement)


def seen_penetrations(model: collision.PenetrationModel, seen: np.ndarray, T_world_sensors: np.ndarray) -> np.ndarray:
    """(P, L) m: each sensor's penetration by the object as that sensor sees it, seen (P, L, 4, 4)."""
    return np.stack([collision.poses_to_penetrations(model, seen[:, i], T_world_sensors[i : i + 1])[:, 0]
                     for i in range(len(T_world_sensors))], axis=1)


def agreement_cost(mesh, poses: np.ndarray, T_world_sensors: np.ndarray, contacts: Contacts,
                   settings: RankSettings) -> np.ndarray:
    """Render-and-compare cost (P,) of poses (P, 4, 4) against the observed patches of ``contacts``:
    ``render_and_compare.agreement_to_cost`` of the terms on the ray grid of ``agreement_step`` pixels, a
    block being pressed when at least half of its pixels are in the observed mask. Poses (P, L, 4, 4):
    the object as each sensor sees it (``refine.refine_poses_and_sensors``)."""
    step = int(settings.agreement_step)
    observed_mask = render_and_compare.image_to_grid(contacts.masks, step) >= 0.5
    observed_depth = render_and_compare.image_to_grid(contacts.depths, step)
    margin = float(settings.agreement_free_margin)
    if poses.ndim == 4:
        per_sensor = [render_and_compare.poses_to_agreement(mesh, poses[:, i], T_world_sensors[i : i + 1], observed_mask[i : i + 1],
                                                   observed_depth[i : i + 1], step, margin)
                      for i in range(len(T_world_sensors))]
        terms = {key: np.concatenate([t[key] for t in per_sensor], axis=1) for key in per_sensor[0]}
    else:
        terms = render_and_compare.poses_to_agreement(mesh, poses, T_world_sensors, observed_mask, observed_depth, step, margin)
    return render_and_compare.agreement_to_cost(
        terms,
        mask_weight=float(settings.agreement_mask_weight),
        depth_weight=float(settings.agreement_depth_weight),
        free_area_weight=float(settings.agreement_free_area_weight),
        free_depth_weight=float(settings.agreement_free_depth_weight),
    )
