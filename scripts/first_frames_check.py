"""A stream's own first frames as its sensors' no-contact images (``tactile6d track --background first-frames``).

    python -m stages.make_sequences --params params.yaml render.background=digit/tacto/bg_digit_240_320.jpg paths.artifacts_dir=ART
    python scripts/first_frames_check.py --artifacts artifacts --sequences ART/sequences/tracking.h5 \\
        --background digit/tacto/bg_digit_240_320.jpg --noise-seed 7 --out DIR

The first command renders the tracking sequences over another unit's no-contact image than the databases' (TACTO's,
in the data directory; ART a scratch directory holding links to ``artifacts/``' folders but its own ``sequences/``).
This writes each sequence as numbered scene folders under DIR, ``--still`` untouched frames first (that unit's
no-contact image with the renderer's noise, seeded from ``--noise-seed``; the hand as at the first frame), and
follows it through ``tactile6d track`` (default settings, or the overrides given) three ways: with no
``--background`` (the estimator's default, the paper's unit), with the unit's own no-contact image recorded apart
(noise-free, ``DIR/own.png``), and with ``--background first-frames --background-frames <still>``. Prints per
sequence and way the positional error over the sequence's own frames (the untouched ones left out), median and
mean cm, and the longest run over 2 cm; then per way over all, and how many sequences have a run over 0.5 s.
A diagnostic: it writes only under DIR (each way's JSON lines too, which a second run reuses).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's tactile6d, not an installed one

from tactile6d import cli  # noqa: E402
from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data.hdf5 import read_artifact, write_tactile_image  # noqa: E402
from tactile6d.data.sequence_dirs import write_sequence_dir  # noqa: E402
from tactile6d.data.third_party import DataStore  # noqa: E402
from tactile6d.evaluation.tracking_accuracy import longest_over  # noqa: E402
from tactile6d.runtime.pinned_process import run_pinned  # noqa: E402
from tactile6d.runtime.script_args import parse_with_overrides  # noqa: E402
from tactile6d.sim.render import DigitRenderer, load_background_bgr  # noqa: E402

WAYS = ("none", "own", "first-frames")


def tracked_positions(argv: list[str], out: Path) -> np.ndarray:
    """``tactile6d track ARGV --json`` (its output kept in ``out``, reused when there) -> positions (F, 3) m, NaN
    where the frame has no pose."""
    if not out.exists():
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = cli.main(["track", *argv, "--json"])
        if code != 0:
            raise SystemExit(f"tactile6d track {' '.join(argv)}: {stderr.getvalue()}")
        out.write_text(stdout.getvalue())
    frames = [json.loads(line, parse_constant=lambda name: None) for line in out.read_text().splitlines()]
    return np.array([[np.nan] * 3 if f["pose"] is None else np.array(f["pose"])[:3, 3] for f in frames])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--artifacts", default="artifacts", help="the objects' artifacts (the databases' unit)")
    parser.add_argument("--sequences", required=True, help="a sequences artifact rendered over the other unit")
    parser.add_argument("--background", required=True, help="the other unit's no-contact image, data-relative "
                        "(the render.background the sequences were made with)")
    parser.add_argument("--still", type=int, default=15, help="untouched frames put first (default 15)")
    parser.add_argument("--noise-seed", type=int, default=0, help="seeds the untouched frames' noise")
    parser.add_argument("--out", required=True, help="folder for the sequence folders and the outputs")
    parser.add_argument("overrides", nargs="*", help="config overrides key=value, passed to tactile6d track")
    args = parse_with_overrides(parser, argv)
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    unit = compose_config([*args.overrides, f"render.background={args.background}"])
    noisy = DigitRenderer.from_config(unit.render, load_background_bgr(unit, DataStore(unit.paths)), workers=1)
    # The unit's own no-contact image exactly as the renderer put it under the images (RGB, resized).
    write_tactile_image(root / "own.png", np.clip(np.rint(noisy.background), 0, 255).astype(np.uint8))
    given = {"none": [], "own": ["--background", str(root / "own.png")],
             "first-frames": ["--background", "first-frames", "--background-frames", str(args.still)]}
    seqs = read_artifact(args.sequences, "sequences")
    fps = float(seqs["fps"])
    per_way: dict[str, list[np.ndarray]] = {way: [] for way in WAYS}
    for q, obj in enumerate(str(o) for o in seqs["objects"]):
        T = seqs["T_world_sensors"][q]
        folder = root / f"q{q}"
        if not folder.exists():
            still = np.stack([[noisy.no_contact(10000 * args.noise_seed + 100 * q + 3 * k + i) for i in range(T.shape[1])]
                              for k in range(args.still)])
            write_sequence_dir(folder, np.concatenate([np.repeat(T[:1], args.still, 0), T]),
                               np.concatenate([still, seqs["images"][q]]), fps=fps)
        truth = seqs["T_world_object"][q][:, :3, 3]
        for way in WAYS:
            argv_q = ["--object", obj, "--sequence", str(folder), "--artifacts", args.artifacts, *given[way],
                      *args.overrides]
            positions = tracked_positions(argv_q, root / f"q{q}_{way}.jsonl")[args.still:]
            errors = np.linalg.norm(positions - truth, axis=1)
            per_way[way].append(errors)
            print(f"{q} {obj:22s} {way:13s} median {100 * np.nanmedian(errors):.2f} mean {100 * np.nanmean(errors):.2f} "
                  f"cm, longest over 2 cm {longest_over(errors, 0.02, fps):.2f} s", flush=True)
    for way, runs in per_way.items():
        errors = np.concatenate(runs)
        over = sum(longest_over(e, 0.02, fps) > 0.5 for e in runs)
        print(f"{way:13s} median {100 * np.nanmedian(errors):.2f} mean {100 * np.nanmean(errors):.2f} cm over "
              f"{len(errors)} frames; {over} of {len(runs)} sequences over 2 cm for more than 0.5 s")
    return 0


if __name__ == "__main__":
    run_pinned()  # figures that repeat on every CPU, as the stages' do
    sys.exit(main())
