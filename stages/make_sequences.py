"""Stage make_sequences: tracking sequences with ground truth (``tactile6d.sim.sequences``): objects held in a
grasp of DIGITs that rolls and slides, the contacts moving over the objects and the gels, a sensor lifting off
and coming back, the grasp moving in the world, rendered frame by frame, with the sensor poses a hand's
kinematics would report.

Reads the objects' artifacts (meshes; surface points, which frame 0's contacts avoid) and the no-contact
background, config sections ``sequences`` (its ``objects``, or ``objects.names`` when null) and ``render``.
Writes ``artifacts/sequences/tracking.h5`` (schema ``sequences``).
"""

from __future__ import annotations

import sys
from dataclasses import fields

import numpy as np
from tqdm import tqdm

from tactile6d.core.config import section_to_dict
from tactile6d.core.errors import ConfigError, exit_on_error
from tactile6d.data import layout
from tactile6d.data.hdf5 import write_artifact
from tactile6d.data.object_artifacts import load_mesh, load_surface_points
from tactile6d.data.third_party import DataStore
from tactile6d.runtime.stage_args import parse_stage_args
from tactile6d.runtime.stage_clock import timed
from tactile6d.sim import sequences, surface_sampling
from tactile6d.sim.render import DigitRenderer, load_background_bgr, mesh_arrays

SEQUENCE_SET = "tracking"


def spec_from_config(v) -> sequences.SequenceSpec:
    """The ``sequences`` config section -> SequenceSpec: every field by its own key (cast to the field
    default's type), ``depth_range`` from ``depth_min``, ``depth_max``. ConfigError names missing keys."""
    defaults = sequences.SequenceSpec()
    names = [f.name for f in fields(sequences.SequenceSpec) if f.name != "depth_range"]
    missing = sorted(set(names + ["depth_min", "depth_max"]) - set(v))
    if missing:
        raise ConfigError(f"config section sequences lacks keys {missing}")
    kwargs = {n: type(getattr(defaults, n))(v[n]) for n in names}
    return sequences.SequenceSpec(**kwargs, depth_range=(float(v["depth_min"]), float(v["depth_max"])))


def object_names(cfg) -> list[str]:
    """The objects the sequences are of: ``sequences.objects``, or ``objects.names`` when that is null."""
    chosen = cfg.sequences.get("objects")
    return [str(o) for o in (cfg.objects.names if chosen is None else chosen)]


def generate(cfg, names: list[str], artifacts_dir: str) -> sequences.SequenceSet:
    """The sequence set of config section ``sequences`` over objects ``names`` (artifacts in ``artifacts_dir``),
    rendered by the ``render`` section's DigitRenderer in this process."""
    v = cfg.sequences
    spec = spec_from_config(v)
    meshes = {o: load_mesh(artifacts_dir, o) for o in names}
    surfaces = {o: surface_sampling.sample_surface(m) for o, m in meshes.items()}
    database = {o: load_surface_points(artifacts_dir, o) for o in names}
    arrays = {o: mesh_arrays(m) for o, m in meshes.items()}
    renderer = DigitRenderer.from_config(cfg.render, load_background_bgr(cfg, DataStore(cfg.paths)), workers=1)

    def render(obj, T_world_object, T_world_sensors, seed):
        return np.stack([renderer.render(arrays[obj], T_world_object, T, seed + i).image
                         for i, T in enumerate(T_world_sensors)])

    count = int(v["count"])
    with tqdm(total=count * spec.n_frames, desc=f"{SEQUENCE_SET} sequences", unit="frame") as bar:
        return sequences.generate_sequences(names, meshes, surfaces, database, render, spec, count, int(v["seed"]),
                                            progress=bar.update)


def main(argv: list[str] | None = None) -> int:
    _, cfg = parse_stage_args(argv, __doc__.splitlines()[0])
    artifacts_dir = cfg.paths.artifacts_dir
    out = generate(cfg, object_names(cfg), artifacts_dir)
    numbers = sequences.summary(out)
    print(f"{SEQUENCE_SET}: {numbers['sequences']} sequences of {numbers['frames']} frames at {numbers['fps']:g} fps; "
          f"{100 * numbers['lifted_frame_share']:.0f}% of frames with a lifted sensor; contact travel "
          f"{numbers['gel_travel_mm']:.1f} mm on the gel, {numbers['surface_slide_mm']:.1f} mm on the surface (means)")
    write_artifact(
        layout.sequences_file(artifacts_dir, SEQUENCE_SET),
        "sequences",
        out.as_datasets(),
        attrs={"sequence_set": SEQUENCE_SET, "summary": numbers},
        config={"sequences": section_to_dict(cfg, "sequences"), "render": section_to_dict(cfg, "render"),
                "objects": section_to_dict(cfg, "objects")},
        compression="lzf",
    )
    return 0


if __name__ == "__main__":
    sys.exit(exit_on_error(timed(main)))
