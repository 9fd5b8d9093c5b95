"""Speed of the Monte Carlo study against the random-number floor, on threads and on Dask.

Run: ``.venv/bin/python benchmarks/bench_study.py [--runs 10000] [--repeats 5] [--dask]``.

The study is the one ``northfinder study --sensor paper-rlg --positions 0,180 --runs 10000
--denoise wavelet-soft`` runs: every error term of paper-rlg, 10 s windows at 200 Hz, 120 s
warm-up, accelerometer levelling, db4 soft-threshold wavelet denoising of both horizontal gyro
windows, eq. 14. Everything is measured in this one interpreter, as ratios:

- the floor: drawing the white noise of the four channels the solvers read (runs x 2 windows x
  2000 samples x 4 channels; 160 million normal deviates at 10 000 runs) with numpy's
  ``Generator.standard_normal``, on one thread ("1-core floor") and split over two threads
  that draw at once ("2-core floor"). The study draws about 6 % more (slow noise, turn-on
  errors); the script prints the exact count;
- the study with one worker and with two threads (``--workers 1`` and the default on 2 cores);
- the same study with denoising that cannot use the shortcut for the window mean
  (``--denoise-option extension=symmetric``: every transform and reconstruction runs);
- with ``--dask``: a Dask LocalCluster of one and of two single-threaded worker processes on
  the loopback interface, started once beforehand and warmed up (start-up printed apart), and
  whether every result equals the one-process result.

Each repeat measures every item in turn, so all see the same load; medians over the repeats.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import threading
import time
from concurrent.futures import Executor
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from northfinder.firmware_sim.error_terms import FLICKER_TAUS_S
from northfinder.firmware_sim.sensors import load_spec
from northfinder.host.montecarlo import (
    StudySettings,
    chunk_runs,
    local_executor,
    monte_carlo,
)
from northfinder.host.plan import Plan
from northfinder.simwindows import SimulatedWindows

BLOCK = 2**18


def draw(n: int, rng: np.random.Generator) -> None:
    buf = np.empty(BLOCK)
    done = 0
    while done < n:
        m = min(BLOCK, n - done)
        rng.standard_normal(out=buf[:m])
        done += m


def floor_threads(n: int, threads: int) -> float:
    rngs = [np.random.default_rng(k) for k in range(threads)]
    share = [n // threads + (k < n % threads) for k in range(threads)]
    ts = [threading.Thread(target=draw, args=(share[k], rngs[k])) for k in range(threads)]
    t0 = time.perf_counter()
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    return time.perf_counter() - t0


def deviates_drawn(runs: int, plan: Plan, settings: StudySettings) -> int:
    """Normal deviates the study draws: white noise, slow noise, turn-on and stop errors."""
    n = round(plan.window_s * settings.sample_rate_hz)
    p = len(plan.positions_deg)
    k = FLICKER_TAUS_S.size
    white = runs * p * n * 4
    # Slow noise of the 4 channels: the components at the start, a jump between the windows
    # (K), and per window m - 1 + K (m: grid steps, 0.1 s); at most as many as steps x (K + 1).
    m = round(plan.window_s / 0.1) + 1
    slow = runs * 4 * (k + p * (m - 1 + k) + (p - 1) * k)
    turn_on = runs * (6 + 6 + 12) + runs * (p - 1)  # bias, scale, misalignment; stop errors
    return white + slow + turn_on


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dask", action="store_true", help="also a Dask LocalCluster of 1 and 2")
    args = ap.parse_args()
    spec = load_spec("paper-rlg")
    plan = Plan((0.0, 180.0), 10.0, denoise="wavelet-soft")
    full = replace(plan, denoise_options=(("extension", "symmetric"),))
    settings = StudySettings()
    generator = SimulatedWindows(spec)
    white = args.runs * 2 * 2000 * 4
    print(
        f"{args.runs} runs, {chunk_runs(plan, settings)} a chunk; {os.cpu_count()} cores; "
        f"load average at start {os.getloadavg()[0]:.2f}"
    )
    print(
        f"normal deviates: white noise of the 4 channels read {white / 1e6:.1f} M (the floor); "
        f"drawn in all {deviates_drawn(args.runs, plan, settings) / 1e6:.1f} M"
    )
    reference = monte_carlo(generator, plan, settings, args.runs, 0)
    clients = {}
    if args.dask:
        from distributed import Client, LocalCluster

        for workers in (1, 2):
            t0 = time.perf_counter()
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address="127.0.0.1:0",
            )
            client = Client(cluster)
            started = time.perf_counter() - t0
            ex = client.get_executor()
            monte_carlo(generator, plan, settings, 200, 0, executor=ex)  # imports, caches
            clients[workers] = (cluster, client, ex)
            print(f"Dask LocalCluster of {workers}: started in {started:.1f} s")
    times: dict[str, list[float]] = {}
    same = True
    loads = []

    def study(key: str, p: Plan, executor: Executor | None) -> NDArray[np.float64]:
        t0 = time.perf_counter()
        errors = monte_carlo(generator, p, settings, args.runs, 0, executor=executor)
        times.setdefault(key, []).append(time.perf_counter() - t0)
        return errors

    for _ in range(args.repeats):
        loads.append(os.getloadavg()[0])
        times.setdefault("floor1", []).append(floor_threads(white, 1))
        times.setdefault("floor2", []).append(floor_threads(white, 2))
        results = [study("study1", plan, None)]
        with local_executor(2) as ex:
            results.append(study("study2", plan, ex))
            study("full2", full, ex)
        for workers, (_, _, ex) in clients.items():
            results.append(study(f"dask{workers}", plan, ex))
        same &= all(np.array_equal(e, reference) for e in results)
    med = {k: statistics.median(v) for k, v in times.items()}
    f1, f2 = med["floor1"], med["floor2"]
    rmse = math.sqrt(float(np.mean(reference**2)))
    print(
        f"\nmedians of {args.repeats} repeats (load average during them "
        f"{min(loads):.2f}..{max(loads):.2f}); RMSE {rmse:.4f} deg"
    )
    print(f"1-core floor          {f1:6.2f} s")
    print(f"2-core floor          {f2:6.2f} s   ({f1 / f2:.2f}x the 1-core floor's speed)")
    for key, label in (
        ("study1", "study, 1 worker"),
        ("study2", "study, 2 threads"),
        ("full2", "study, 2 threads, full wavelet transforms (extension=symmetric)"),
        ("dask1", "study, Dask LocalCluster of 1 worker"),
        ("dask2", "study, Dask LocalCluster of 2 workers"),
    ):
        if key in med:
            print(
                f"{label:<66} {med[key]:6.2f} s   {med[key] / f1:5.2f}x 1-core floor, "
                f"{med[key] / f2:5.2f}x 2-core floor"
            )
    if clients:
        print(f"Dask speed-up, 2 workers against 1: {med['dask1'] / med['dask2']:.2f}x")
    print(f"identical results for seed 0 on every executor: {same}")
    for cluster, client, _ in clients.values():
        client.close()
        cluster.close()


if __name__ == "__main__":
    main()
