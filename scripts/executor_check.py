"""The same stage through the local executor and through a Dask cluster on localhost: equal artifacts? At what cost?

Runs ``stages.render_database`` for one object and ``stages.ablation`` on the first N scenes of a set,
each as ``dvc repro`` would (``python -m stages.<name>``, a fresh process), once with
``executor.address=null`` (the stage's local worker processes) and once with ``executor.address`` set
to a ``distributed.LocalCluster`` of ``--dask-workers`` single-threaded worker processes on 127.0.0.1,
started before the runs (its start-up is printed, not counted: a real cluster is already up). Prints
per stage the md5 of each output, whether they are equal, both wall times and the overhead, with the
load average (``uptime``) before and after each run.

The ablation's metrics hold a timing (``time_s_median``), so its digest is of the JSON without it.
Each run writes into its own temporary artifacts directory whose inputs are symbolic links into
``--artifacts``; nothing under ``--artifacts`` is written.

    python scripts/executor_check.py --artifacts /work/exp_art --object 002_master_chef_can \\
        --scene-set caddeo2023 --scenes 4 --variants paper_fast,default

Dask's default worker environment sets MALLOC_TRIM_THRESHOLD_, which makes the renderer about 1.8x
slower (docs/distributed.md); the cluster here is started without it, as docs/distributed.md
recommends, unless ``--dask-default-env``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # this checkout's tactile6d, not an installed one

from omegaconf import OmegaConf  # noqa: E402

from tactile6d.core.config import compose_config  # noqa: E402
from tactile6d.data import layout  # noqa: E402
from tactile6d.data.hdf5 import read_artifact, write_artifact  # noqa: E402


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def md5(path: Path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


def run_stage(argv: list[str], env: dict) -> float:
    """``python -m stages.<...> argv`` in the checkout -> wall seconds; its output goes to a log beside."""
    print(f"  load before: {uptime()}", flush=True)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", *argv], cwd=REPO, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    print(f"  load after:  {uptime()}", flush=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(argv)} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    for line in done.stdout.splitlines():
        print(f"  | {line}")
    return seconds


def link_inputs(source: Path, target: Path, kinds: tuple[str, ...]) -> None:
    target.mkdir(parents=True)
    for kind in kinds:
        (target / kind).symlink_to((source / kind).resolve())


def first_scenes(source: Path, scene_set: str, n: int, target_name: str, roots: list[Path]) -> None:
    """Write the first ``n`` scenes of ``scene_set`` as scene set ``target_name`` under each root."""
    scenes = read_artifact(layout.scenes_file(source, scene_set), "scenes")
    total = len(scenes["objects"])
    data = {k: (v[:n] if getattr(v, "ndim", 0) >= 1 and len(v) == total else v) for k, v in scenes.data.items()}
    for root in roots:
        write_artifact(layout.scenes_file(root, target_name), "scenes", data, config=scenes.config)


def report(stage: str, local_s: float, dask_s: float, local_digest: str, dask_digest: str) -> dict:
    overhead = dask_s - local_s
    print(f"{stage}: local {local_s:.1f} s, Dask {dask_s:.1f} s, overhead {overhead:+.1f} s "
          f"({100 * overhead / local_s:+.0f} %); digests {local_digest} / {dask_digest}: "
          f"{'EQUAL' if local_digest == dask_digest else 'DIFFERENT'}", flush=True)
    return {"stage": stage, "local_s": round(local_s, 2), "dask_s": round(dask_s, 2), "overhead_s": round(overhead, 2),
            "local_digest": local_digest, "dask_digest": dask_digest, "equal": local_digest == dask_digest}


def without_timings(results: dict) -> dict:
    return {name: {L: {k: v for k, v in summary.items() if k != "time_s_median"} for L, summary in by_L.items()}
            for name, by_L in results.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--artifacts", type=Path, required=True, help="a finished pipeline's artifacts directory")
    parser.add_argument("--object", default="002_master_chef_can", help="object whose database is rendered")
    parser.add_argument("--scene-set", default="caddeo2023")
    parser.add_argument("--scenes", type=int, default=4, help="the first N scenes of the set (0: skip the ablation)")
    parser.add_argument("--variants", default="paper_fast,default",
                        help="comma-separated ablation.variants to run (default: two)")
    parser.add_argument("--workers", type=int, default=2, help="local worker processes (render.workers, ablation.workers)")
    parser.add_argument("--dask-workers", type=int, default=2, help="worker processes of the local Dask cluster")
    parser.add_argument("--skip-render", action="store_true")
    parser.add_argument("--repeat", type=int, default=1,
                        help="run each stage this many times, local and Dask alternately (each pair is reported)")
    parser.add_argument("--dask-default-env", action="store_true",
                        help="keep Dask's MALLOC_TRIM_THRESHOLD_ in the workers' environment")
    parser.add_argument("--keep", type=Path, help="write the runs here (a new directory) instead of a temporary one")
    args = parser.parse_args()

    import dask
    from distributed import LocalCluster

    env = dict(os.environ)  # the nannies write their workers' variables into this process's environment
    source = args.artifacts.resolve()
    root = args.keep or Path(tempfile.mkdtemp(prefix="executor_check-"))
    local, remote = root / "local", root / "dask"
    estimator_inputs = ("objects", "surfaces", "latents", "ae", "patch")
    for target in (local, remote):
        link_inputs(source, target, estimator_inputs)
    print(f"machine: {os.cpu_count()} CPUs; runs under {root}", flush=True)

    if not args.dask_default_env:
        dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None})
    start = time.perf_counter()
    cluster = LocalCluster(n_workers=args.dask_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None)
    print(f"Dask LocalCluster of {args.dask_workers} workers at {cluster.scheduler_address} started in "
          f"{time.perf_counter() - start:.1f} s", flush=True)
    address = f"executor.address={cluster.scheduler_address}"
    figures = []
    try:
        for _ in range(0 if args.skip_render else args.repeat):
            stage = ["stages.render_database", "--object", args.object, f"render.workers={args.workers}"]
            print(f"render_database {args.object}, local ({args.workers} processes):", flush=True)
            local_s = run_stage([*stage, f"paths.artifacts_dir={local}"], env)
            print(f"render_database {args.object}, Dask:", flush=True)
            dask_s = run_stage([*stage, f"paths.artifacts_dir={remote}", address], env)
            figures.append(report(f"render_database {args.object}", local_s, dask_s,
                                  md5(layout.database_file(local, args.object)),
                                  md5(layout.database_file(remote, args.object))))
            if not figures[-1]["equal"]:  # keep both for a look
                for label, target in (("local", local), ("dask", remote)):
                    kept = root / f"different_{len(figures)}_{label}.h5"
                    shutil.copyfile(layout.database_file(target, args.object), kept)
                    print(f"  kept {kept}", flush=True)
        if args.scenes > 0:
            subset = f"{args.scene_set}_first{args.scenes}"
            first_scenes(source, args.scene_set, args.scenes, subset, [local, remote])
            names = [v for v in args.variants.split(",") if v]
            for target in (local, remote):
                cfg = compose_config([f"paths.artifacts_dir={target}", f"ablation.workers={args.workers}"])
                OmegaConf.set_struct(cfg, False)
                unknown = sorted(set(names) - set(cfg.ablation.variants))
                if unknown:
                    sys.exit(f"no ablation variants {unknown}; there are {list(cfg.ablation.variants)}")
                cfg.ablation.variants = {n: cfg.ablation.variants[n] for n in names}
                OmegaConf.save(cfg, target / "params.yaml")
            stage = ["stages.ablation", "--scene-set", subset]
            for _ in range(args.repeat):
                print(f"ablation {subset} {names}, local ({args.workers} processes):", flush=True)
                local_s = run_stage([*stage, "--params", str(local / "params.yaml")], env)
                print(f"ablation {subset} {names}, Dask:", flush=True)
                dask_s = run_stage([*stage, "--params", str(remote / "params.yaml"), address], env)
                digests = []
                for target in (local, remote):
                    results = json.loads(layout.metrics_file(target, f"ablation_{subset}").read_text())
                    text = json.dumps(without_timings(results), sort_keys=True)
                    digests.append(hashlib.md5(text.encode()).hexdigest())
                figures.append(report(f"ablation {subset} ({len(names)} variants, metrics without time_s_median)",
                                      local_s, dask_s, *digests))
    finally:
        cluster.close()
    print(json.dumps(figures))
    return 0 if all(f["equal"] for f in figures) else 1


if __name__ == "__main__":
    sys.exit(main())
