"""Tracking: the object's pose followed over a stream of frames, between single-shot estimates.

A hand that holds an object keeps touching it, and its DIGITs stream 30-60 frames per second while the
fingers roll and slide. Estimating every frame from scratch (``Estimator.estimate``: select, optimize,
rank) costs 0.4 s and forgets the pose a moment ago. ``Tracker`` keeps the pose instead:

- **hypotheses**: a re-detection (a single-shot estimate) gives the poses that explain the contacts about
  equally well (``Estimate.distinct``: a box touched on its large faces has several); up to ``hypotheses``
  of them are followed, each with its *evidence*, a running mean of its score over about
  ``evidence_frames`` frames. The one with the least evidence is reported.
- **update** (every frame): the sensors' contacts are read from the new images (their contact patches:
  on ``threads`` threads in ``update``; in ``track``, which takes a stream of frames, on ``read_ahead``
  worker processes while the frame before is followed, the same answers sooner), and each hypothesis's
  last pose (the reported one's also moved on by its last motion: constant velocity) is refined against
  them and scored by the single-shot ranking's own re-scoring (``rank.refine_and_score``: each sensor's
  small pose error estimated beside the object's pose, ``sensors.pose_sigma_mm``/``_deg``; surface fit +
  penetration beyond the sensor poses' allowance + the corrections' cost + render-and-compare). Only the
  sensors whose image shows contact are fitted; every sensor's image is compared, so a pose that presses a
  sensor whose image shows none pays for it.
- **fit check**: a hypothesis whose refined pose does not fit the contacts (mean point-to-plane residual
  over ``max_residual``), disagrees with the images (render-and-compare cost over ``max_agreement``) or
  penetrates a sensor deeper than the limit (the larger of the ranking's allowance and the last
  re-detection's best pose's penetration, plus ``penetration_margin``) is dropped; two that reach the same
  pose (``rank.dedup_*``) become one.
- **re-detection**: at the first frame and when every hypothesis is dropped, the frame is estimated from
  scratch and its poses replace the hypotheses; every ``redetect_every`` frames and on request, the
  frame is estimated from scratch too and its poses join them, so that a track that settled on a wrong
  pose which fits as well (the evidence cannot tell) is offered the right one again. The tracker never
  returns an updated pose that penetrates a sensor beyond the limit.
- **a sensor lifted off**: while a sensor that touched at the last re-detection shows no contact, for at
  most ``lift_wait`` frames, the track is not re-detected: a periodic re-detection waits until it touches
  again, and when every hypothesis fails the fit check but the touching sensors' contacts still fit one (the
  images' agreement or the penetration failed, as they do while a gel is barely pressed) the last pose is
  held (``hold``, reason ``lift``, ``fit_ok`` False) and the hypotheses are refined again on the next frame.
  Contacts that fit no hypothesis (the object moved or swapped) are re-detected at once. With one contact
  fewer the object's pose is less determined (two contacts leave a cylinder free to slide along its axis),
  and a single-shot estimate from the others is then worse than the pose followed so far.
- a frame where no image shows contact holds the last pose (nothing to fit), as does a re-detection that
  matches nothing (then the next frame is re-detected again).

Confidence per frame: the estimator's calibrated confidence (``confidence.ConfidenceModel``, P(ADI < 1
cm) of a single-shot estimate) of the last re-detection, carried between re-detections; None without a
calibrated model. And whether the frame is *ambiguous*: the single-shot rule (``confidence.distinct_poses``:
another pose farther than 0.75 cm ADI whose score is within ``ambiguity_ratio`` of the best's) applied to the
poses followed and their evidence, so it changes as the frames tell the poses apart. ``TrackedFrame`` also
carries the fit terms, so a caller can apply a stricter check.

Light: images are brought to their no-contact images' light as ``Estimator.estimate`` does, but the
fit of the light (``photometric.fit_light``, 30 ms for three images) is made at re-detection and every
``light_every`` frames only, and applied in between (a lookup table): the light does not drift at 30
frames per second.

No-contact images: those the call passes, else the estimator's. Where the estimator has known units
(``Estimator.known_units``) and the call passes none, the first frame of each sensor count decides, as an estimate
does, which of its images are read against a known unit's (``encode.align_light_to_known_units``; a
``photometric.KnownUnitWarning``), and every later frame of that sensor count is read against the same no-contact
images, re-detections and updates alike, until ``reset``.

Settings: config section ``track`` (conf/track/default.yaml); the estimator's own sections (``rank``,
``sensors``) for the refinement and the score. Units: metres, radians; poses 4x4 float64.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tactile6d.core.config import compose_config
from tactile6d.core.errors import ConfigError, InputError, NoMatch
from tactile6d.core.geometry import invert_pose, rotation_angle
from tactile6d.estimation import confidence
from tactile6d.estimation import rank as rank_step
from tactile6d.estimation.estimator import Estimate, Estimator
from tactile6d.perception import photometric
from tactile6d.perception.contact_patch import image_to_patch
from tactile6d.perception.contacts import Contacts, UntouchedSensorWarning, patches_to_contacts
from tactile6d.perception.encode import align_light_to_known_units, sensor_background
from tactile6d.perception.patch_reader import PatchReader
from tactile6d.runtime.executor import cancel_unless_interrupted

MODES = ("redetect", "update", "hold")


@dataclass(frozen=True)
class TrackSettings:
    """The ``track`` config section (conf/track/default.yaml documents each key); lengths in metres."""

    refine_iterations: int
    predict: bool
    hypotheses: int
    evidence_frames: int
    max_residual: float
    max_agreement: float
    penetration_margin: float
    redetect_every: int
    lift_wait: int
    light_every: int
    threads: int
    read_ahead: int
    rival_ratio: float | None

    def __post_init__(self) -> None:
        if min(self.refine_iterations, self.threads, self.hypotheses, self.evidence_frames) < 1:
            raise ConfigError(f"track.refine_iterations, threads, hypotheses and evidence_frames must be >= 1, got "
                              f"{self.refine_iterations}, {self.threads}, {self.hypotheses}, {self.evidence_frames}")
        if self.read_ahead < 0:
            raise ConfigError(f"track.read_ahead must be >= 0 (0: no reader processes), got {self.read_ahead}")
        if min(self.max_residual, self.max_agreement, self.penetration_margin) < 0:
            raise ConfigError("track.max_residual, max_agreement and penetration_margin must be >= 0")
        if self.redetect_every < 0 or self.light_every < 0:
            raise ConfigError("track.redetect_every and track.light_every must be >= 0 (0: never)")
        if self.lift_wait < 0:
            raise ConfigError(f"track.lift_wait must be >= 0 frames (0: no wait), got {self.lift_wait}")
        if self.rival_ratio is not None and self.rival_ratio < 0:
            raise ConfigError(f"track.rival_ratio must be >= 0 or null (the confidence's ambiguity_ratio), got "
                              f"{self.rival_ratio}")

    @classmethod
    def from_cfg(cls, section: Mapping) -> TrackSettings:
        names = list(cls.__dataclass_fields__)
        missing = [n for n in names if n not in section]
        if missing:
            raise ConfigError(f"config section track lacks keys {missing}")
        return cls(**{n: section[n] for n in names})


@dataclass(frozen=True)
class TrackedFrame:
    """The tracker's answer for one frame.

    pose (4, 4) ``T_world_object``, the reported hypothesis's (NaN before any pose was found); mode:
    ``redetect`` (estimated from scratch), ``update`` (the hypotheses refined) or ``hold`` (the last pose
    kept: no image showed contact, the re-detection that ``reason`` asked for matched nothing, or every
    hypothesis failed the fit check while a sensor was lifted, reason ``lift``); reason: why this frame was
    re-detected (``start``, ``request``, ``periodic``, ``fit``), ``lift`` on such a hold, or None; confidence:
    the calibrated P(ADI < 1 cm) of the last re-detection (module docstring), None without a confidence model;
    ambiguous: whether another pose followed explains the frames about as well as the reported one (module
    docstring; False without a confidence model); rivals (R, 4, 4): those poses, ``T_world_object``, the least
    evidence first (R = 0 unless ambiguous), so that a caller can keep them in view;
    touching (L,) bool: the sensors whose image shows contact; residual (m): mean point-to-plane residual
    of the touching sensors' contacts; agreement: render-and-compare cost (mean over sensors of 1 - mask
    IoU and the share of untouched gel pressed); penetration (m): the deepest sensor penetration, through
    the corrected sensor poses (on a re-detected frame: the single-shot best's, through the poses given);
    residual and agreement are NaN on a re-detected or held frame. fit_ok: False on a re-detection that
    matched nothing and on a ``lift`` hold; seconds: wall-clock time of the frame; estimate: the single-shot
    ``Estimate`` of a re-detected frame, else None.
    """

    pose: np.ndarray
    mode: str
    reason: str | None
    confidence: float | None
    ambiguous: bool
    touching: np.ndarray
    residual: float
    agreement: float
    penetration: float
    fit_ok: bool
    seconds: float
    estimate: Estimate | None = field(default=None, repr=False)
    rivals: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)), repr=False)

    def to_dict(self) -> dict:
        """JSON-ready: the poses as nested lists (None before any pose), the rest as numbers, None where NaN."""
        return {
            "pose": self.pose.tolist() if np.isfinite(self.pose).all() else None,
            "mode": self.mode,
            "reason": self.reason,
            "confidence": self.confidence,
            "ambiguous": self.ambiguous,
            "rivals": self.rivals.tolist(),
            "touching": self.touching.tolist(),
            "residual": _number(self.residual),
            "agreement": _number(self.agreement),
            "penetration": _number(self.penetration),
            "fit_ok": self.fit_ok,
            "seconds": self.seconds,
        }


def _number(value: float) -> float | None:
    """A float for JSON: None for NaN (not a JSON number)."""
    return None if np.isnan(value) else float(value)


class Tracker:
    """Follows one object's pose over frames (module docstring).

    estimator: the object's ``Estimator`` (its settings give the refinement and the score); settings:
    the ``track`` section (``TrackSettings``; default: conf/'s); reader: the ``PatchReader`` of ``track``
    (default: its own of ``read_ahead`` processes, started by the first ``track``). Feed frames in time order
    to ``update``, or a stream of them to ``track``; ``reset`` forgets the track (the next frame is
    re-detected). Holds a thread pool and its reader: use it as a context manager or call ``close`` (a
    reader given stays open).
    """

    def __init__(self, estimator: Estimator, settings: TrackSettings | None = None,
                 reader: PatchReader | None = None):
        if not estimator.settings.rank.refine:
            raise InputError("tracking refines the last pose: it needs rank.refine (and the object's surface)")
        # Every frame is read against the same no-contact images: the known units are looked at once per sensor count
        # (``_unit_backgrounds``), not by each re-detection's estimate, which would leave the updates between them
        # reading against others.
        self.estimator = estimator.without_known_units()
        self._known_units = estimator.known_units
        self.settings = settings if settings is not None else TrackSettings.from_cfg(compose_config()["track"])
        self._pool = ThreadPoolExecutor(self.settings.threads) if self.settings.threads > 1 else None
        # track()'s reader processes: the caller's (who closes it), else the tracker's own, started by track().
        self._reader, self._own_reader = reader, False
        self.reset()

    @classmethod
    def from_artifacts(cls, object_name: str, artifacts_dir: str | Path, cfg: Mapping | None = None,
                       **estimator_kwargs) -> Tracker:
        """The tracker of one object from an artifacts directory (``Estimator.from_artifacts``, whose
        keyword arguments pass through); cfg: the composed config (default: conf/'s)."""
        cfg = cfg if cfg is not None else compose_config()
        estimator = Estimator.from_artifacts(object_name, artifacts_dir, cfg, **estimator_kwargs)
        return cls(estimator, TrackSettings.from_cfg(cfg["track"]))

    def reset(self) -> None:
        """Forget the track: the next frame is estimated from scratch (its no-contact images decided anew)."""
        # Per sensor count, the no-contact images decided at its first frame (None: the estimator's own).
        self._unit_backgrounds: dict[int, np.ndarray | None] = {}
        self._poses: list[np.ndarray] = []  # the poses returned so far (the last two are kept)
        self._hypotheses: list[_Hypothesis] = []  # the poses followed, the one with the least evidence reported
        self._penetration_limit = np.inf  # m: the deepest penetration an updated pose may have
        self._confidence: float | None = None
        self._rivals = np.zeros((0, 4, 4))  # the poses followed that make the frame ambiguous (_rival_poses)
        self._light: list[photometric.LightFit] | None = None
        self._frames_since_light = 0
        self._frames_since_redetect = 0
        self._requested = False
        self._touching_at_redetect: np.ndarray | None = None  # (L,) the sensors touching at the last re-detection
        self._frames_lifted = 0  # consecutive frames on which one of those showed no contact

    @property
    def pose(self) -> np.ndarray | None:
        """The last pose returned (4, 4), or None before the first."""
        return self._poses[-1] if self._poses else None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        if self._own_reader and self._reader is not None:
            self._reader.close()
            self._reader, self._own_reader = None, False

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, T_world_sensors, images, backgrounds=None, redetect: bool = False) -> TrackedFrame:
        """One frame: sensors at T_world_sensors (L, 4, 4) with images (L, 320, 240, 3) uint8 RGB; L may
        change from frame to frame. backgrounds: the sensors' no-contact images for this frame, as for
        ``Estimator.estimate``; redetect: estimate this frame from scratch. -> ``TrackedFrame``."""
        start = time.perf_counter()
        return self._step(self._checked_frame(T_world_sensors, images, backgrounds, redetect), start)

    def _checked_frame(self, T_world_sensors, images, backgrounds, redetect: bool = False) -> _Frame:
        """One frame's inputs checked (``Estimator.check_scene``), with the no-contact images it is read against."""
        T, images, per_sensor = self.estimator._checked_scene(T_world_sensors, images, backgrounds)
        if backgrounds is None and self._known_units is not None and images is not None and per_sensor is not None:
            n = len(T)
            if n not in self._unit_backgrounds:
                _, _, chosen, found = align_light_to_known_units(self.estimator.settings.select, images, per_sensor,
                                                                 self._known_units)
                photometric.warn_about_known_units(found, stacklevel=4)
                self._unit_backgrounds[n] = chosen if found else None
            if self._unit_backgrounds[n] is not None:
                per_sensor = backgrounds = self._unit_backgrounds[n]
        return _Frame(T, images, per_sensor, backgrounds, redetect)

    def track(self, frames: Iterable[tuple]) -> Iterator[TrackedFrame]:
        """``update`` over a stream of frames, each ``(T_world_sensors, images)`` or ``(T_world_sensors,
        images, backgrounds)``, in order -> one ``TrackedFrame`` per frame, the same answers as ``update``
        frame by frame, bit for bit.

        Faster where a core is free: each frame's contact patches are read on the reader processes
        (``track.read_ahead`` of them, or the ``reader`` given to the tracker) while the frame before is
        followed in this process. Its cost: a frame's answer comes when the next frame has arrived (or the
        stream has ended), and a frame's ``seconds`` run from its turn, its patches read by then or not.
        A reading made under a light the frame before changed (its re-detection or light fit) is read
        again. With ``read_ahead`` 0 and no reader, or without patch contacts, it is ``update`` in a loop.
        An input error in a frame is raised after the frame before it has been answered.
        """
        reader = self._track_reader()
        if reader is None:
            for item in frames:
                yield self.update(*_frame_arguments(item))
            return
        waiting: _Frame | None = None
        for item in frames:
            try:
                frame = self._checked_frame(*_frame_arguments(item))
            except Exception:
                if waiting is not None:
                    yield self._step(waiting, time.perf_counter())
                raise
            frame.ahead = self._submit_reading(reader, frame)
            if waiting is not None:
                yield self._step(waiting, time.perf_counter())
            waiting = frame
        if waiting is not None:
            yield self._step(waiting, time.perf_counter())

    def _track_reader(self) -> PatchReader | None:
        """The reader processes of ``track`` (started at its first call), or None where it reads in turn."""
        if not self.estimator.settings.select.reads_patches:
            return None
        if self._reader is None and self.settings.read_ahead > 0:
            self._reader, self._own_reader = PatchReader(self.settings.read_ahead), True
        return self._reader

    def _submit_reading(self, reader: PatchReader, frame: _Frame) -> _Reading:
        """The frame's patches submitted to the reader, under the light as it stands now."""
        n = len(frame.T)
        fits = self._light_fits(n) or [None] * n
        no_contacts = [sensor_background(frame.per_sensor, i) for i in range(n)]
        return _Reading(self._light, reader.submit(frame.images, no_contacts, fits, self.estimator.patch_model))

    def _step(self, frame: _Frame, start: float) -> TrackedFrame:
        """``update`` of a checked frame (its patches perhaps submitted to ``track``'s reader)."""
        est = self.estimator
        T, raw, per_sensor, backgrounds = frame.T, frame.images, frame.per_sensor, frame.backgrounds
        self._frames_since_redetect += 1
        self._frames_since_light += 1
        self._requested = self._requested or frame.redetect  # a request on a frame without contact waits for one
        reason = self._redetect_reason()
        if reason == "start":
            if frame.ahead is not None:
                cancel_unless_interrupted(frame.ahead.futures)
            return self._redetect(T, raw, backgrounds, reason, start)
        fresh_light = self._light_is_stale(len(T))
        images = raw
        if fresh_light:
            images, self._light = est._read_light(raw, per_sensor, None)[:2]
            self._frames_since_light = 0
        if frame.ahead is not None and (fresh_light or frame.ahead.light is not self._light):
            cancel_unless_interrupted(frame.ahead.futures)  # read under another light: read it again
            frame.ahead = None if fresh_light else self._submit_reading(self._reader, frame)
        if frame.ahead is not None:
            contacts = patches_to_contacts(PatchReader.results(frame.ahead.futures), T)
        else:
            if not fresh_light:
                images = self._apply_light(raw)
            contacts = self._read_contacts(T, images, per_sensor)
        touching = contacts.from_patch.copy() if contacts.observed else np.ones(len(T), dtype=bool)
        if not touching.any():
            return self._answer(self.pose, "hold", None, touching, np.nan, np.nan, np.nan, True, start)
        lifted = self._lift_waits(touching)
        answer = self._follow(T, raw, backgrounds, contacts, touching, start, lifted)
        if reason is not None and answer.mode == "update" and not (lifted and reason == "periodic"):
            # Requested or periodic: the frame's single-shot poses join the hypotheses followed, which were
            # scored on this frame too; the evidence decides between them from here on. Read under a light
            # fitted this frame, its images are what the single-shot estimate would read: not read twice.
            read = (images, contacts) if fresh_light else None
            return self._redetect(T, raw, backgrounds, reason, start, keep=True, read=read)
        return answer

    # --- the steps ---------------------------------------------------------------------------------------

    def _redetect_reason(self) -> str | None:
        """Why this frame is estimated from scratch: no hypothesis yet, a pending request, or the period."""
        if not self._hypotheses:
            return "start"
        if self._requested:
            return "request"
        if self.settings.redetect_every and self._frames_since_redetect >= self.settings.redetect_every:
            return "periodic"
        return None

    def _lift_waits(self, touching: np.ndarray) -> bool:
        """Whether a sensor that touched at the last re-detection shows no contact (touching (L,)) and has for
        at most ``lift_wait`` frames, this one counted: re-detections then wait (module docstring)."""
        before = self._touching_at_redetect
        lifted = before is not None and len(before) == len(touching) and bool((before & ~touching).any())
        self._frames_lifted = self._frames_lifted + 1 if lifted else 0
        return lifted and self._frames_lifted <= self.settings.lift_wait

    def _light_is_stale(self, n_sensors: int) -> bool:
        """Whether the light is fitted anew this frame: ``light_every`` frames on, or a sensor count
        other than the fits'."""
        if self._light is None:
            return False
        if len(self._light) != n_sensors:
            return True
        return bool(self.settings.light_every) and self._frames_since_light >= self.settings.light_every

    def _light_fits(self, n_sensors: int) -> list[photometric.LightFit] | None:
        """The last light fits, where they are n_sensors' (a frame of another sensor count is read as given)."""
        return self._light if self._light is not None and len(self._light) == n_sensors else None

    def _apply_light(self, images: np.ndarray) -> np.ndarray:
        """The images under their no-contact images' light and level, by the last fits (``photometric.apply_fit``)."""
        fits = self._light_fits(len(images))
        if fits is None:
            return images
        return np.stack([photometric.apply_fit(im, fit) for im, fit in zip(images, fits)])

    def _read_contacts(self, T: np.ndarray, images: np.ndarray, per_sensor: np.ndarray | None) -> Contacts:
        """The sensors' contacts (``Estimator.contacts``), the images' patches read in parallel."""
        est = self.estimator
        if not est.settings.select.reads_patches or self._pool is None:
            return est._read_contacts(T, images, per_sensor)
        model = est.patch_model
        patches = list(self._pool.map(lambda i: image_to_patch(images[i], sensor_background(per_sensor, i), model),
                                      range(len(images))))
        return patches_to_contacts(patches, T)

    def _follow(self, T: np.ndarray, images, backgrounds, contacts: Contacts, touching: np.ndarray,
                start: float, lifted: bool = False) -> TrackedFrame:
        """Each hypothesis refined and scored against this frame; those failing the fit check dropped, the
        rest's evidence updated; the one with the least evidence reported (a re-detection when none is left,
        or, while a lifted sensor makes re-detections wait, the last pose held and every hypothesis kept)."""
        s = self.settings
        candidates, owners = [], []
        leader = self._leader()
        for k, h in enumerate(self._hypotheses):
            candidates.append(h.poses[-1])
            owners.append(k)
            if k == leader and s.predict and len(h.poses) == 2:  # constant velocity: the last motion again
                candidates.append(h.poses[-1] @ invert_pose(h.poses[-2]) @ h.poses[-1])
                owners.append(k)
        # Refined and scored as the single-shot ranking re-scores its candidates, with refine_iterations steps.
        est = self.estimator
        scored = rank_step.refine_and_score(est.penetration_model, est.surface, est.mesh, np.stack(candidates), T,
                                            contacts, est.settings.rank, est.settings.sensors, s.refine_iterations)
        residual, penetration = scored.distance, scored.depths.max(axis=1)
        owners = np.array(owners)
        kept, contacts_fit = [], False
        for k, h in enumerate(self._hypotheses):
            mine = np.flatnonzero(owners == k)
            best = int(mine[np.argmin(scored.scores[mine])])
            contacts_fit = contacts_fit or residual[best] <= s.max_residual
            if not (residual[best] <= s.max_residual and scored.agreement[best] <= s.max_agreement
                    and penetration[best] <= self._penetration_limit):
                continue  # this frame rules it out
            h.poses = [h.poses[-1], scored.poses[best]]
            h.evidence += (scored.scores[best] - h.evidence) / s.evidence_frames
            h.terms = (residual[best], scored.agreement[best], penetration[best])
            kept.append(h)
        if not kept and lifted and contacts_fit:
            # The touching sensors' contacts still fit: the images' agreement or the penetration failed, as a
            # finger lifting off or coming back (its gel barely pressed) makes them fail.
            return self._answer(self.pose, "hold", "lift", touching, np.nan, np.nan, np.nan, False, start)
        self._hypotheses = _merged(kept, self.estimator.settings.rank)
        if not self._hypotheses:
            return self._redetect(T, images, backgrounds, "fit", start)
        self._rivals = self._rival_poses()
        h = self._hypotheses[self._leader()]
        return self._answer(h.poses[-1], "update", None, touching, *h.terms, True, start)

    def _leader(self) -> int:
        """The hypothesis reported: the least evidence (running mean score)."""
        return int(np.argmin([h.evidence for h in self._hypotheses]))

    def _rival_poses(self) -> np.ndarray:
        """The last poses (R, 4, 4) of the hypotheses other than the reported one that explain the frames about
        as well, the least evidence first: the single-shot rule (``confidence.distinct_poses`` with the
        model's ``ambiguity_ratio``) on the hypotheses' last poses and evidence. Empty (R = 0) with one
        hypothesis or without a confidence model; the frame is ambiguous when there are any."""
        model = self.estimator.confidence_model
        if model is None or len(self._hypotheses) < 2:
            return np.zeros((0, 4, 4))
        order = sorted(range(len(self._hypotheses)), key=lambda k: self._hypotheses[k].evidence)  # leader first
        poses = np.stack([self._hypotheses[k].poses[-1] for k in order])
        evidence = np.array([self._hypotheses[k].evidence for k in order])
        distances = confidence.distances_from_best(self.estimator.spread_points, poses)
        return poses[confidence.distinct_poses(evidence, distances, model.ambiguity_ratio)[1:]]

    def _redetect(self, T: np.ndarray, images, backgrounds, reason: str, start: float, keep: bool = False,
                  read: tuple[np.ndarray, Contacts] | None = None) -> TrackedFrame:
        """The frame (images as given) estimated from scratch; the light's fits and the confidence are taken
        from it. Its poses that explain the contacts about equally well become the hypotheses followed, or
        with ``keep`` join those followed so far (the ``hypotheses`` with the least evidence are kept). A
        sensor lifted off is left out of the estimate as out of an update (no warning: each frame's
        ``touching`` says which sensors touch). When it matches nothing (``NoMatch``: e.g. a barely pressed
        gel's image read as a contact of no database image), the last pose is held, marked as failing the fit
        check, and the next frame tries again. read: the images brought to their light by fits made this frame
        (``self._light``) and their contacts, which the estimate then takes instead of fitting and reading them
        again (the same estimate, sooner)."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UntouchedSensorWarning)
                estimate = self.estimator.estimate(T, images, backgrounds) if read is None else self._estimate_read(
                    T, *read, backgrounds)
        except NoMatch:
            touching = np.zeros(len(T), dtype=bool)
            return self._answer(self.pose, "hold", reason, touching, np.nan, np.nan, np.nan, False, start)
        contacts = estimate.contacts
        touching = contacts.from_patch.copy() if contacts.observed else np.ones(len(T), dtype=bool)
        if not touching.any():
            # No image shows contact: the estimate stands on the sensors' landmarks alone, not on the object.
            return self._answer(self.pose, "hold", None, touching, np.nan, np.nan, np.nan, True, start)
        self._requested = False
        self._touching_at_redetect, self._frames_lifted = touching, 0
        self._light = estimate.light
        self._frames_since_light = 0
        self._frames_since_redetect = 0
        self._confidence = estimate.confidence
        if len(estimate.poses):
            # The poses that explain the contacts about equally well are all followed, until frames tell
            # them apart; without a confidence model, the best alone.
            chosen = self._to_follow(estimate)
            new = [_Hypothesis([estimate.poses[i]], float(estimate.scores[i])) for i in chosen]
            both = _merged((self._hypotheses if keep else []) + new, self.estimator.settings.rank)
            self._hypotheses = both[: self.settings.hypotheses]
            self._rivals = self._rival_poses()
            self._penetration_limit = (max(self.estimator.settings.sensors.contact_sigma,
                                           float(estimate.penetrations[0].max())) + self.settings.penetration_margin)
        penetration = float(estimate.penetrations[0].max()) if len(estimate.poses) else np.nan
        pose = self._hypotheses[self._leader()].poses[-1] if self._hypotheses else None
        return self._answer(pose, "redetect", reason, touching, np.nan, np.nan, penetration, True, start, estimate)

    def _to_follow(self, estimate: Estimate) -> list[int]:
        """Indices into ``estimate.poses`` (best first) of the poses a re-detection offers to follow: with
        ``rival_ratio`` the best and every pose farther than 0.75 cm ADI from it whose score is within that ratio
        of the best's (``confidence.distinct_poses``); without it, ``Estimate.distinct`` (the same rule at the
        confidence model's ``ambiguity_ratio``; the best alone without a model)."""
        if self.settings.rival_ratio is None:
            return [0] if estimate.distinct is None else list(estimate.distinct)
        distances = confidence.distances_from_best(self.estimator.spread_points, estimate.poses)
        return list(confidence.distinct_poses(estimate.scores, distances, self.settings.rival_ratio))

    def _estimate_read(self, T: np.ndarray, aligned: np.ndarray, contacts: Contacts, backgrounds) -> Estimate:
        """``Estimator.estimate`` of a frame whose images were brought to their light by fits made this frame
        and read into ``contacts``: the encoder's angles, then select, optimize and rank."""
        est = self.estimator
        angles = est.encode(aligned, contacts, T, backgrounds) if est.settings.select.method == "ours" else None
        return replace(est.estimate_encoded(T, contacts, angles), light=self._light)

    def _answer(self, pose, mode, reason, touching, residual, agreement, penetration, fit_ok, start,
                estimate=None) -> TrackedFrame:
        pose = np.full((4, 4), np.nan) if pose is None else np.asarray(pose, dtype=np.float64)
        self._poses = (self._poses + [pose])[-2:]
        return TrackedFrame(pose, mode, reason, self._confidence, len(self._rivals) > 0, touching, float(residual),
                            float(agreement), float(penetration), fit_ok, time.perf_counter() - start, estimate,
                            self._rivals.copy())


@dataclass
class _Hypothesis:
    """One pose followed: its last two poses (4, 4) and its evidence, a running mean of its score (m) over
    about ``evidence_frames`` frames; terms: its last fit terms (residual m, agreement, penetration m)."""

    poses: list[np.ndarray]
    evidence: float
    terms: tuple[float, float, float] = (np.nan, np.nan, np.nan)


def _merged(hypotheses: list[_Hypothesis], rank) -> list[_Hypothesis]:
    """The hypotheses without those that came within ``rank.dedup_translation`` and ``dedup_rotation`` of
    one with less evidence (two that reach the same pose are one)."""
    order = sorted(range(len(hypotheses)), key=lambda k: hypotheses[k].evidence)
    kept: list[_Hypothesis] = []
    for k in order:
        T = hypotheses[k].poses[-1]
        if not any(np.linalg.norm(T[:3, 3] - o.poses[-1][:3, 3]) <= rank.dedup_translation
                   and rotation_angle(T[:3, :3], o.poses[-1][:3, :3]) <= np.radians(rank.dedup_rotation) for o in kept):
            kept.append(hypotheses[k])
    return kept


@dataclass
class _Reading:
    """A frame's patches submitted to ``track``'s reader: the light fits they are read under (the tracker's
    ``_light`` then, by identity) and the futures of the patches."""

    light: list[photometric.LightFit] | None
    futures: list


@dataclass
class _Frame:
    """A checked frame (``Estimator._checked_scene``): sensor poses (L, 4, 4), images as given, no-contact
    images per sensor (or None), the call's backgrounds, a re-detection request, and its patches' reading
    when ``track`` submitted one."""

    T: np.ndarray
    images: np.ndarray
    per_sensor: np.ndarray | None
    backgrounds: object
    redetect: bool
    ahead: _Reading | None = None


def _frame_arguments(item: tuple) -> tuple:
    """``(T_world_sensors, images, backgrounds)`` of one of ``Tracker.track``'s frames (backgrounds None if absent)."""
    if not isinstance(item, (tuple, list)) or len(item) not in (2, 3):
        raise InputError("Tracker.track takes frames (T_world_sensors, images) or (T_world_sensors, images, "
                         f"backgrounds), got {type(item).__name__}"
                         + (f" of length {len(item)}" if isinstance(item, (tuple, list)) else ""))
    return (item[0], item[1], item[2] if len(item) == 3 else None)
