"""The objects the commands know by name, where each one's artifacts live, and which ``dvc repro`` targets
make what is missing (shared by ``tactile6d estimate`` and ``tactile6d identify``).

Two libraries, one namespace:

- **objects**: those with artifacts in the artifacts directory, and those of the configured sets
  (``objects.names``, and every set in conf/objects); the per-object stages ``prepare_object@<name>``,
  ``sample_surface@<name>``, ``render_database@<name>`` and ``encode_database@<name>`` make the artifacts
  of the composed ``objects.names``.
- **distractors** of the identification library: ``identify.distractors``, and those with artifacts under
  ``layout.distractors_dir``; the stages ``prepare_distractors`` ... ``encode_distractors`` make them all
  at once.
- **your own objects**: config section ``own`` (mesh files, ``sim.mesh_import.own_objects``), and those
  with artifacts under ``layout.own_dir``; the stages ``prepare_own@<name>`` ... ``encode_own@<name>``
  make each one's.

A name with artifacts in the artifacts directory is an object there; otherwise one of your own objects'
artifacts are read from their folder, otherwise a distractor's from the distractors' folder, so that each
is estimated by name like any object.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tactile6d.core.config import CONF_DIR
from tactile6d.core.errors import ArtifactError, InputError
from tactile6d.data import layout

# The per-object artifacts an estimate reads: (path of an object's file, the stage that makes it, needed by
# the baseline too). The database itself is not read: DVC renders it on the way to encode_database.
ESTIMATE_ARTIFACTS: tuple[tuple[Callable[[Path, str], Path], str, bool], ...] = (
    (layout.object_file, "prepare_object", True),
    (layout.surface_file, "sample_surface", True),
    (layout.latents_file, "encode_database", False),
)


KINDS = ("object", "own", "distractor")  # an object of the artifacts directory, one of your own, a distractor


@dataclass(frozen=True)
class KnownObject:
    """One object by name: its kind (``KINDS``: an object of the artifacts directory, one of your own objects,
    a distractor of the identification library) and the folder its per-object artifacts live in
    (``objects_dir`` of ``Estimator.from_artifacts``)."""

    name: str
    kind: str
    objects_dir: Path

    @property
    def distractor(self) -> bool:
        return self.kind == "distractor"


class KnownObjects:
    """The object names the commands accept (module docstring), with the artifacts directory they read."""

    def __init__(self, artifacts: str | Path, cfg):
        self.artifacts = Path(artifacts)
        self.with_artifacts = objects_with_artifacts(self.artifacts)
        self.configured = configured_objects(cfg)
        self.in_pipeline = [str(n) for n in cfg.objects.names]
        self.distractors_with_artifacts = objects_with_artifacts(layout.distractors_dir(self.artifacts))
        self.distractors = list(dict.fromkeys([*self.distractors_with_artifacts,
                                               *(str(n) for n in cfg.identify.distractors)]))
        self.own_with_artifacts = objects_with_artifacts(layout.own_dir(self.artifacts))
        from tactile6d.sim.mesh_import import own_objects  # trimesh: loaded when a command runs, not for its --help

        self.own_configured = list(own_objects(cfg))
        self.own = list(dict.fromkeys([*self.own_with_artifacts, *self.own_configured]))

    def __contains__(self, name: str) -> bool:
        return (name in self.with_artifacts or name in self.configured or name in self.own
                or name in self.distractors)

    def get(self, name: str) -> KnownObject:
        """The object of that name; InputError listing the known ones when it is none."""
        if name not in self:
            raise InputError(f"unknown object {name!r}; {self.listing()}")
        if name in self.with_artifacts:
            return KnownObject(name, "object", self.artifacts)
        if name in self.own:
            return KnownObject(name, "own", layout.own_dir(self.artifacts))
        if name in self.distractors:
            return KnownObject(name, "distractor", layout.distractors_dir(self.artifacts))
        return KnownObject(name, "object", self.artifacts)

    def listing(self) -> str:
        have = ", ".join(self.with_artifacts) or "none"
        others = ", ".join(o for o in self.configured if o not in self.with_artifacts)
        distractors = ", ".join(self.distractors)
        own = ", ".join(self.own)
        return (f"objects with artifacts in {self.artifacts}: {have}"
                + (f"; other configured objects (conf/objects): {others}" if others else "")
                + (f"; your own objects (conf/own): {own}" if own else "")
                + (f"; distractors of the identification library: {distractors}" if distractors else ""))

    def require_artifacts(self, name: str, baseline: bool = False) -> KnownObject:
        """The object, after checking that every artifact an estimate of it reads is there (``baseline``: the
        baseline's, without latents); one ArtifactError naming every missing file and every ``dvc repro``
        target that makes them, or what to configure when no stage makes them."""
        known = self.get(name)
        missing = [(path_of(known.objects_dir, name), stage) for path_of, stage, always in ESTIMATE_ARTIFACTS
                   if (always or not baseline) and not path_of(known.objects_dir, name).is_file()]
        if not missing:
            return known
        files = ", ".join(str(path) for path, _ in missing)
        from tactile6d.data.object_artifacts import DISTRACTOR_STAGES, OWN_STAGES

        if known.distractor:
            targets = [DISTRACTOR_STAGES[stage] for _, stage in missing]
        elif known.kind == "own" and name in self.own_configured:
            targets = [f"{OWN_STAGES[stage]}@{name}" for _, stage in missing]
        elif known.kind == "object" and name in self.in_pipeline:
            targets = [f"{stage}@{name}" for _, stage in missing]
        else:
            raise ArtifactError(f"{files}: missing, and no stage makes them: {name!r} is in none of the pipeline's "
                                f"object lists; add it to objects.names (conf/objects) or to identify.distractors "
                                f"(conf/identify), or its mesh file to own (conf/own, `tactile6d add-object`), then "
                                f"run `dvc repro`")
        raise ArtifactError(f"{files}: missing; make {'it' if len(missing) == 1 else 'them'} with "
                            f"`dvc repro {' '.join(dict.fromkeys(targets))}`")


def objects_with_artifacts(artifacts: Path) -> list[str]:
    """Objects with any per-object artifact in ``artifacts``: a missing one is then reported with the dvc
    command that makes it (``KnownObjects.require_artifacts``)."""
    return sorted({p.stem for kind in ("objects", "surfaces", "latents") for p in (artifacts / kind).glob("*.h5")})


def configured_objects(cfg) -> list[str]:
    """The names of every object set in conf/objects (ycb, primitives), and the composed objects.names."""
    import yaml

    names = [str(n) for n in cfg.objects.names]
    for path in sorted((CONF_DIR / "objects").glob("*.yaml")):
        names += [str(n) for n in (yaml.safe_load(path.read_text()) or {}).get("names", [])]
    return list(dict.fromkeys(names))
