"""Which object of a library touches the sensors, and in what pose: ``Identifier``.

The identifier holds one ``Estimator`` per candidate object. For a scene (sensor poses and images) it

1. reads the images once (``encode``): the contact patches, and the autoencoder's latents of the images
   centred on their contacts. Only the last, cheap step of the encoding depends on the object (the
   angle against that object's no-contact latent);
2. estimates every object with the ``identify.screen`` settings (fewer tuples, a tighter distance
   threshold, fewer re-scored candidates) and keeps each one's best pose's features
   (``identity_model.FEATURES``); an object whose database fits no tuple of the sensors' distances does
   not match;
3. scores the objects with the calibrated weights and turns the scores into probabilities
   (``identification``), best first;
4. with ``identify.refine_best``, re-estimates the most probable object with the full settings, so
   that its pose is the one ``Estimator.estimate`` gives. When the screen is spread over worker
   processes, this process makes that estimate for the object leading when one is left to screen, while
   a worker screens it; it is kept when that object wins (``_screen_and_guess``).

Units: metres and radians for poses; features as in ``tactile6d.estimation.identity_model``.
"""

from __future__ import annotations

import dataclasses
import json
import time
import uuid
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tactile6d.core.config import compose_config, config_for_workers
from tactile6d.core.errors import ArtifactError, ConfigError, InputError, NoMatch
from tactile6d.core.settings import Settings
from tactile6d.data import layout
from tactile6d.data.object_artifacts import require
from tactile6d.estimation import identity_model
from tactile6d.estimation import rank as rank_step
from tactile6d.estimation.estimator import Estimate, Estimator
from tactile6d.estimation.optimize import use_cpu_devices_for
from tactile6d.perception import encode as encode_step
from tactile6d.perception import photometric
from tactile6d.perception.contacts import Contacts
from tactile6d.perception.inputs import PenetrationWarning, check_sensor_poses, warn_if_pressed_in
from tactile6d.runtime.executor import Executor, LocalExecutor, executor_from_config, process_cache


@dataclass(frozen=True)
class SceneEncoding:
    """What a scene's images say, independent of the object: contacts (``Estimator.contacts``) and the
    latents (L, latent_dim) of the images as the encoder sees them (None for the baseline); misread: the images
    read against another unit's no-contact image (``photometric.from_another_unit``)."""

    contacts: Contacts
    latents: np.ndarray | None
    misread: tuple[int, ...] = ()


@dataclass(frozen=True)
class Candidate:
    """One library object's answer for a scene.

    features (F,) (``identity_model.FEATURES``; NaN when it does not match); estimate: its ranked poses
    (None when it does not match); why: the reason it does not match (None when it does).
    """

    name: str
    features: np.ndarray
    estimate: Estimate | None
    why: str | None = None

    @property
    def matched(self) -> bool:
        return self.estimate is not None


@dataclass(frozen=True)
class RankedObject:
    """One object in an identification: probability (0-1), score (calibrated, lower is better, inf when
    it does not match), its candidate (features, best poses)."""

    name: str
    probability: float
    score: float
    candidate: Candidate

    @property
    def pose(self) -> np.ndarray | None:
        """Its best ``T_world_object`` (4, 4), None when it does not match."""
        return None if self.candidate.estimate is None else self.candidate.estimate.best


@dataclass(frozen=True)
class Identification:
    """The library's objects ranked, most probable first; ``best`` is the first. refined: whether the
    best object's estimate was redone with the full settings. seconds: encode; objects (the pass over the
    library; with a spread screen it includes ``guess``, the full estimate of the object leading when one
    was left to screen, made meanwhile: ``Identifier._screen_and_guess``); refine (the winner's full
    estimate after the pass: about 0 when the guess was the winner); total."""

    objects: tuple[RankedObject, ...]
    refined: bool
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def best(self) -> RankedObject:
        return self.objects[0]

    def to_dict(self) -> dict:
        """JSON-ready: objects with probability, score, features and best pose (4x4 nested lists)."""
        return {
            "objects": [
                {
                    "name": o.name,
                    "probability": o.probability,
                    "score": o.score if np.isfinite(o.score) else None,
                    "features": dict(zip(identity_model.FEATURES,
                                         [None if np.isnan(v) else float(v) for v in o.candidate.features])),
                    "pose": None if o.pose is None else o.pose.tolist(),
                    "no_match": o.candidate.why,
                }
                for o in self.objects
            ],
            "refined": self.refined,
            "seconds": dict(self.seconds),
        }


def screen_settings(settings: Settings, screen: Mapping) -> Settings:
    """The settings of the pass over the library: ``settings`` with ``identify.screen``'s N,
    delta_d_max, max_checks and candidates."""
    max_checks = screen["max_checks"]
    return dataclasses.replace(
        settings,
        select=dataclasses.replace(settings.select, N=int(screen["N"]), delta_d_max=float(screen["delta_d_max"]),
                                   max_checks=None if max_checks is None else int(max_checks)),
        rank=dataclasses.replace(settings.rank, candidates=int(screen["candidates"])),
    )


def load_weights(artifacts_dir: str | Path) -> np.ndarray:
    """The calibrated feature weights (F,) (stage calibrate_identify)."""
    path = require(layout.identify_calibration_file(artifacts_dir), "calibrate_identify")
    data = json.loads(path.read_text())
    if list(data.get("features", [])) != list(identity_model.FEATURES):
        raise ArtifactError(f"{path}: weights for features {data.get('features')}, expected "
                            f"{list(identity_model.FEATURES)}; re-run `dvc repro calibrate_identify`")
    return np.asarray(data["weights"], dtype=np.float64)


class Identifier:
    """Identification over a library of objects (module docstring).

    estimators: name -> that object's ``Estimator`` with the full settings, all with the same settings,
    the same no-contact image(s) (one for all sensors or one per sensor) and (method 'ours') encoders that
    encode alike
    (``LatentAngleEncoder.encodes_like``; ``from_artifacts``'s do); weights (F,): the calibrated feature
    weights (None: only ``candidates`` can be called, which is how they are calibrated); screen: the
    ``identify.screen`` section; refine_best: as ``identify.refine_best``.
    """

    def __init__(self, estimators: Mapping[str, Estimator], weights: np.ndarray | None = None,
                 screen: Mapping | None = None, refine_best: bool = True):
        # Where the screen runs when it is spread (``spread``): each worker process loads the library itself
        # from ``_source``, since estimators (Embree scenes, fcl objects) do not travel between processes.
        self._executor: Executor | None = None
        self._source: LibrarySource | None = None
        if len(estimators) < 1:
            raise InputError("an identifier needs at least one object")
        self.names = list(estimators)
        self.full = dict(estimators)
        first = self.full[self.names[0]]
        self.settings = first.settings
        for name, est in self.full.items():
            if est.settings != self.settings:
                raise InputError(f"object {name!r} has other settings than {self.names[0]!r}")
            if (est.no_contact is None) != (first.no_contact is None) or (
                    est.no_contact is not None and not np.array_equal(est.no_contact, first.no_contact)):
                raise InputError(f"object {name!r} has another no-contact image than {self.names[0]!r}")
            if est.encoder is not None and not first.encoder.encodes_like(est.encoder):
                raise InputError(f"object {name!r} encodes images with another autoencoder than {self.names[0]!r}")
        self.screened = ({n: e.with_settings(screen_settings(self.settings, screen)) for n, e in self.full.items()}
                         if screen is not None else dict(self.full))
        self.weights = None if weights is None else np.asarray(weights, dtype=np.float64)
        if self.weights is not None and self.weights.shape != (len(identity_model.FEATURES),):
            raise InputError(f"need {len(identity_model.FEATURES)} weights ({', '.join(identity_model.FEATURES)}), "
                             f"got shape {self.weights.shape}")
        self.refine_best = bool(refine_best)

    @classmethod
    def from_artifacts(
        cls,
        objects: Sequence[str],
        artifacts_dir: str | Path,
        cfg: Mapping | None = None,
        data_dir: str | Path | None = None,
        background: np.ndarray | None = None,
        calibrated: bool = True,
        distractors: Sequence[str] = (),
        own: Sequence[str] = (),
        known_units: Mapping[str, np.ndarray] | None = None,
    ) -> Identifier:
        """Load every object's artifacts (``Estimator.from_artifacts``); objects that cannot be loaded
        are named together in one error. The library is ``objects`` (artifacts in artifacts_dir), then
        ``distractors`` (artifacts in ``layout.distractors_dir(artifacts_dir)``, see ``identify.distractors``),
        then ``own``, your own objects (artifacts in ``layout.own_dir(artifacts_dir)``, config section ``own``).
        cfg: the composed config (default: conf/); weights: cfg's ``identify.weights``, else the
        calibrate_identify stage's (``calibrated=False``: none, for calibrating). background: the sensors'
        no-contact image (320, 240, 3) uint8 RGB, or (L, 320, 240, 3) one per sensor in sensor order, as
        ``Estimator.from_artifacts`` takes it (default: ``render.background``), and known_units, your own DIGIT
        units' no-contact images, likewise (screening workers are sent each scene as read, not the units)."""
        cfg = cfg if cfg is not None else compose_config()
        groups = {"a library object": list(objects), "a distractor": list(distractors), "one of your own": list(own)}
        names = [name for group in groups.values() for name in group]
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:
            raise InputError(f"{', '.join(twice)} cannot be more than one of: {', '.join(groups)}")
        library = {**{name: None for name in objects},
                   **{name: layout.distractors_dir(artifacts_dir) for name in distractors},
                   **{name: layout.own_dir(artifacts_dir) for name in own}}
        if len(library) == 0:
            raise InputError("no objects to identify among")
        estimators, failed = {}, []
        for name, objects_dir in library.items():
            try:
                estimators[name] = Estimator.from_artifacts(name, artifacts_dir, cfg, data_dir, background, objects_dir,
                                                            known_units)
            except ArtifactError as exc:
                failed.append(f"{name} ({exc})")
        if failed:
            raise ArtifactError(f"{len(failed)} of {len(library)} objects cannot be identified, their artifacts "
                                f"are missing or unreadable: " + "; ".join(failed))
        first = estimators[next(iter(estimators))]
        for est in estimators.values():  # one network for all, as the encoding is shared
            if est.encoder is not None and first.encoder.encodes_like(est.encoder):
                est.encoder.model = first.encoder.model
        section = cfg["identify"]
        weights = None
        if section.get("weights") is not None:
            weights = np.asarray(list(section["weights"]), dtype=np.float64)
        elif calibrated:
            weights = load_weights(artifacts_dir)
        identifier = cls(estimators, weights, section["screen"], bool(section["refine_best"]))
        workers = int(section.get("workers", 1))
        if workers < 1:
            raise ConfigError(f"identify.workers must be >= 1, got {workers}")
        executor = executor_from_config(cfg, workers, initializer=use_cpu_devices_for,
                                        initargs=(str(cfg["optimize"]["solver"]), int(cfg["optimize"]["cpu_devices"])))
        if isinstance(executor, LocalExecutor) and executor.workers == 1:
            return identifier  # this process screens every object: nothing to spread
        identifier.spread(executor, LibrarySource.of(objects, distractors, artifacts_dir, cfg, data_dir, background,
                                                     own))
        return identifier

    def spread(self, executor: Executor, source: LibrarySource) -> None:
        """Screen the objects through ``executor`` (one task per object and scene) from now on; each worker
        process loads the library from ``source`` once, on its first task. The identifier closes the
        executor (``close``)."""
        self.close()
        self._executor, self._source = executor, source

    def describe(self) -> str:
        """Where the objects are screened, for a log line."""
        return "this process" if self._executor is None else self._executor.describe()

    def encode(self, T_world_sensors, images=None, backgrounds=None) -> SceneEncoding:
        """Read the scene's images once: contacts and latents (module docstring, step 1), each image against
        its sensor's no-contact image (backgrounds as for ``Estimator.estimate``; None: the library's own),
        after the checks of ``Estimator.check_scene`` and the light's alignment (``Estimator.align_light``)."""
        return self._encode(T_world_sensors, images, backgrounds)[1]

    def _encode(self, T_world_sensors, images, backgrounds) -> tuple[np.ndarray, SceneEncoding]:
        """``encode``, also returning the checked sensor poses (L, 4, 4): the scene's one check."""
        first = self.full[self.names[0]]
        T, images, per_sensor = first._checked_scene(T_world_sensors, images, backgrounds)
        read = first._read_images(T, images, per_sensor, backgrounds is None)
        misread = photometric.from_another_unit(read.light)
        if self.settings.select.method != "ours":
            return T, SceneEncoding(read.contacts, None, misread)
        seen = encode_step.images_to_encode(self.settings.select, read.images, read.contacts, T, read.per_sensor)
        # A call's own backgrounds, or known units' read against, go to the encoder; without, it reads against its
        # own (as custom encoders do).
        own = backgrounds is not None or read.known
        latents = first.encoder.latents(seen, read.per_sensor) if own else first.encoder.latents(seen)
        return T, SceneEncoding(read.contacts, latents, misread)

    def candidate(self, name: str, T_world_sensors: np.ndarray, encoding: SceneEncoding) -> Candidate:
        """One object's screened estimate and features for an encoded scene, its sensor poses (L, 4, 4) as
        ``check_sensor_poses`` returned them (``screen`` checks them once for every object)."""
        est = self.screened[name]
        try:
            estimate = estimate_encoded(est, T_world_sensors, encoding)
        except NoMatch as exc:
            return Candidate(name, np.full(len(identity_model.FEATURES), np.nan), None, str(exc))
        return Candidate(name, self.features(est, T_world_sensors, estimate), estimate)

    def features(self, est: Estimator, T_world_sensors: np.ndarray, estimate: Estimate) -> np.ndarray:
        """(F,) features of an estimate's best pose (``identity_model.FEATURES``); sensor poses checked (L, 4, 4)."""
        agreement = 0.0
        if est.mesh is not None and estimate.contacts.observed:
            agreement = float(rank_step.agreement_cost(est.mesh, estimate.best[None], T_world_sensors,
                                                       estimate.contacts, est.settings.rank)[0])
        return np.array([1e3 * estimate.losses[0], 1e3 * estimate.penetrations[0].max(), agreement])

    def screen(self, T_world_sensors, encoding: SceneEncoding) -> list[Candidate]:
        """Every object's screened candidate, in library order: in this process, or through the executor
        of ``spread`` (identify.workers > 1 or a Dask cluster's ``executor.address``; the same results,
        see the tests)."""
        return self._screen(check_sensor_poses(T_world_sensors), encoding)

    def _screen(self, T: np.ndarray, encoding: SceneEncoding) -> list[Candidate]:
        """``screen`` for checked sensor poses."""
        found: list = [None] * len(self.names)
        for i, candidate in self._screened(T, encoding):
            found[i] = candidate
        return found

    def _screened(self, T_world_sensors: np.ndarray, encoding: SceneEncoding) -> Iterator[tuple[int, Candidate]]:
        """(library index, screened candidate) of every object, as each is made: in library order in this
        process, in the order they finish through the executor of ``spread``."""
        if self._executor is None:
            yield from ((i, self.candidate(name, T_world_sensors, encoding)) for i, name in enumerate(self.names))
            return
        # One object per task: which object is slow depends on the scene, and a free worker takes the next.
        n = len(self.names)
        yield from self._executor.completed(screen_task, [self._source] * n, self.names, [T_world_sensors] * n,
                                            [encoding] * n)

    def close(self) -> None:
        """Release the executor of ``spread``, if any (its worker processes, a cluster connection); the
        identifier screens in this process afterwards."""
        if self._executor is not None:
            self._executor.close()
            self._executor, self._source = None, None

    def __enter__(self) -> Identifier:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def candidates(self, T_world_sensors, images=None, backgrounds=None) -> tuple[list[Candidate], SceneEncoding]:
        """Every object's screened candidate (steps 1-2), in library order, and the scene's encoding."""
        T, encoding = self._encode(T_world_sensors, images, backgrounds)
        return self._screen(T, encoding), encoding

    def identify(self, T_world_sensors, images=None, backgrounds=None) -> Identification:
        """The library's objects ranked by calibrated probability for sensors at T_world_sensors (L, 4, 4)
        with images (L, 320, 240, 3) uint8 RGB (required by method 'ours'). backgrounds: the sensors'
        no-contact images for this call, (320, 240, 3) for all or (L, 320, 240, 3) one per sensor; None:
        the library's own (``from_artifacts``'s ``background``)."""
        if self.weights is None:
            raise InputError("this identifier has no calibrated weights (set identify.weights or run "
                             "`dvc repro calibrate_identify`)")
        start = time.perf_counter()
        t0 = time.perf_counter()
        T, encoding = self._encode(T_world_sensors, images, backgrounds)
        seconds = {"encode": time.perf_counter() - t0}
        t0 = time.perf_counter()
        found, guess, guess_seconds = self._screen_and_guess(T, encoding)
        seconds.update(objects=time.perf_counter() - t0, guess=guess_seconds)
        scores = identity_model.features_to_scores(np.stack([c.features for c in found]), self.weights)
        probabilities = identity_model.scores_to_probabilities(scores)
        order = np.lexsort((np.arange(len(found)), -probabilities))
        t0 = time.perf_counter()
        refined = False
        best = found[order[0]]
        if self.refine_best and best.matched:
            # The full settings search at least as wide as the screen's, so the object matches again. Its
            # features and probability stay the screen's: they are what the weights were calibrated on.
            estimate = guess[1] if guess is not None and guess[0] == best.name else self._full_estimate(
                best.name, T, encoding)
            if estimate is not None:  # else (NoMatch) the screen's estimate stands
                found[order[0]] = dataclasses.replace(best, estimate=estimate)
                refined = True
        seconds["refine"] = time.perf_counter() - t0
        seconds["total"] = time.perf_counter() - start
        winner = found[order[0]]
        if winner.matched and winner.estimate is not None:
            warn_if_pressed_in(winner.estimate.penetrations[0], self.full[winner.name].settings.sensors.contact_sigma,
                               stacklevel=3, misread=encoding.misread)
        ranked = tuple(RankedObject(found[i].name, float(probabilities[i]), float(scores[i]), found[i]) for i in order)
        return Identification(ranked, refined, seconds)

    def _full_estimate(self, name: str, T_world_sensors: np.ndarray, encoding: SceneEncoding) -> Estimate | None:
        """Object ``name``'s estimate with the full settings (None when it matches nothing)."""
        try:
            return estimate_encoded(self.full[name], T_world_sensors, encoding)
        except NoMatch:
            return None

    def _screen_and_guess(self, T_world_sensors: np.ndarray, encoding: SceneEncoding
                          ) -> tuple[list[Candidate], tuple[str, Estimate | None] | None, float]:
        """``screen``, and, when it is spread and ``refine_best`` is on, a guess at the winner's full
        estimate: (candidates, (name, its full estimate) or None, seconds spent on the guess).

        Once one object is left to screen, one worker is idle and so is this process, which only waits:
        it makes the full estimate of the object leading so far meanwhile. The guess is used only when that
        object wins, so the identification is the same as without it. It usually wins (34 of the paper's 40
        triplets against the ten YCB objects), as a wrong object fits the sensors badly and its screen
        tends to take longest; when it does not, the winner is re-estimated after the screen, and the guess
        cost at most its own time (docs/identity_model.md).
        """
        if self._executor is None or not self.refine_best:
            return self._screen(T_world_sensors, encoding), None, 0.0
        found: list[Candidate | None] = [None] * len(self.names)
        left = len(self.names)
        guess, seconds = None, 0.0
        for i, candidate in self._screened(T_world_sensors, encoding):
            found[i] = candidate
            left -= 1
            if left == 1:
                leader = self._leader(found)
                if leader is not None:
                    t0 = time.perf_counter()
                    guess = (leader, self._full_estimate(leader, T_world_sensors, encoding))
                    seconds = time.perf_counter() - t0
        return found, guess, seconds

    def _leader(self, found: Sequence[Candidate | None]) -> str | None:
        """The name of the matched candidate of lowest score among those in ``found`` (None for the objects
        not screened yet), ties to the first; None when none has matched."""
        scored = [(c.name, c.features) for c in found if c is not None and c.matched]
        if not scored:
            return None
        scores = identity_model.features_to_scores(np.stack([f for _, f in scored]), self.weights)
        return scored[int(np.argmin(scores))][0]


def estimate_encoded(est: Estimator, T_world_sensors: np.ndarray, encoding: SceneEncoding) -> Estimate:
    """``est``'s estimate from a scene's shared encoding (its own angles from the shared latents), for checked
    sensor poses (L, 4, 4). A wrong object's best pose may well press into a sensor: the ``PenetrationWarning`` is
    the identification's to give, for the object it ranks first (``Identifier.identify``)."""
    angles = None if encoding.latents is None else np.asarray(est.encoder.angles(encoding.latents), np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PenetrationWarning)
        return est._estimate_checked(T_world_sensors, encoding.contacts, angles)  # the identifier checked the poses


@dataclass(frozen=True)
class LibrarySource:
    """What a worker process loads an identifier's library from: ``Identifier.from_artifacts``'s
    arguments, with absolute paths (a worker's working directory may be another) and the config as
    plain containers (it is pickled to the workers).

    token: one per identifier, so that a long-lived worker (a Dask cluster's) reloads for a new one: the
    artifacts may have changed between two stage runs. background: None for the configured one.
    """

    token: str
    objects: tuple[str, ...]
    distractors: tuple[str, ...]
    artifacts_dir: str
    cfg: dict
    data_dir: str | None
    background: np.ndarray | None
    own: tuple[str, ...] = ()

    @classmethod
    def of(cls, objects, distractors, artifacts_dir, cfg, data_dir=None, background=None, own=()) -> LibrarySource:
        container = config_for_workers(cfg)
        # A worker screens in its own process: no executor within an executor.
        container.setdefault("identify", {})["workers"] = 1
        container["executor"] = {**container.get("executor", {}), "address": None}
        return cls(uuid.uuid4().hex, tuple(objects), tuple(distractors), str(Path(artifacts_dir).resolve()),
                   container, None if data_dir is None else str(Path(data_dir).resolve()),
                   None if background is None else np.asarray(background), tuple(own))

    def load(self) -> Identifier:
        """The library's identifier, screening in this process (no weights: it only screens)."""
        from omegaconf import OmegaConf

        return Identifier.from_artifacts(self.objects, self.artifacts_dir, OmegaConf.create(self.cfg), self.data_dir,
                                         self.background, calibrated=False, distractors=self.distractors,
                                         own=self.own)


def screen_task(source: LibrarySource, name: str, T_world_sensors: np.ndarray, encoding: SceneEncoding) -> Candidate:
    """One task of a spread screen: object ``name``'s candidate, from this process's copy of the library
    (loaded on its first task, and kept while it screens for the same identifier)."""
    library = process_cache(("identify library", source.token), source.load, slot="identify library")
    return library.candidate(name, T_world_sensors, encoding)
