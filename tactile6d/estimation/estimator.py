"""The online pose estimator: one object's cached artifacts in, ranked ``T_world_object`` out.

``Estimator`` holds one object's arrays and runs the four steps: ``perception.encode``, then
``estimation.select``, ``optimize`` and ``rank`` (each module holds its algorithm and the step that calls
it). ``Estimator.from_artifacts`` loads them from an artifacts directory (no DVC needed), the plain
constructor takes arrays (tests, robots with their own storage). ``Estimate`` is the result.

Confidence: with a calibrated ``confidence.ConfidenceModel`` (stage calibrate_confidence), each estimate
also carries the probability that its best pose is within 1 cm ADI of the truth and the ranked poses
that explain the contacts about equally well (``Estimate.confidence``, ``Estimate.distinct``).

Randomness: every call draws from fresh generators seeded by ``select.seed`` (used only when L = 1) and
``optimize.seed`` (each tuple's random rotation), so the same input always gives the same estimate.

Units: metres, radians; poses are 4x4 float64 (``T_world_sensor``, ``T_world_object``).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tactile6d.core.config import compose_config
from tactile6d.core.errors import ArtifactError, InputError
from tactile6d.core.settings import Settings, needs_normals
from tactile6d.data import layout
from tactile6d.data.object_artifacts import (
    load_collision_vertices,
    load_database_angles,
    load_mesh,
    load_surface_normals,
    load_surface_points,
)
from tactile6d.estimation import collision, confidence
from tactile6d.estimation import optimize as optimization
from tactile6d.estimation import optimize as optimize_step
from tactile6d.estimation import rank as rank_step
from tactile6d.estimation import select as select_step
from tactile6d.estimation.run_storage import compact_hypotheses, expand_hypotheses
from tactile6d.estimation.select import Selection
from tactile6d.perception import encode as encode_step
from tactile6d.perception import photometric
from tactile6d.perception.contact_patch import PatchModel
from tactile6d.perception.contacts import Contacts, warn_if_untouched
from tactile6d.perception.inputs import (
    backgrounds_per_sensor,
    body_overlap_margin,
    check_backgrounds,
    check_bodies_apart,
    check_images,
    check_images_against_backgrounds,
    check_sensor_poses,
    check_sensors_within_reach,
    warn_if_pressed_in,
    warn_if_underdetermined,
)
from tactile6d.sim.surface_sampling import sample_surface

STEPS = ("encode", "select", "optimize", "rank")


@dataclass(frozen=True)
class Estimate:
    """Ranked poses of one estimate, best first.

    poses (K, 4, 4) ``T_world_object``; scores (K,) loss + deepest penetration (m); losses (K,) m;
    penetrations (K, L) m; angles (L,) the images' latent angles (rad; None for the baseline);
    contacts: the sensors' contact points and normals the estimate used (``tactile6d.perception.contacts``);
    selection: the selection diagnostics; n_hypotheses: poses ranked; seconds: wall-clock time per step
    (encode, select, optimize, rank) and in total; light: how each image's light differed from its
    no-contact image's (``photometric.LightFit``, sensor order), None when the images were read as given.

    confidence: P(ADI of the best pose < 1 cm) from the estimator's ``confidence.ConfidenceModel``, a
    float in [0, 1]; distinct (D,) int64, D >= 1: indices into ``poses`` of the poses that explain the
    contacts about equally well (``confidence.distinct_poses``), 0 (the best) first. Both None when the
    estimator has no confidence model.
    """

    poses: np.ndarray
    scores: np.ndarray
    losses: np.ndarray
    penetrations: np.ndarray
    angles: np.ndarray | None
    contacts: Contacts
    selection: Selection
    n_hypotheses: int
    seconds: dict[str, float] = field(default_factory=dict)
    light: list[photometric.LightFit] | None = None
    confidence: float | None = None
    distinct: np.ndarray | None = None

    @property
    def best(self) -> np.ndarray:
        """The best-ranked pose (4, 4)."""
        return self.poses[0]

    @property
    def ambiguous(self) -> bool:
        """Whether poses other than the best explain the contacts about equally well (False without a
        confidence model): the best pose may then be the wrong one."""
        return self.distinct is not None and len(self.distinct) > 1

    def to_dict(self) -> dict:
        """JSON-ready summary: poses as nested lists, diagnostics as numbers."""
        sel = self.selection
        return {
            "poses": self.poses.tolist(),
            "scores": self.scores.tolist(),
            "losses": self.losses.tolist(),
            "penetrations": self.penetrations.tolist(),
            "seconds": dict(self.seconds),
            "contacts": {
                "points": self.contacts.points.tolist(),
                "normals": self.contacts.normals.tolist(),
                "from_patch": self.contacts.from_patch.tolist(),
            },
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
            "light": None if self.light is None else [fit.to_dict() for fit in self.light],
            "confidence": self.confidence,
            "ambiguous": self.ambiguous,
            "distinct_poses": [
                {"rank": int(i), "pose": self.poses[i].tolist(), "score": float(self.scores[i])}
                for i in ([] if self.distinct is None else self.distinct)
            ],
        }


@dataclass(frozen=True)
class ReadImages:
    """What a checked scene's images say once read (``Estimator._read_images``): the images (L, 320, 240, 3) brought
    to their no-contact images' light (None without images), their light fits (None where the light is not aligned),
    the no-contact images per sensor they were read against, whether any of those is a known unit's, and the
    sensors' contacts."""

    images: np.ndarray | None
    light: list[photometric.LightFit] | None
    per_sensor: np.ndarray | None
    known: bool
    contacts: Contacts


class Estimator:
    """Pose estimation for one object.

    points (M, 3) database points (object frame, m); pieces: the object's convex collision pieces
    (``collision.ConvexPieces``, or a sequence of (V, 3) vertex arrays); db_angles (M,) the database
    images' latent angles (rad) and encoder: images (L, 320, 240, 3) uint8 RGB -> (L,) latent angles,
    both needed by method 'ours' only; settings: the select/optimize/rank config (``Settings``), by
    default conf/'s; normals (M, 3) the database points' outward normals, needed by
    ``select.normal_tol_deg`` and ``optimize.normal_weight``; surface: the object's surface samples
    (``surface_sampling.SurfaceSamples``, or a ``trimesh.Trimesh`` to sample), needed by ``rank.refine``;
    no_contact (320, 240, 3) uint8 RGB, the sensors' no-contact image, or (L, 320, 240, 3) each sensor's
    own in sensor order (``estimate`` may pass others per call), and patch_model, the contact-patch
    calibration (``contact_patch.PatchModel``), needed by ``select.contacts=patch``; mesh: the object
    (``trimesh.Trimesh``), needed by ``rank.agreement_weight`` > 0 (render-and-compare);
    confidence_model: the calibrated confidence (``confidence.ConfidenceModel``), without which estimates
    carry no confidence; known_units: the no-contact images of known DIGIT units (``encode.KnownUnits``, or a
    mapping name -> (320, 240, 3) uint8 RGB), against which ``estimate`` reads an image whose no-contact image
    looks like another unit's, when the call passes none of its own and the image agrees with one of them
    (``from_artifacts`` gives the data directory's when no background is passed to it).

    The ``gd`` solver splits its batch over JAX's CPU devices, a process-wide setting that must be made
    before JAX first runs: a program that uses it calls ``optimize.use_cpu_devices_for(solver,
    cpu_devices)`` at its start (the estimator does not change it).
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
        no_contact: np.ndarray | None = None,
        patch_model: PatchModel | None = None,
        mesh=None,
        confidence_model: confidence.ConfidenceModel | None = None,
        known_units: encode_step.KnownUnits | Mapping[str, np.ndarray] | None = None,
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
            surface = sample_surface(surface)
        if self.settings.rank.refine and surface is None:
            raise InputError("rank.refine needs the object's surface (a mesh or contact.SurfaceSamples)")
        self.surface = surface
        if self.settings.select.reads_patches and (no_contact is None or patch_model is None):
            raise InputError("select.contacts=patch needs the sensors' no-contact image and the patch calibration")
        self.no_contact = None if no_contact is None else check_backgrounds(no_contact)
        self.patch_model = patch_model
        if self.settings.rank.uses_agreement and self.settings.select.reads_patches and mesh is None:
            raise InputError("rank.agreement_weight > 0 needs the object's mesh")
        self.mesh = mesh
        if not isinstance(pieces, collision.ConvexPieces):
            pieces = collision.vertices_to_pieces(list(pieces))
        self.penetration_model = collision.PenetrationModel(pieces)
        self.confidence_model = confidence_model
        self.known_units = known_units
        # The database points stand for the object in the distances between ranked poses.
        self.spread_points = confidence.spread_points(self.points)
        # Their bounding box's diagonal bounds how far apart two sensors touching the object can be.
        self.extent = float(np.linalg.norm(np.ptp(self.points, axis=0)))

    @classmethod
    def from_artifacts(
        cls,
        object_name: str,
        artifacts_dir: str | Path,
        cfg: Mapping | None = None,
        data_dir: str | Path | None = None,
        background: np.ndarray | None = None,
        objects_dir: str | Path | None = None,
        known_units: Mapping[str, np.ndarray] | None = None,
    ) -> Estimator:
        """Load one object's artifacts: object.h5 (collision pieces, mesh), surface.h5 (points) and, for
        method 'ours', latents.h5 (angles), the autoencoder checkpoint and the patch calibration. cfg: the composed config
        (default: conf/ with no overrides). ArtifactError names a missing file and the command that
        makes it. objects_dir: where the object's own artifacts live, if not in artifacts_dir (an
        identification library's distractors: ``layout.distractors_dir(artifacts_dir)``); the
        autoencoder, the patch calibration and the confidence model always come from artifacts_dir. The
        confidence model is optional (``load_confidence_model``): without it estimates carry no confidence.

        background: the no-contact image (320, 240, 3) uint8 RGB of the sensors whose images will be
        estimated, or (L, 320, 240, 3) one per sensor in sensor order (a hand's units differ); the encoder
        and the contact patches see each image minus its sensor's. Pass your own sensors' when they are not
        the simulated one; by default it is ``render.background`` from the data directory
        (``perception.encode.load_background``), the background the databases and the paper's images were rendered over,
        and an image that does not agree with it is read against the known unit's it agrees with
        (``encode.KNOWN_UNITS``, with a ``photometric.KnownUnitWarning``). known_units: your own units' no-contact
        images, name -> (320, 240, 3) uint8 RGB, known beside those (``encode.KnownUnits``); InputError with a
        ``background``, against which they would never be looked at.
        """
        cfg = cfg if cfg is not None else _default_cfg()
        settings = Settings.from_cfg(cfg)
        own = artifacts_dir if objects_dir is None else objects_dir
        points = load_surface_points(own, object_name)
        pieces = load_collision_vertices(own, object_name)
        db_angles = encoder = patch_model = None
        if settings.select.method != "ours":
            known_units = None  # the baseline reads no image
        else:
            db_angles, latent_nc = load_database_angles(own, object_name)
            if background is None:
                background = encode_step.load_background(cfg, data_dir)
                known_units = encode_step.KnownUnits(cfg, data_dir, known_units)
            elif known_units:
                raise InputError("known units are looked at only for images read without their own no-contact "
                                 "image: pass a background or known units, not both")
            else:
                known_units = None
            background = check_backgrounds(background)
            encoder = encode_step.LatentAngleEncoder.from_checkpoint(
                layout.ae_checkpoint(artifacts_dir), background, latent_nc
            )
            if settings.select.reads_patches:
                patch_model = encode_step.load_patch_model(artifacts_dir)
        normals = load_surface_normals(own, object_name) if needs_normals(settings) else None
        mesh = load_mesh(own, object_name) if settings.rank.rescores else None
        surface = sample_surface(mesh) if settings.rank.refine else None
        return cls(points, pieces, db_angles, encoder, settings, normals, surface, background, patch_model, mesh,
                   load_confidence_model(artifacts_dir), known_units)

    def with_settings(self, settings: Settings) -> Estimator:
        """The same object's estimator with other select/optimize/rank settings, sharing every array
        (the same checks as the constructor: InputError when the new settings need what this one lacks)."""
        return Estimator(self.points, self.penetration_model.pieces, self.db_angles, self.encoder, settings,
                         self.normals, self.surface, self.no_contact, self.patch_model, self.mesh,
                         self.confidence_model, self.known_units)

    def without_known_units(self) -> Estimator:
        """The same estimator, sharing every array, reading each image against its own or the call's no-contact
        image only (``known_units`` None); itself when it has no known units."""
        if self.known_units is None:
            return self
        plain = copy.copy(self)
        plain.known_units = None
        return plain

    # Each step is public so that a caller can run, time or inspect it alone.

    def backgrounds(self, n_sensors: int, backgrounds=None) -> np.ndarray | None:
        """The no-contact images (L, 320, 240, 3) of n_sensors sensors, one per sensor: ``backgrounds``
        ((320, 240, 3) for all or (L, 320, 240, 3), checked) when given, else this estimator's own
        (``no_contact``); None when neither is there. InputError naming a bad background or count."""
        chosen = self.no_contact if backgrounds is None else check_backgrounds(backgrounds)
        return None if chosen is None else backgrounds_per_sensor(chosen, n_sensors)

    def check_scene(self, T_world_sensors, images=None, backgrounds=None) -> tuple[np.ndarray, np.ndarray | None]:
        """The checks of one estimate's inputs (``tactile6d.perception.inputs``) -> (T (L, 4, 4), images (L, 320, 240,
        3) or None): poses, images, backgrounds and their counts; sensors whose bodies overlap; images that
        are grey or look BGR against their sensor's no-contact image, when the images are read (method
        'ours' or patch contacts) against one; a warning for one sensor."""
        T, images, _ = self._checked_scene(T_world_sensors, images, backgrounds)
        return T, images

    def _checked_scene(self, T_world_sensors, images, backgrounds) -> tuple[np.ndarray, np.ndarray | None,
                                                                            np.ndarray | None]:
        """``check_scene``, also returning the no-contact images per sensor (``backgrounds``): what the
        steps of one estimate then take as they are, unchecked (``estimate``, ``identifier.Identifier``)."""
        T = check_sensor_poses(T_world_sensors)
        reads_images = self.settings.select.method == "ours" or self.settings.select.reads_patches
        if reads_images or images is not None:
            images = check_images(images, T.shape[0])
        per_sensor = self.backgrounds(T.shape[0], backgrounds)
        if reads_images and per_sensor is not None:
            check_images_against_backgrounds(images, per_sensor)
        check_bodies_apart(T, body_overlap_margin(self.settings.sensors.pair_distance_tolerance))
        warn_if_underdetermined(T.shape[0])
        return T, images, per_sensor

    def align_light(self, images, backgrounds=None) -> tuple[np.ndarray | None, list[photometric.LightFit] | None]:
        """Checked images (L, 320, 240, 3) -> (the same brought to their no-contact images' light, their fits),
        or (as given, None) where ``select.align_light`` is off or there are no no-contact images
        (``perception.encode.align_light``); a ``photometric.UnitWarning`` for each image whose no-contact
        image looks like another unit's, a ``photometric.LightWarning`` for each other whose light cannot be
        trusted (``photometric.warn_about_light``). backgrounds as for ``estimate``."""
        if images is None:
            return None, None
        return self._read_light(images, self.backgrounds(len(images), backgrounds), False)[:2]

    def _read_light(self, images, per_sensor, match_known_units: bool
                    ) -> tuple[np.ndarray, list[photometric.LightFit] | None, np.ndarray | None, bool]:
        """``align_light`` on checked images and no-contact images per sensor; with ``match_known_units`` (a call that
        passed no no-contact images of its own), an image whose no-contact image looks like another unit's is read
        instead against the one of ``known_units`` it agrees with (a ``photometric.KnownUnitWarning``). -> (images
        aligned, their fits, the no-contact images per sensor read against, whether any is a known unit's)."""
        aligned, fits, per_sensor, found = encode_step.align_light_to_known_units(
            self.settings.select, images, per_sensor, self.known_units if match_known_units else None)
        photometric.warn_about_known_units(found, stacklevel=4)
        if fits is not None:
            photometric.warn_about_light(images, per_sensor, fits, stacklevel=4)
        return aligned, fits, per_sensor, bool(found)

    def encode(self, images, contacts: Contacts | None = None, T_world_sensors=None, backgrounds=None) -> np.ndarray:
        """(L, 320, 240, 3) uint8 RGB -> (L,) latent angles (rad).

        With ``select.centre_images`` and contacts (as ``contacts`` returned, for sensors at
        T_world_sensors (L, 4, 4)), each image whose contact was read from it is first moved so that
        contact sits at the image centre (``perception.encode.centre_images``); without contacts, as is.
        backgrounds: the sensors' no-contact images for this call ((320, 240, 3) for all or (L, 320, 240, 3)),
        passed to the encoder as ``encoder(images, backgrounds)``; None: the estimator's own.
        """
        if self.encoder is None:
            raise InputError("this estimator has no image encoder (built for the baseline)")
        images = np.asarray(images)
        per_sensor = self.backgrounds(images.shape[0], backgrounds)
        own = None if backgrounds is None else per_sensor  # only a call's own go to the encoder
        if contacts is None:
            angles = self.encoder(images) if own is None else self.encoder(images, own)
            return np.asarray(angles, dtype=np.float64).reshape(images.shape[0])
        return encode_step.read_angles(self.encoder, self.settings.select, images, contacts,
                                       check_sensor_poses(T_world_sensors), per_sensor, own)

    def contacts(self, T_world_sensors, images=None, backgrounds=None) -> Contacts:
        """The sensors' contacts (``select.contacts``): their landmarks, or each image's contact patch
        (images (L, 320, 240, 3) uint8 RGB needed then, each read against its sensor's no-contact image:
        ``backgrounds`` as for ``encode``, else the estimator's own)."""
        T = check_sensor_poses(T_world_sensors)
        if not self.settings.select.reads_patches:
            return self._read_contacts(T, None, None)
        return self._read_contacts(T, check_images(images, T.shape[0]), self.backgrounds(T.shape[0], backgrounds))

    def read_scene(self, T_world_sensors, images=None, backgrounds=None) -> tuple[np.ndarray, Contacts]:
        """The sensor poses checked (L, 4, 4) and the sensors' contacts, read as ``estimate`` reads them: the inputs
        checked (``check_scene``), each image brought to its no-contact image's light and, where the call passes no
        no-contact images, read against the known unit's its own agrees with (``known_units``; a
        ``photometric.KnownUnitWarning``). For a caller that needs the contacts of a scene without estimating
        its pose (``tactile6d calibrate-sensors``, whose object pose is known)."""
        T, images, per_sensor = self._checked_scene(T_world_sensors, images, backgrounds)
        return T, self._read_images(T, images, per_sensor, backgrounds is None).contacts

    def _read_images(self, T: np.ndarray, images: np.ndarray | None, per_sensor: np.ndarray | None,
                     match_known_units: bool) -> ReadImages:
        """A checked scene's images read, as ``estimate``, ``read_scene`` and the identifier read them: brought to
        their no-contact images' light (``_read_light``, known units matched with ``match_known_units``), then their
        contacts (``_read_contacts``)."""
        light, known = None, False
        if images is not None:
            images, light, per_sensor, known = self._read_light(images, per_sensor, match_known_units)
        return ReadImages(images, light, per_sensor, known, self._read_contacts(T, images, per_sensor))

    def _read_contacts(self, T: np.ndarray, images: np.ndarray | None, per_sensor: np.ndarray | None) -> Contacts:
        """``contacts`` from checked inputs: sensor poses, images and no-contact images per sensor."""
        if not self.settings.select.reads_patches:
            return encode_step.read_contacts(self.settings.select, T)
        return encode_step.read_contacts(self.settings.select, T, images, per_sensor, self.patch_model)

    def select(self, contacts: Contacts, angles: np.ndarray | None = None) -> Selection:
        """Candidate tuples for the sensors' contacts (``contacts``), given the images' angles (L,)."""
        return select_step.select(self.points, self.db_angles, contacts, angles, self.settings.select, self.normals,
                                  sensors=self.settings.sensors)

    def optimize(self, contacts: Contacts, tuples: np.ndarray) -> optimization.PoseHypotheses:
        """Pose hypotheses for tuples (T, L) of database indices."""
        return optimize_step.optimize(self.points, contacts, tuples, self.settings.optimize, self.normals,
                                      sensors=self.settings.sensors)

    def rank(self, T_world_sensors, poses: np.ndarray, losses: np.ndarray,
             contacts: Contacts | None = None) -> rank_step.RankedPoses:
        """The top-k distinct poses of (P, 4, 4) hypotheses with losses (P,), rounded first to the form
        the optimize stage stores (``compact_hypotheses``), so that online and offline rank alike.
        contacts: as ``contacts`` returned (default: the sensors' landmarks)."""
        return self._rank(check_sensor_poses(T_world_sensors), poses, losses, contacts)

    def _rank(self, T: np.ndarray, poses: np.ndarray, losses: np.ndarray,
              contacts: Contacts | None) -> rank_step.RankedPoses:
        """``rank`` for checked sensor poses."""
        poses, losses = expand_hypotheses(**compact_hypotheses(poses, losses))
        return rank_step.rank(self.penetration_model, T, poses, losses, self.settings.rank, self.surface, contacts,
                              self.mesh, sensors=self.settings.sensors)

    def estimate(self, T_world_sensors, images=None, backgrounds=None) -> Estimate:
        """The ranked poses for sensors at T_world_sensors (L, 4, 4) with images (L, 320, 240, 3) uint8 RGB.

        Images are required by method 'ours'; the baseline ignores them (but checks them when given).
        backgrounds: the sensors' no-contact images for this call, (320, 240, 3) uint8 RGB for all or
        (L, 320, 240, 3) one per sensor in sensor order; None: the estimator's own (``from_artifacts``'s
        ``background``). The inputs are checked first (``check_scene``): InputError for a bad one, an
        ``inputs.UnderdeterminedPoseWarning`` for one sensor. Then each image is brought to its no-contact
        image's light (``align_light``; a ``photometric.LightWarning`` where that light cannot be trusted),
        and only then read; an image whose no-contact image (not passed by the call) looks like another unit's
        is read against the known unit's it agrees with (``known_units``; a ``photometric.KnownUnitWarning``).
        Sensors whose images show no contact while others' do are left out of the selection and the fit, and still
        checked in the ranking (``Contacts.touching``; a ``contacts.UntouchedSensorWarning``). Touching sensors a
        metre apart and out of the object's reach are an InputError (``inputs.check_sensors_within_reach``: poses in
        millimetres, say), and a best pose that presses deep into a sensor gets an ``inputs.PenetrationWarning`` (a
        pose given inverted, say).
        """
        start = time.perf_counter()
        T, images, per_sensor = self._checked_scene(T_world_sensors, images, backgrounds)  # the one check
        t0 = time.perf_counter()
        read = self._read_images(T, images, per_sensor, backgrounds is None)
        images, per_sensor, contacts = read.images, read.per_sensor, read.contacts
        angles = None
        if self.settings.select.method == "ours":
            if self.encoder is None:
                raise InputError("this estimator has no image encoder (built for the baseline)")
            # A call's own no-contact images, or known units' read against, go to the encoder too; without, it
            # reads against its own.
            angles = encode_step.read_angles(self.encoder, self.settings.select, images, contacts, T, per_sensor,
                                             per_sensor if backgrounds is not None or read.known else None)
        encode_seconds = time.perf_counter() - t0
        estimate = self._estimate_checked(T, contacts, angles, photometric.from_another_unit(read.light))
        steps = {k: estimate.seconds[k] for k in STEPS[1:]}
        estimate.seconds.clear()
        estimate.seconds.update(encode=encode_seconds, **steps, total=time.perf_counter() - start)
        return replace(estimate, light=read.light)

    def estimate_encoded(self, T_world_sensors, contacts: Contacts, angles: np.ndarray | None) -> Estimate:
        """The ranked poses from what the images say, already read: the sensors' contacts (as ``contacts``
        returns) and the images' latent angles (L,) rad (``encode``; None for the baseline). Runs select,
        optimize and rank, then the confidence (with a confidence model); ``seconds`` has those steps and
        their total (the confidence counted in rank's)."""
        return self._estimate_checked(check_sensor_poses(T_world_sensors), contacts, angles)

    def _estimate_checked(self, T: np.ndarray, contacts: Contacts, angles: np.ndarray | None,
                          misread: tuple[int, ...] = ()) -> Estimate:
        """``estimate_encoded`` for checked sensor poses; misread: the images read against another unit's
        no-contact image (``photometric.from_another_unit``), which a ``PenetrationWarning`` names."""
        warn_if_untouched(contacts, stacklevel=4)
        check_sensors_within_reach(T, contacts.touching, self.extent, self.settings.sensors.pair_distance_tolerance)
        start = time.perf_counter()
        seconds = {}
        t0 = time.perf_counter()
        chosen = self.select(contacts, angles)
        seconds["select"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        hypotheses = self.optimize(contacts, chosen.tuples)
        seconds["optimize"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        ranked = self._rank(T, hypotheses.poses, hypotheses.losses, contacts)
        if len(ranked.poses) > 0:
            warn_if_pressed_in(ranked.penetrations[0], self.settings.sensors.contact_sigma, stacklevel=4,
                               misread=misread)
        probability = distinct = None
        if self.confidence_model is not None and len(ranked.poses) > 0:
            probability, distinct = confidence.assess(self.confidence_model, self.spread_points,
                                                      ranked.poses, ranked.scores)
        seconds["rank"] = time.perf_counter() - t0
        seconds["total"] = time.perf_counter() - start
        return Estimate(
            poses=ranked.poses,
            scores=ranked.scores,
            losses=ranked.losses,
            penetrations=ranked.penetrations,
            angles=angles,
            contacts=contacts,
            selection=chosen,
            n_hypotheses=int(hypotheses.poses.shape[0]),
            seconds=seconds,
            confidence=probability,
            distinct=distinct,
        )


def load_confidence_model(artifacts_dir: str | Path) -> confidence.ConfidenceModel | None:
    """The confidence model of ``layout.confidence_model_file(artifacts_dir)``; None when the file is not
    there (the pipeline has not calibrated one yet: estimates then carry no confidence). ArtifactError
    for a model on other features than this code computes, or a file that is not a model."""
    path = layout.confidence_model_file(artifacts_dir)
    if not path.exists():
        return None
    try:
        return confidence.ConfidenceModel.from_json(path.read_text())
    except (ValueError, TypeError) as exc:  # other features or broken JSON; TypeError: missing or unknown fields
        raise ArtifactError(f"confidence model {path}: {exc} (run `dvc repro calibrate_confidence`)") from exc


def _default_cfg():
    return compose_config()
