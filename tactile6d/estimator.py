"""The online pose estimator: one object's cached artifacts in, ranked ``T_world_object`` out (DESIGN §1 steps 4-8).

Steps, each a module-level function that the DVC stages (select_tuples, optimize, rank) call too, so that
an offline run and an online estimate of the same input give the same result:

1. ``encode``: tactile images (L, 320, 240, 3) uint8 RGB -> latent angles (L,) rad (the autoencoder);
2. ``select``: database point tuples (T, L) whose latent angles (method ``ours``) and pairwise
   distances match the sensors' (``tactile6d.selection``); method ``baseline`` skips the angles;
3. ``optimize``: one or 15 poses per tuple (``tactile6d.optimize``, solver ``fast`` or ``gd``);
4. ``rank``: the top-k distinct poses by loss + deepest sensor penetration (``tactile6d.collision``,
   ``tactile6d.ranking``).

``Estimator`` holds one object's arrays and runs the four steps; ``Estimator.from_artifacts`` loads them
from an artifacts directory (no DVC needed), the plain constructor takes arrays (tests, robots with
their own storage).

Randomness: every call draws from fresh generators seeded by ``select.seed`` (used only when L = 1) and
``optimize.seed`` (each tuple's random rotation), so the same input always gives the same estimate.

The ``tuples``, ``hypotheses`` and ``ranked`` artifact schemas of the three stages are registered here,
beside the code that fills them.

Units: metres, radians; poses are 4x4 float64 (``T_world_sensor``, ``T_world_object``).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from tactile6d import collision, layout, ranking, selection
from tactile6d import refine as refinement
from tactile6d import optimize as optimization
from tactile6d.errors import ArtifactError, ConfigError, DataError, InputError
from tactile6d.geometry import is_rotation, make_pose, rotmat_to_rotvec, rotvec_to_rotmat
from tactile6d.io import TACTILE_IMAGE_SHAPE, Schema, read_artifact, register_schema
from tactile6d.sensor import contact_normals, contact_points

METHODS = ("ours", "baseline")
SOLVERS = ("fast", "gd")
STEPS = ("encode", "select", "optimize", "rank")

# Artifacts of the per-run stages (layout.run_dir), one row per scene of the set. Ragged per-scene arrays
# are stacked over the scenes, with ``offsets`` (S + 1,): scene s owns rows offsets[s]:offsets[s + 1].
# ``failure`` (S,) says why a scene has no estimate ('' when it has one); the sensor poses and the
# seconds of earlier steps are carried forward so that each stage reads only its predecessor's file.
_RUN_FIELDS = ("names", "objects", "T_world_sensors", "failure")  # carried through all three
register_schema(Schema(
    "tuples", 1, "select_tuples",
    _RUN_FIELDS + ("tuples", "errors", "offsets", "angles", "omega_sizes", "delta_h", "widened", "delta_d",
                   "capped", "seconds_encode", "seconds_select"),
))
register_schema(Schema(
    "hypotheses", 1, "optimize",
    _RUN_FIELDS + ("translations", "rotvecs", "losses", "tuple_index", "offsets", "seconds_encode",
                   "seconds_select", "seconds_optimize"),
))
register_schema(Schema(
    "ranked", 1, "rank",
    _RUN_FIELDS + ("poses", "scores", "losses", "penetrations", "n_poses", "seconds_encode", "seconds_select",
                   "seconds_optimize", "seconds_rank"),
))


# --- settings ----------------------------------------------------------------------------------------


def _fields(section: Mapping, cls) -> dict:
    names = list(cls.__dataclass_fields__)
    missing = [n for n in names if n not in section]
    if missing:
        raise ConfigError(f"config section for {cls.__name__} lacks keys {missing}")
    return {n: section[n] for n in names}


@dataclass(frozen=True)
class SelectSettings:
    """The ``select`` config section (conf/select/default.yaml documents each key)."""

    method: str
    delta_h: float
    delta_h_widen_step: float
    delta_h_max: float
    N: int
    delta_d_start: float
    delta_d_down: float
    delta_d_up: float
    delta_d_max: float
    seed: int
    delta_d_rule: str
    normal_tol_deg: float | None
    normal_max_sensors: int | None

    @classmethod
    def from_cfg(cls, section: Mapping) -> SelectSettings:
        out = cls(**_fields(section, cls))
        if out.method not in METHODS:
            raise ConfigError(f"select.method must be one of {', '.join(METHODS)}, not {out.method!r}")
        if out.delta_d_rule not in selection.DELTA_D_RULES:
            raise ConfigError(f"select.delta_d_rule must be one of {', '.join(selection.DELTA_D_RULES)}, "
                              f"not {out.delta_d_rule!r}")
        if not (out.delta_h > 0 and out.delta_h_widen_step > 0 and out.delta_h_max >= out.delta_h):
            raise ConfigError(f"select needs delta_h > 0, delta_h_widen_step > 0 and delta_h_max >= delta_h; got "
                              f"{out.delta_h}, {out.delta_h_widen_step}, {out.delta_h_max}")
        if out.normal_tol_deg is not None and not out.normal_tol_deg > 0:
            raise ConfigError(f"select.normal_tol_deg must be null (off) or > 0, got {out.normal_tol_deg}")
        _check_max_sensors("select", out.normal_max_sensors)
        return out

    @property
    def uses_normals(self) -> bool:
        """Whether the normal check can apply at all (then the database normals are needed)."""
        return self.normal_tol_deg is not None

    def normals_apply(self, n_sensors: int) -> bool:
        """Whether the normal check applies to an estimate from ``n_sensors`` sensors."""
        return self.uses_normals and (self.normal_max_sensors is None or n_sensors <= self.normal_max_sensors)


def _check_max_sensors(section: str, value) -> None:
    if value is not None and not (isinstance(value, int) and value >= 1):
        raise ConfigError(f"{section}.normal_max_sensors must be null (any L) or an integer >= 1, got {value!r}")


def needs_normals(settings: Settings) -> bool:
    """Whether the database normals are read: normal-consistent selection or the orientation-aware loss."""
    return settings.select.uses_normals or settings.optimize.normal_weight > 0


@dataclass(frozen=True)
class OptimizeSettings:
    """The ``optimize`` config section (conf/optimize/default.yaml)."""

    solver: str
    n_irls: int
    n_steps: int
    gain_t: float
    gain_r: float
    offset: float
    n_translations: int
    precision: str
    cpu_devices: int
    seed: int
    normal_weight: float
    normal_max_sensors: int | None

    @classmethod
    def from_cfg(cls, section: Mapping) -> OptimizeSettings:
        out = cls(**_fields(section, cls))
        if out.solver not in SOLVERS:
            raise ConfigError(f"optimize.solver must be one of {', '.join(SOLVERS)}, not {out.solver!r}")
        if out.normal_weight < 0:
            raise ConfigError(f"optimize.normal_weight must be >= 0, got {out.normal_weight}")
        if out.normal_weight > 0 and out.solver != "fast":
            # the gd solver is the paper's, on positions only: say how to get it rather than drop the term
            raise ConfigError(f"optimize.normal_weight={out.normal_weight} needs solver fast; with solver "
                              f"{out.solver!r} set optimize.normal_weight=0 too (or use preset=paper)")
        _check_max_sensors("optimize", out.normal_max_sensors)
        return out

    def normal_weight_for(self, n_sensors: int) -> float:
        """The normal term's weight for an estimate from ``n_sensors`` sensors (0: positions only)."""
        if self.normal_max_sensors is not None and n_sensors > self.normal_max_sensors:
            return 0.0
        return float(self.normal_weight)


@dataclass(frozen=True)
class RankSettings:
    """The ``rank`` config section (conf/rank/default.yaml); ``dedup_rotation`` in degrees."""

    top_k: int
    dedup_translation: float
    dedup_rotation: float
    batch: int
    refine: bool
    refine_candidates: int
    refine_iterations: int
    refine_normal_weight: float
    refine_offset: float

    @classmethod
    def from_cfg(cls, section: Mapping) -> RankSettings:
        out = cls(**_fields(section, cls))
        if out.top_k < 1 or out.batch < 1:
            raise ConfigError(f"rank.top_k and rank.batch must be >= 1, got {out.top_k}, {out.batch}")
        if out.refine and (out.refine_candidates < out.top_k or out.refine_iterations < 1 or out.refine_normal_weight < 0):
            raise ConfigError("rank.refine needs refine_candidates >= top_k, refine_iterations >= 1 and "
                              "refine_normal_weight >= 0")
        return out


@dataclass(frozen=True)
class Settings:
    """All the estimator reads from the config: the select, optimize and rank sections."""

    select: SelectSettings
    optimize: OptimizeSettings
    rank: RankSettings

    @classmethod
    def from_cfg(cls, cfg: Mapping) -> Settings:
        missing = [k for k in ("select", "optimize", "rank") if k not in cfg]
        if missing:
            raise ConfigError(f"config lacks sections {missing}")
        return cls(
            SelectSettings.from_cfg(cfg["select"]),
            OptimizeSettings.from_cfg(cfg["optimize"]),
            RankSettings.from_cfg(cfg["rank"]),
        )


# --- input checks ------------------------------------------------------------------------------------


def check_sensor_poses(T_world_sensors) -> np.ndarray:
    """Sensor poses -> (L, 4, 4) float64, L >= 1; InputError naming the first bad one."""
    T = np.asarray(T_world_sensors, dtype=np.float64)
    if T.ndim == 2 and T.shape == (4, 4):
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] < 1:
        raise InputError(f"sensor poses must be (L, 4, 4) with L >= 1, got shape {T.shape}")
    for i, pose in enumerate(T):
        if not np.all(np.isfinite(pose)):
            raise InputError(f"sensor pose {i} has NaN or infinite entries")
        if not is_rotation(pose[:3, :3], atol=1e-5):
            raise InputError(f"sensor pose {i}: the upper-left 3x3 block is not a rotation matrix")
        if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]):
            raise InputError(f"sensor pose {i}: the last row must be 0 0 0 1, got {pose[3].tolist()}")
    return T


def check_images(images, n_sensors: int) -> np.ndarray:
    """L tactile images (an array or a sequence of arrays) -> (L, 320, 240, 3) uint8, one per sensor."""
    if images is None:
        raise InputError("method 'ours' needs one tactile image per sensor, got none")
    if isinstance(images, np.ndarray) and images.ndim == 4:
        images = list(images)
    elif isinstance(images, np.ndarray):
        raise InputError(f"tactile images must be (L, 320, 240, 3), got shape {images.shape}")
    if len(images) != n_sensors:
        raise InputError(f"{len(images)} tactile images for {n_sensors} sensor poses")
    for i, image in enumerate(images):
        image = np.asarray(image)
        if image.shape != TACTILE_IMAGE_SHAPE:
            raise InputError(f"image {i} has shape {image.shape}, a DIGIT image is (320, 240, 3): "
                             "320 rows x 240 columns x RGB")
        if image.dtype != np.uint8:
            raise InputError(f"image {i} has dtype {image.dtype}, tactile images must be uint8")
    return np.stack([np.asarray(image) for image in images])


# --- the four steps ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Selection:
    """Result and diagnostics of the selection step.

    tuples (T, L) int64 database indices; errors (T,) mean pair-distance error (m); omega_sizes (L,)
    |Omega_i|; delta_h (L,) the latent-angle threshold each sensor used (rad; NaN for the baseline);
    widened (L,) whether it had to be raised above ``select.delta_h``; delta_d the distance threshold
    the adaptive rule stopped at (m); capped: only the N lowest-error tuples were kept.
    """

    tuples: np.ndarray
    errors: np.ndarray
    omega_sizes: np.ndarray
    delta_h: np.ndarray
    widened: np.ndarray
    delta_d: float
    capped: bool


def select(
    points: np.ndarray,
    db_angles: np.ndarray | None,
    T_world_sensors: np.ndarray,
    angles: np.ndarray | None,
    settings: SelectSettings,
    normals: np.ndarray | None = None,
) -> Selection:
    """Tactile then distance selection (DESIGN §1 steps 4, 5; step 8 for method 'baseline').

    points (M, 3) database points (object frame, m); db_angles (M,) their latent angles (rad; unused
    by the baseline); T_world_sensors (L, 4, 4); angles (L,) the sensors' latent angles (rad; unused by
    the baseline); normals (M, 3) the points' outward normals, needed when ``select.normal_tol_deg``
    is set (normal-consistent tuples only).
    """
    n_sensors = T_world_sensors.shape[0]
    check = None
    if settings.normals_apply(n_sensors):
        if normals is None:
            raise InputError("select.normal_tol_deg is set: the database normals are needed")
        check = selection.NormalCheck(np.asarray(normals, dtype=np.float64), contact_normals(T_world_sensors),
                                      float(np.radians(settings.normal_tol_deg)))
    if settings.method == "ours":
        if db_angles is None or angles is None:
            raise InputError("method 'ours' needs the database's and the images' latent angles")
        # The widening is reported in Selection.widened; no warning per scene.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tactile = selection.angles_to_omegas(
                db_angles, angles, settings.delta_h, settings.delta_h_widen_step, settings.delta_h_max
            )
        omegas, delta_h = tactile.omegas, tactile.delta_h
        widened = delta_h > settings.delta_h + 1e-12
    else:
        omegas = selection.all_points_omegas(points.shape[0], n_sensors)
        delta_h = np.full(n_sensors, np.nan)
        widened = np.zeros(n_sensors, dtype=bool)
    chosen = selection.select_tuples(
        points,
        contact_points(T_world_sensors),
        omegas,
        n_max=int(settings.N),
        delta_start=float(settings.delta_d_start),
        step_down=float(settings.delta_d_down),
        step_up=float(settings.delta_d_up),
        delta_max=float(settings.delta_d_max),
        rng=np.random.default_rng(settings.seed),
        rule=str(settings.delta_d_rule),
        normals=check,
    )
    return Selection(
        tuples=chosen.tuples,
        errors=chosen.errors,
        omega_sizes=np.array([len(o) for o in omegas]),
        delta_h=np.asarray(delta_h, dtype=np.float64),
        widened=np.asarray(widened, dtype=bool),
        delta_d=chosen.delta_d,
        capped=chosen.capped,
    )


def optimize(
    points: np.ndarray,
    T_world_sensors: np.ndarray,
    tuples: np.ndarray,
    settings: OptimizeSettings,
    normals: np.ndarray | None = None,
) -> optimization.PoseHypotheses:
    """Pose hypotheses for the tuples (DESIGN §1 step 6): (P, 4, 4) poses, (P,) losses (m), tuple index.

    normals (M, 3): the database normals, needed when ``optimize.normal_weight`` > 0.
    """
    return optimization.tuples_to_poses(
        points,
        contact_points(T_world_sensors),
        tuples,
        settings.solver,
        np.random.default_rng(settings.seed),
        n_steps=int(settings.n_steps),
        gain_t=float(settings.gain_t),
        gain_r=float(settings.gain_r),
        offset=float(settings.offset),
        n_translations=int(settings.n_translations),
        n_irls=int(settings.n_irls),
        precision=str(settings.precision),
        normals=normals,
        sensor_normals=contact_normals(T_world_sensors),
        normal_weight=settings.normal_weight_for(T_world_sensors.shape[0]),
    )


def rank(
    model: collision.PenetrationModel,
    T_world_sensors: np.ndarray,
    poses: np.ndarray,
    losses: np.ndarray,
    settings: RankSettings,
    surface=None,
) -> ranking.RankedPoses:
    """The top-k distinct poses by loss + deepest sensor penetration (DESIGN §1 step 7).

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


def compact_hypotheses(poses: np.ndarray, losses: np.ndarray) -> dict[str, np.ndarray]:
    """Poses (P, 4, 4) and losses (P,) -> float32 ``translations`` (P, 3) m, ``rotvecs`` (P, 3) rad, ``losses``.

    The form hypotheses.h5 stores. The estimator ranks ``expand_hypotheses(compact_hypotheses(...))``
    too, so an offline run ranks exactly the poses an online estimate ranks: fcl's penetration depth
    is not continuous in the pose (EPA stops early on some contacts, see collision.py), so even the
    ~1e-8 m of float32 rounding could otherwise change a depth, and the ranking, now and then.
    """
    return {
        "translations": np.asarray(poses, dtype=np.float64)[:, :3, 3].astype(np.float32),
        "rotvecs": rotmat_to_rotvec(np.asarray(poses, dtype=np.float64)[:, :3, :3]).astype(np.float32),
        "losses": np.asarray(losses).astype(np.float32),
    }


def expand_hypotheses(translations, rotvecs, losses) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``compact_hypotheses``: -> poses (P, 4, 4) float64, losses (P,) float64."""
    R = rotvec_to_rotmat(np.asarray(rotvecs, dtype=np.float64))
    poses = make_pose(R, np.asarray(translations, dtype=np.float64))
    return poses, np.asarray(losses, dtype=np.float64)


# --- loading one object's artifacts ------------------------------------------------------------------


def _require(path: Path, stage: str, name: str) -> Path:
    """A missing artifact is the usual first-run error: name the exact DVC command that makes it."""
    if not path.is_file():
        raise ArtifactError(f"{path}: missing; make it with `dvc repro {stage}@{name}` (or `dvc repro` for all)")
    return path


def load_surface_points(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The object's M database points (M, 3), object frame, m (stage sample_surface)."""
    path = _require(layout.surface_file(artifacts_dir, name), "sample_surface", name)
    return np.asarray(read_artifact(path, "surface")["points"], dtype=np.float64)


def load_surface_normals(artifacts_dir: str | Path, name: str) -> np.ndarray:
    """The database points' outward unit normals (M, 3), object frame (stage sample_surface)."""
    path = _require(layout.surface_file(artifacts_dir, name), "sample_surface", name)
    return np.asarray(read_artifact(path, "surface")["normals"], dtype=np.float64)


def load_database_angles(artifacts_dir: str | Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The database images' latent angles (M,) rad and the no-contact latent (128,) (stage encode_database)."""
    path = _require(layout.latents_file(artifacts_dir, name), "encode_database", name)
    art = read_artifact(path, "latents")
    return np.asarray(art["angles"], dtype=np.float64), np.asarray(art["latent_nc"], dtype=np.float32)


def load_refine_surface(artifacts_dir: str | Path, name: str):
    """The object's clean mesh (stage prepare_object) as ``contact.SurfaceSamples`` (1 mm samples with
    face normals), the surface ``rank.refine`` fits the sensors' contacts to."""
    import trimesh

    from tactile6d.contact import sample_surface

    path = _require(layout.object_file(artifacts_dir, name), "prepare_object", name)
    art = read_artifact(path, "object")
    return sample_surface(trimesh.Trimesh(np.asarray(art["vertices"]), np.asarray(art["faces"]), process=False))


def load_pieces(artifacts_dir: str | Path, name: str) -> collision.ConvexPieces:
    """The object's convex collision pieces (stage prepare_object)."""
    from tactile6d.meshes import unpack_pieces

    path = _require(layout.object_file(artifacts_dir, name), "prepare_object", name)
    return collision.vertices_to_pieces([v for v, _ in unpack_pieces(read_artifact(path, "object").data)])


def load_background(cfg: Mapping, data_dir: str | Path | None = None) -> np.ndarray:
    """The no-contact image the tactile images were rendered over, (320, 240, 3) uint8 **RGB**.

    ``render.background`` is a path relative to the data directory: ``data_dir`` when given, else the
    one ``tactile6d.data.DataStore`` resolves from ``paths``. The PNG is read in RGB order like the
    tactile images (``io.read_tactile_image``): the renderer takes the file in OpenCV's BGR order
    (``render.load_background_bgr``) and flips it to RGB itself, so its no-contact output is the file's
    RGB; the paper's images match it there channel for channel.
    """
    from tactile6d.io import read_tactile_image

    relpath = str(cfg["render"]["background"])
    if data_dir is not None:
        path = Path(data_dir) / relpath
        if not path.is_file():
            raise DataError(f"no-contact background {path} not found (render.background under the data directory)")
    else:
        from tactile6d.data import DataStore

        path = DataStore(cfg["paths"]).path(relpath)
    return read_tactile_image(path)


class LatentAngleEncoder:
    """Images (L, 320, 240, 3) uint8 RGB -> (L,) latent angles (rad) of a trained autoencoder.

    The angle is ``arccos(cos_sim(h, h_nc))`` with ``h_nc`` the no-contact latent the database angles
    were computed against (from latents.h5), so image and database angles are comparable.
    """

    def __init__(self, model, norm, background: np.ndarray, latent_nc: np.ndarray):
        self.model, self.norm = model, norm
        self.background = np.asarray(background)
        self.latent_nc = np.asarray(latent_nc)

    @classmethod
    def from_checkpoint(cls, path: str | Path, background: np.ndarray, latent_nc: np.ndarray) -> LatentAngleEncoder:
        from tactile6d.autoencoder import load_checkpoint

        model, norm, _ = load_checkpoint(path)
        return cls(model, norm, background, latent_nc)

    def __call__(self, images: np.ndarray) -> np.ndarray:
        from tactile6d.autoencoder import encode, latent_angles

        return latent_angles(encode(self.model, self.norm, images, self.background), self.latent_nc)


# --- the estimator -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Estimate:
    """Ranked poses of one estimate, best first.

    poses (K, 4, 4) ``T_world_object``; scores (K,) loss + deepest penetration (m); losses (K,) m;
    penetrations (K, L) m; angles (L,) the images' latent angles (rad; None for the baseline);
    selection: the selection diagnostics; n_hypotheses: poses ranked; seconds: wall-clock time per step
    (encode, select, optimize, rank) and in total.
    """

    poses: np.ndarray
    scores: np.ndarray
    losses: np.ndarray
    penetrations: np.ndarray
    angles: np.ndarray | None
    selection: Selection
    n_hypotheses: int
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def best(self) -> np.ndarray:
        """The best-ranked pose (4, 4)."""
        return self.poses[0]

    def to_dict(self) -> dict:
        """JSON-ready summary: poses as nested lists, diagnostics as numbers."""
        sel = self.selection
        return {
            "poses": self.poses.tolist(),
            "scores": self.scores.tolist(),
            "losses": self.losses.tolist(),
            "penetrations": self.penetrations.tolist(),
            "seconds": dict(self.seconds),
            "selection": {
                "angles": None if self.angles is None else self.angles.tolist(),
                "omega_sizes": sel.omega_sizes.tolist(),
                "delta_h": [None if np.isnan(d) else float(d) for d in sel.delta_h],
                "widened": sel.widened.tolist(),
                "delta_d": sel.delta_d,
                "n_tuples": int(sel.tuples.shape[0]),
                "capped": sel.capped,
            },
            "n_hypotheses": self.n_hypotheses,
        }


class Estimator:
    """Pose estimation for one object.

    points (M, 3) database points (object frame, m); pieces: the object's convex collision pieces
    (``collision.ConvexPieces``, or a sequence of (V, 3) vertex arrays); db_angles (M,) the database
    images' latent angles (rad) and encoder: images (L, 320, 240, 3) uint8 RGB -> (L,) latent angles,
    both needed by method 'ours' only; settings: the select/optimize/rank config (``Settings``), by
    default conf/'s; normals (M, 3) the database points' outward normals, needed by
    ``select.normal_tol_deg`` and ``optimize.normal_weight``; surface: the object's surface samples
    (``contact.SurfaceSamples``, or a ``trimesh.Trimesh`` to sample), needed by ``rank.refine``.
    """

    def __init__(
        self,
        points: np.ndarray,
        pieces: collision.ConvexPieces | Sequence[np.ndarray],
        db_angles: np.ndarray | None = None,
        encoder: Callable[[np.ndarray], np.ndarray] | None = None,
        settings: Settings | None = None,
        normals: np.ndarray | None = None,
        surface=None,
    ):
        self.settings = settings if settings is not None else Settings.from_cfg(_default_cfg())
        self.points = np.asarray(points, dtype=np.float64)
        if self.points.ndim != 2 or self.points.shape[1] != 3 or self.points.shape[0] == 0:
            raise InputError(f"database points must be (M, 3) with M >= 1, got {self.points.shape}")
        if db_angles is not None:
            db_angles = np.asarray(db_angles, dtype=np.float64)
            if db_angles.shape != self.points.shape[:1]:
                raise InputError(f"{db_angles.shape} database angles for {self.points.shape[0]} points")
        if self.settings.select.method == "ours" and (db_angles is None or encoder is None):
            raise InputError("select.method=ours needs the database angles and an image encoder")
        self.db_angles = db_angles
        self.encoder = encoder
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float64)
            if normals.shape != self.points.shape:
                raise InputError(f"{normals.shape} database normals for {self.points.shape[0]} points")
        if needs_normals(self.settings) and normals is None:
            raise InputError("select.normal_tol_deg / optimize.normal_weight need the database normals")
        self.normals = normals
        if surface is not None and not hasattr(surface, "tree"):
            from tactile6d.contact import sample_surface

            surface = sample_surface(surface)
        if self.settings.rank.refine and surface is None:
            raise InputError("rank.refine needs the object's surface (a mesh or contact.SurfaceSamples)")
        self.surface = surface
        if not isinstance(pieces, collision.ConvexPieces):
            pieces = collision.vertices_to_pieces(list(pieces))
        self.penetration_model = collision.PenetrationModel(pieces)
        if self.settings.optimize.solver == "gd":
            optimization.use_cpu_devices(self.settings.optimize.cpu_devices)

    @classmethod
    def from_artifacts(
        cls,
        object_name: str,
        artifacts_dir: str | Path,
        cfg: Mapping | None = None,
        data_dir: str | Path | None = None,
        background: np.ndarray | None = None,
    ) -> Estimator:
        """Load one object's artifacts: object.h5 (collision pieces), surface.h5 (points) and, for
        method 'ours', latents.h5 (angles) and the autoencoder checkpoint. cfg: the composed config
        (default: conf/ with no overrides). ArtifactError names a missing file and the command that
        makes it.

        background: the no-contact image (320, 240, 3) uint8 RGB of the sensor whose images will be
        estimated; the encoder sees each image minus it. Pass your own sensor's when it is not the
        simulated one; by default it is ``render.background`` from the data directory
        (``load_background``), the background the databases and the paper's images were rendered over.
        """
        cfg = cfg if cfg is not None else _default_cfg()
        settings = Settings.from_cfg(cfg)
        points = load_surface_points(artifacts_dir, object_name)
        pieces = load_pieces(artifacts_dir, object_name)
        db_angles = encoder = None
        if settings.select.method == "ours":
            db_angles, latent_nc = load_database_angles(artifacts_dir, object_name)
            if background is None:
                background = load_background(cfg, data_dir)
            encoder = LatentAngleEncoder.from_checkpoint(
                layout.ae_checkpoint(artifacts_dir), check_images(np.asarray(background)[None], 1)[0], latent_nc
            )
        normals = load_surface_normals(artifacts_dir, object_name) if needs_normals(settings) else None
        surface = load_refine_surface(artifacts_dir, object_name) if settings.rank.refine else None
        return cls(points, pieces, db_angles, encoder, settings, normals, surface)

    # Each step is public so that a caller can run, time or inspect it alone.

    def encode(self, images) -> np.ndarray:
        """(L, 320, 240, 3) uint8 RGB -> (L,) latent angles (rad)."""
        if self.encoder is None:
            raise InputError("this estimator has no image encoder (built for the baseline)")
        images = np.asarray(images)
        return np.asarray(self.encoder(images), dtype=np.float64).reshape(images.shape[0])

    def select(self, T_world_sensors, angles: np.ndarray | None = None) -> Selection:
        """Candidate tuples for the sensors at T_world_sensors (L, 4, 4), given the images' angles (L,)."""
        return select(self.points, self.db_angles, check_sensor_poses(T_world_sensors), angles, self.settings.select,
                      self.normals)

    def optimize(self, T_world_sensors, tuples: np.ndarray) -> optimization.PoseHypotheses:
        """Pose hypotheses for tuples (T, L) of database indices."""
        return optimize(self.points, check_sensor_poses(T_world_sensors), tuples, self.settings.optimize, self.normals)

    def rank(self, T_world_sensors, poses: np.ndarray, losses: np.ndarray) -> ranking.RankedPoses:
        """The top-k distinct poses of (P, 4, 4) hypotheses with losses (P,), rounded first to the form
        the optimize stage stores (``compact_hypotheses``), so that online and offline rank alike."""
        poses, losses = expand_hypotheses(**compact_hypotheses(poses, losses))
        return rank(self.penetration_model, check_sensor_poses(T_world_sensors), poses, losses, self.settings.rank,
                    self.surface)

    def estimate(self, T_world_sensors, images=None) -> Estimate:
        """The ranked poses for sensors at T_world_sensors (L, 4, 4) with images (L, 320, 240, 3) uint8 RGB.

        Images are required by method 'ours'; the baseline ignores them (but checks them when given).
        """
        start = time.perf_counter()
        T = check_sensor_poses(T_world_sensors)
        ours = self.settings.select.method == "ours"
        if ours or images is not None:
            images = check_images(images, T.shape[0])
        seconds = {}
        t0 = time.perf_counter()
        angles = self.encode(images) if ours else None
        seconds["encode"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        chosen = select(self.points, self.db_angles, T, angles, self.settings.select, self.normals)
        seconds["select"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        hypotheses = optimize(self.points, T, chosen.tuples, self.settings.optimize, self.normals)
        seconds["optimize"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        ranked = self.rank(T, hypotheses.poses, hypotheses.losses)
        seconds["rank"] = time.perf_counter() - t0
        seconds["total"] = time.perf_counter() - start
        return Estimate(
            poses=ranked.poses,
            scores=ranked.scores,
            losses=ranked.losses,
            penetrations=ranked.penetrations,
            angles=angles,
            selection=chosen,
            n_hypotheses=int(hypotheses.poses.shape[0]),
            seconds=seconds,
        )


def _default_cfg():
    from tactile6d.config import compose_config

    return compose_config()


# --- the per-run stages' artifacts and command line --------------------------------------------------


def stack_ragged(parts: Sequence[np.ndarray], row_shape: tuple[int, ...], dtype) -> tuple[np.ndarray, np.ndarray]:
    """Per-scene arrays (n_s, *row_shape) -> (sum n_s, *row_shape) and offsets (S + 1,) int64."""
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    rows = [np.asarray(p, dtype=dtype).reshape(-1, *row_shape) for p in parts]
    return (np.concatenate(rows) if rows else np.zeros((0, *row_shape), dtype)), offsets


def scene_rows(data: np.ndarray, offsets: np.ndarray, scene: int) -> np.ndarray:
    """Scene ``scene``'s rows of an array stacked by ``stack_ragged``."""
    return data[offsets[scene] : offsets[scene + 1]]

# --- the per-run stages' command line ---------------------------------------------------------------


def median_or_nan(values) -> float:
    """The median, or NaN for an empty scene set (without NumPy's empty-slice warning)."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.median(values)) if values.size else float("nan")


def carried(art, keys: Sequence[str]) -> dict[str, np.ndarray]:
    """Datasets of a predecessor's artifact to write again; strings (read back as objects) -> str arrays."""
    return {k: np.asarray(art[k], dtype=str) if art[k].dtype == object else art[k] for k in keys}


def parse_run_stage_args(argv: list[str] | None, description: str):
    """Command line of select_tuples, optimize and rank: ``[--params FILE] --scene-set NAME --method
    ours|baseline key=value ...``. ``--method`` also sets ``select.method`` in the returned config.
    Returns ``(args, cfg)``.
    """
    import argparse

    from omegaconf import OmegaConf

    from tactile6d.config import load_config

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--params", help="composed params file (DVC passes params.yaml); default: compose conf/")
    parser.add_argument("--scene-set", required=True, help="scene set: artifacts/scenes/<name>.h5")
    parser.add_argument("--method", required=True, choices=METHODS)
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    cfg = load_config(args.overrides, args.params)
    OmegaConf.update(cfg, "select.method", args.method)
    return args, cfg
