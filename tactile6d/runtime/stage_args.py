"""The command line every pipeline stage shares (``python -m stages.<name> ...``), and what stages print.

Stages read the composed ``params.yaml`` (``--params``, as DVC passes it) or compose ``conf/``, then take
Hydra-style ``key=value`` overrides. Per-object stages name their object (or every distractor of the
identification library); the select, optimize and rank stages name a scene set and a method.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from tactile6d.core.config import load_config
from tactile6d.data.layout import distractors_dir, own_dir


def parse_stage_args(argv: list[str] | None, description: str, per_object: bool = False, add_arguments=None):
    """Common command line of ``python -m stages.<name>``.

    ``[--params params.yaml] [--object NAME [--distractor | --own] | --distractors] key=value ...``: without
    ``--params`` the config is composed from ``conf/`` (so group overrides work), with it the composed file
    is read. ``add_arguments(parser)`` may add a stage's own flags. Returns ``(args, cfg)``; a per-object
    stage's ``args.names`` are the objects it makes (``--object``'s one, or with ``--distractors`` every
    distractor of the identification library, ``identify.distractors``, in one run) and
    ``args.objects_dir`` is where their artifacts live: ``paths.artifacts_dir``, for distractors
    ``layout.distractors_dir`` of it, for your own objects (``--own``, config section ``own``) ``layout.own_dir``.
    """
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--params", help="composed params file (DVC passes params.yaml); default: compose conf/")
    if per_object:
        which = parser.add_mutually_exclusive_group(required=True)
        which.add_argument("--object", help="object name (see conf/objects/)")
        which.add_argument("--distractors", action="store_true",
                           help="every distractor of the identification library (identify.distractors), "
                                "in one run; their artifacts live under <artifacts>/distractors/")
        parser.add_argument("--distractor", action="store_true",
                            help="with --object: a distractor of the identification library, whose artifacts "
                                 "live under <artifacts>/distractors/")
        parser.add_argument("--own", action="store_true",
                            help="with --object: one of your own objects (config section own: a mesh file), "
                                 "whose artifacts live under <artifacts>/own/")
    if add_arguments is not None:
        add_arguments(parser)
    parser.add_argument("overrides", nargs="*", help="config overrides key=value (Hydra syntax)")
    args = parser.parse_args(argv)
    cfg = load_config(args.overrides, args.params)
    if per_object:
        if args.distractors:
            args.names = [str(name) for name in cfg.identify.distractors]
        else:
            args.names = [args.object]
        artifacts = cfg.paths.artifacts_dir
        if args.own and (args.distractor or args.distractors):
            parser.error("--own names one of your own objects, not a distractor")
        if args.own:
            args.objects_dir = own_dir(artifacts)
        elif args.distractor or args.distractors:
            args.objects_dir = distractors_dir(artifacts)
        else:
            args.objects_dir = Path(artifacts)
    return args, cfg


def parse_run_stage_args(argv: list[str] | None, description: str, methods: tuple[str, ...]):
    """Command line of select_tuples, optimize and rank: ``parse_stage_args``'s with ``--scene-set NAME
    --method METHOD``, METHOD one of ``methods`` (``core.settings.METHODS``). ``--method`` also sets
    ``select.method`` in the returned config. Returns ``(args, cfg)``.
    """

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--scene-set", required=True, help="scene set: artifacts/scenes/<name>.h5")
        parser.add_argument("--method", required=True, choices=methods)

    args, cfg = parse_stage_args(argv, description, add_arguments=add_arguments)
    OmegaConf.update(cfg, "select.method", args.method)
    return args, cfg


def median_or_nan(values) -> float:
    """The median, or NaN for an empty scene set (without NumPy's empty-slice warning)."""
    values = np.asarray(values, dtype=np.float64)
    return float(np.median(values)) if values.size else float("nan")
