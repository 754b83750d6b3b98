"""The estimator's settings: the ``select``, ``optimize``, ``rank`` and ``sensors`` config sections as checked,
frozen dataclasses. Each section's keys are documented in its conf/<section>/default.yaml; this module
holds no defaults of its own, so a missing key is a ConfigError naming it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from tactile6d.core.errors import ConfigError
from tactile6d.core.sensor import GEL_CENTER

METHODS = ("ours", "baseline")
# Where a sensor's contact is read from: its landmark (the paper) or the patch its image shows (perception.contacts).
CONTACT_SOURCES = ("landmark", "patch")
# How the selection sets its distance threshold (estimation.select): the paper's adaptive rule, or the N best tuples.
DELTA_D_RULES = ("paper", "best_n")
SOLVERS = ("fast", "gd")


class _Section:
    """A config section as a frozen dataclass: ``from_cfg`` takes exactly its fields from the section (a
    missing key is a ConfigError naming it); each section checks its values in ``__post_init__``, so that
    a section built directly or with ``dataclasses.replace`` is checked too."""

    @classmethod
    def from_cfg(cls, section: Mapping):
        names = list(cls.__dataclass_fields__)
        missing = [n for n in names if n not in section]
        if missing:
            raise ConfigError(f"config section for {cls.__name__} lacks keys {missing}")
        return cls(**{n: section[n] for n in names})


@dataclass(frozen=True)
class SensorSettings(_Section):
    """The ``sensors`` config section (conf/sensors/default.yaml): how far the sensor poses handed to the
    estimator may be off, as a robot's forward kinematics gives them. Per axis, one standard deviation, in
    each sensor's own frame; 0 and 0 declare the poses exact (simulation, the paper's method).

    Every step reads the same error through the quantities below: selection's pair-distance and
    normal tolerances, the fit's noise floor, the refinement's prior on each sensor's correction and the
    ranking's penetration allowance.
    """

    pose_sigma_mm: float
    pose_sigma_deg: float

    def __post_init__(self) -> None:
        if not (self.pose_sigma_mm >= 0 and self.pose_sigma_deg >= 0):
            raise ConfigError(f"sensors.pose_sigma_mm and sensors.pose_sigma_deg must be >= 0, "
                              f"got {self.pose_sigma_mm}, {self.pose_sigma_deg}")

    @property
    def exact(self) -> bool:
        """Whether the sensor poses are declared exact (both sigmas 0)."""
        return self.contact_sigma == 0

    @property
    def contact_sigma(self) -> float:
        """m, per axis: how far a sensor's contact point is off when its pose is off by ``pose_sigma_mm``
        and ``pose_sigma_deg``: the translation error and the rotation's at the gel (``sensor.GEL_CENTER``'s
        distance from the sensor's origin), combined in quadrature. Also how deep a true pose appears to
        press into such a sensor: the ranking's penetration allowance."""
        lever = float(np.linalg.norm(GEL_CENTER))
        return float(np.hypot(1e-3 * self.pose_sigma_mm, lever * np.radians(self.pose_sigma_deg)))

    @property
    def angle_sigma(self) -> float:
        """rad, per axis: how far a sensor (and its contact normal) is turned."""
        return float(np.radians(self.pose_sigma_deg))

    @property
    def pair_distance_tolerance(self) -> float:
        """m: how far the distance between two sensors' contact points may be off, two standard deviations.
        Two contact points each off by ``contact_sigma`` per axis move apart, along the line between them,
        by a Gaussian of standard deviation sqrt(2) contact_sigma."""
        return 2.0 * np.sqrt(2.0) * self.contact_sigma

    @property
    def pair_angle_tolerance(self) -> float:
        """rad: how far an angle between two sensors' contact normals (or a normal and the line between
        the contacts) may be off, two standard deviations: sqrt(2) angle_sigma for two sensors."""
        return 2.0 * np.sqrt(2.0) * self.angle_sigma

    @property
    def correction_sigmas(self) -> tuple[float, float]:
        """The refinement's prior on each sensor's correction: (m, rad), the shift of its contact point and
        its turn, one standard deviation per axis. A sigma of 0 is taken as a thousandth of a millimetre or
        degree: that part of the pose is as good as exact."""
        return max(self.contact_sigma, 1e-6), float(np.radians(max(self.pose_sigma_deg, 1e-3)))


@dataclass(frozen=True)
class SelectSettings(_Section):
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
    contacts: str
    centre_images: bool
    align_light: bool
    max_checks: int | None
    join_sensors: int | None

    def __post_init__(self) -> None:
        if self.max_checks is not None and not self.max_checks >= 1:
            raise ConfigError(f"select.max_checks must be null (no limit) or >= 1, got {self.max_checks}")
        if self.join_sensors is not None and not self.join_sensors >= 2:
            raise ConfigError(f"select.join_sensors must be null (join every sensor) or >= 2, got {self.join_sensors}")
        if self.method not in METHODS:
            raise ConfigError(f"select.method must be one of {', '.join(METHODS)}, not {self.method!r}")
        if self.contacts not in CONTACT_SOURCES:
            raise ConfigError(f"select.contacts must be one of {', '.join(CONTACT_SOURCES)}, not {self.contacts!r}")
        if self.delta_d_rule not in DELTA_D_RULES:
            raise ConfigError(f"select.delta_d_rule must be one of {', '.join(DELTA_D_RULES)}, "
                              f"not {self.delta_d_rule!r}")
        if not (self.delta_h > 0 and self.delta_h_widen_step > 0 and self.delta_h_max >= self.delta_h):
            raise ConfigError(f"select needs delta_h > 0, delta_h_widen_step > 0 and delta_h_max >= delta_h; got "
                              f"{self.delta_h}, {self.delta_h_widen_step}, {self.delta_h_max}")
        if self.normal_tol_deg is not None and not self.normal_tol_deg > 0:
            raise ConfigError(f"select.normal_tol_deg must be null (off) or > 0, got {self.normal_tol_deg}")
        _check_max_sensors("select", self.normal_max_sensors)

    @property
    def uses_normals(self) -> bool:
        """Whether the normal check can apply at all (then the database normals are needed)."""
        return self.normal_tol_deg is not None

    @property
    def reads_patches(self) -> bool:
        """Whether each image's contact patch gives its sensor's contact: source ``patch``, method ``ours``
        (the baseline reads no image, so it keeps the paper's landmarks)."""
        return self.method == "ours" and self.contacts == "patch"

    @property
    def aligns_light(self) -> bool:
        """Whether each image is brought to its no-contact image's light before it is read (method ``ours``:
        the baseline reads no image)."""
        return self.method == "ours" and bool(self.align_light)

    @property
    def centres_images(self) -> bool:
        """Whether images are moved so their read contact sits at the centre before their angle is read."""
        return self.reads_patches and bool(self.centre_images)

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
class OptimizeSettings(_Section):
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
    noise_floor: bool
    normal_max_sensors: int | None

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ConfigError(f"optimize.solver must be one of {', '.join(SOLVERS)}, not {self.solver!r}")
        if self.normal_weight < 0:
            raise ConfigError(f"optimize.normal_weight must be >= 0, got {self.normal_weight}")
        if self.normal_weight > 0 and self.solver != "fast":
            # the gd solver is the paper's, on positions only: say how to get it rather than drop the term
            raise ConfigError(f"optimize.normal_weight={self.normal_weight} needs solver fast; with solver "
                              f"{self.solver!r} set optimize.normal_weight=0 too (or use preset=paper)")
        _check_max_sensors("optimize", self.normal_max_sensors)

    def noise_for(self, sensors: SensorSettings) -> tuple[float, float]:
        """The fast solver's IRLS floor (m, rad): the contacts' expected error when ``noise_floor`` is on, else
        (0, 0), the paper's plain distances."""
        return (sensors.contact_sigma, sensors.angle_sigma) if self.noise_floor else (0.0, 0.0)

    def normal_weight_for(self, n_sensors: int) -> float:
        """The normal term's weight for an estimate from ``n_sensors`` sensors (0: positions only)."""
        if self.normal_max_sensors is not None and n_sensors > self.normal_max_sensors:
            return 0.0
        return float(self.normal_weight)


@dataclass(frozen=True)
class RankSettings(_Section):
    """The ``rank`` config section (conf/rank/default.yaml); ``dedup_rotation`` in degrees."""

    top_k: int
    dedup_translation: float
    dedup_rotation: float
    batch: int
    candidates: int
    refine: bool
    refine_iterations: int
    refine_normal_weight: float
    refine_patch_normal_weight: float
    refine_offset: float
    refine_patch_points: int
    refine_patch_weight: float
    refine_free_weight: float
    refine_free_stride: int
    agreement_weight: float
    agreement_step: int
    agreement_free_margin: float
    agreement_mask_weight: float
    agreement_depth_weight: float
    agreement_free_area_weight: float
    agreement_free_depth_weight: float
    pose_correction_weight: float

    def __post_init__(self) -> None:
        if self.top_k < 1 or self.batch < 1:
            raise ConfigError(f"rank.top_k and rank.batch must be >= 1, got {self.top_k}, {self.batch}")
        if self.rescores and self.candidates < self.top_k:
            raise ConfigError(f"rank.candidates ({self.candidates}) must be >= rank.top_k ({self.top_k})")
        if self.refine and (self.refine_iterations < 1 or min(self.refine_normal_weight, self.refine_patch_normal_weight) < 0):
            raise ConfigError("rank.refine needs refine_iterations >= 1 and refine_normal_weight, refine_patch_normal_weight >= 0")
        if self.refine_patch_points < 0 or self.refine_patch_weight < 0:
            raise ConfigError(f"rank.refine_patch_points and rank.refine_patch_weight must be >= 0, got "
                              f"{self.refine_patch_points}, {self.refine_patch_weight}")
        if self.refine_free_weight < 0 or self.refine_free_stride < 1:
            raise ConfigError(f"rank.refine_free_weight must be >= 0 and rank.refine_free_stride >= 1, got "
                              f"{self.refine_free_weight}, {self.refine_free_stride}")
        weights = (self.agreement_weight, self.agreement_free_margin, self.agreement_mask_weight,
                   self.agreement_depth_weight, self.agreement_free_area_weight, self.agreement_free_depth_weight)
        if min(weights) < 0:
            raise ConfigError(f"rank.agreement_* weights and margin must be >= 0, got {weights}")
        if not self.pose_correction_weight >= 0:
            raise ConfigError(f"rank.pose_correction_weight must be >= 0, got {self.pose_correction_weight}")
        if self.agreement_step < 1 or 240 % self.agreement_step or 320 % self.agreement_step:
            raise ConfigError(f"rank.agreement_step must divide 240 and 320, got {self.agreement_step}")

    @property
    def uses_agreement(self) -> bool:
        """Whether render-and-compare re-scores the candidates (where the contacts were read from images)."""
        return self.agreement_weight > 0

    def surface_normal_weight(self, patch_points: bool) -> float:
        """m/rad: the contact normals' weight in the refinement and its score, ``refine_patch_normal_weight``
        where the patches' points are fitted too (``patch_points``), else ``refine_normal_weight``."""
        return float(self.refine_patch_normal_weight if patch_points else self.refine_normal_weight)

    @property
    def rescores(self) -> bool:
        """Whether the best ``candidates`` poses are re-scored (refined and/or rendered and compared)."""
        return self.refine or self.uses_agreement


@dataclass(frozen=True)
class Settings:
    """All the estimator reads from the config: the select, optimize, rank and sensors sections."""

    select: SelectSettings
    optimize: OptimizeSettings
    rank: RankSettings
    sensors: SensorSettings

    @classmethod
    def from_cfg(cls, cfg: Mapping) -> Settings:
        missing = [k for k in ("select", "optimize", "rank", "sensors") if k not in cfg]
        if missing:
            raise ConfigError(f"config lacks sections {missing}")
        return cls(
            SelectSettings.from_cfg(cfg["select"]),
            OptimizeSettings.from_cfg(cfg["optimize"]),
            RankSettings.from_cfg(cfg["rank"]),
            SensorSettings.from_cfg(cfg["sensors"]),
        )

    @property
    def corrects_sensors(self) -> bool:
        """Whether the refinement estimates each sensor's small pose error beside the object's pose
        (``refine.refine_poses_and_sensors``): refinement on and the sensor poses not declared exact."""
        return self.rank.refine and not self.sensors.exact

