"""``sonicskin reproduce``: the paper's Sec. V on the simulated rig, SVM and network side by side.

Every experiment (:mod:`.experiments`) trains both models on the same split through the one fit, replays the test
streams through the exported artifact and writes a PNG; ``report.md`` puts the numbers next to the paper's."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from .. import threads
from ..feature_cache import load_features_cached
from ..jsonio import OMIT, json_safe
from ..rig import Rig
from . import experiments
from .aggregate import Spread, aggregate
from .context import USES, Context, datasets
from .report import report

__all__ = ["reproduce", "Spread", "SEEDS", "EXPERIMENTS", "default_jobs"]

SEEDS = {"quick": (0, 1), "full": (0, 1, 2)}
EXPERIMENTS = ("fig6b", "fig11", "fig12", "fig13", "table1", "fig16")
STEPS = {name: getattr(experiments, name) for name in EXPERIMENTS}
# Experiments that run in one worker process when seeds run in parallel: those sharing datasets and fits stay
# together (Fig. 6b's OSPA model is Table I's moving model; Fig. 13 and Table I share the stationary dataset).
GROUPS = (("fig11",), ("fig6b", "table1", "fig13"), ("fig12",), ("fig16",))


def default_jobs() -> int:
    """Worker processes for ``reproduce``: usable cores / the thread setting, at most 4 (each holds its datasets' features)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(4, cores // threads.get()))


def _simulate_task(out, quick, rig, seed, name, n_threads):
    """Worker: simulate (if not there yet) and featurise one dataset of one simulator seed."""
    threads.configure(n_threads)
    lines: list[str] = []
    ctx = Context(Path(out), quick, lines.append, rig)
    ctx.sim_seed, ctx.progress = int(seed), False
    t0, c0 = time.perf_counter(), time.process_time()
    load_features_cached(ctx.dataset(name), progress=False)
    lines.append(f"seed {seed} dataset {name}: {time.perf_counter() - t0:.0f} s ({time.process_time() - c0:.0f} CPU-s)")
    return lines


def _experiment_task(out, quick, rig, seed, plots, names, n_threads, log=None):
    """Run experiments ``names`` of one simulator seed in one process (one shared :class:`Context`)."""
    if n_threads is not None:
        threads.configure(n_threads)
    lines: list[str] = []
    say = log or lines.append
    ctx = Context(Path(out), quick, say, rig)
    ctx.sim_seed, ctx.plots = int(seed), plots
    if log is None:
        ctx.progress = False
    res, times = {}, {}
    for name in names:
        t0, c0 = time.perf_counter(), time.process_time()
        res[name] = STEPS[name](ctx)
        times[name] = (time.perf_counter() - t0, time.process_time() - c0)
        say(f"seed {seed} {name}: {times[name][0]:.0f} s ({times[name][1]:.0f} CPU-s in its process)")
    return int(seed), res, lines, ctx.figs, times, dict(ctx.shared)


def reproduce(out: str | Path = "reports/reproduce", *, quick: bool = False, seeds=None, only=None, rig: Rig | None = None,
              log=print, jobs: int | None = None) -> dict:
    """Run every experiment (or ``only``) per simulator seed and report each number's mean and spread (independent of ``jobs``)."""
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ctx = Context(out, quick, log, rig)
    seeds = tuple(SEEDS["quick" if quick else "full"] if seeds is None else seeds)
    if not seeds:
        raise ValueError("reproduce needs at least one simulator seed")
    if not ctx.net:
        log("torch/lightning not installed: network columns are skipped (pip install 'sonicskin[train]')")
    names = list(STEPS)
    if only:
        unknown = sorted(set(only) - set(EXPERIMENTS))
        if unknown:
            raise ValueError(f"unknown experiment(s) {unknown}; choose from {list(EXPERIMENTS)}")
        names = [n for n in names if n in set(only)]
    jobs = default_jobs() if jobs is None else int(jobs)
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    results: dict[int, dict] = {s: {} for s in seeds}
    timing: dict = {}
    shared_all: dict = {}

    def merge(seed, res, lines, figs, times, shared):  # one experiment task's results
        for line in lines:
            log(line)
        results[seed].update(res)
        ctx.figs += figs
        timing.update({(seed, k): v for k, v in times.items()})
        shared_all.update({k: shared_all.get(k, 0) + v for k, v in shared.items()})

    if jobs == 1:
        for seed in tqdm(seeds, desc="simulator seeds", unit="seed"):
            merge(*_experiment_task(out, quick, ctx.rig, seed, seed == seeds[0], names, None, log))
    else:
        import concurrent.futures
        import multiprocessing

        n_threads = max(1, threads.get() // jobs) if threads.get() >= jobs else 1
        wanted = [d for d in datasets(quick) if any(d in USES[n] for n in names)]
        log(f"{len(wanted) * len(seeds)} datasets, then {len(names)} experiments x {len(seeds)} seeds, in {jobs} worker "
            f"processes of {n_threads} thread(s)")
        ts = time.perf_counter()
        # Fresh worker processes (spawn: no forked BLAS/OpenMP or torch state); results come back as they finish.
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            def par(calls):
                futs = [pool.submit(fn, *args) for fn, args in calls]
                for f in concurrent.futures.as_completed(futs):
                    yield f.result()

            for lines in par((_simulate_task, (str(out), quick, ctx.rig, s, d, n_threads)) for d in wanted for s in seeds):
                for line in lines:
                    log(line)
            log(f"datasets ready: {time.perf_counter() - ts:.0f} s")
            tasks = [(s, [n for n in g if n in names]) for g in GROUPS for s in seeds]
            tasks = [(s, g) for s, g in tasks if g]
            for task in par((_experiment_task, (str(out), quick, ctx.rig, s, s == seeds[0], g, n_threads)) for s, g in tasks):
                merge(*task)
    runs = [{n: results[s][n] for n in names} for s in seeds]
    ctx.timing = timing
    ctx.jobs, ctx.names = jobs, names
    log(f"models fitted {shared_all.get('fits', 0)}, fits reused {shared_all.get('fits_reused', 0)}, "
        f"predictions reused {shared_all.get('replays_reused', 0)}")
    res = aggregate(runs)
    runtime = time.perf_counter() - t0
    (out / "report.md").write_text(report(res, ctx, runtime, seeds))

    def spread(o):  # a mean over seeds keeps its spread; callables are left out
        return {"mean": float(o), "std": o.std, "values": o.values} if isinstance(o, Spread) else OMIT if callable(o) else o

    (out / "report.json").write_text(json.dumps(json_safe({**res, "runtime_s": runtime, "quick": quick, "seeds": list(seeds),
                                                       "experiments": names, "jobs": jobs,
                                                       "experiment_seconds": {f"{n} seed {s}": {"wall": w, "cpu": c}
                                                                              for (s, n), (w, c) in timing.items()}},
                                                          convert=spread), indent=1, allow_nan=False))
    log(f"wrote {out / 'report.md'}, report.json and {len(ctx.figs)} figures in {runtime / 60:.1f} min")
    return res
