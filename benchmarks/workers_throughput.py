"""Sim throughput through the workers vs the simulator alone on the same episodes.

For k = 1 and 2 worker processes (`handful worker sim --max-parallel 1`, each one rollout at a
time) against a real server: the episodes/s from the first claim to the last result (server
timestamps), after a warm-up. The same schedules are then run by the simulator alone: one
process (`rollout` in a loop) for k = 1, a warm `RolloutPool` of 2 processes for k = 2. Both
sides record the same trajectory (qpos included, for 3D replay). Overhead = 1 − worker rate /
simulator rate. The workers' objectives must equal the simulator's bit for bit.

Usage: python benchmarks/workers_throughput.py [--task throw] [--preset reference]
           [--episodes 40] [--workers 1 2] [--repeats 1]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from datetime import datetime
from pathlib import Path

import numpy as np
from workers_common import cpu_s, server, start_worker, stop_worker

from app.client import HandfulClient
from app.sim import RolloutPool, rollout


def _wait_done(api: HandfulClient, exp_id: int, n: int, timeout_s: float = 3600.0) -> list[dict]:
    deadline = time.monotonic() + timeout_s
    while True:  # a light poll: the server's CPU is part of what is measured
        counts = api.get_experiment(exp_id)["status_counts"]
        done = counts.get("completed", 0) + counts.get("failed", 0)
        if done >= n:
            return api.list_trials(exp_id)
        if time.monotonic() > deadline:
            raise TimeoutError(f"{done}/{n} trials done after {timeout_s} s")
        time.sleep(1.0)


def _ts(value: str) -> float:
    return datetime.fromisoformat(value.replace("Z", "+00:00")).timestamp()


def run_workers(
    k: int, args: argparse.Namespace, root: Path
) -> tuple[float, float, float, list[dict]]:
    """k warm worker processes on one experiment: episodes/s, worker and server CPU s/episode,
    and the finished trials."""
    with server(root / f"server-k{k}") as srv:
        api = HandfulClient(srv.url, token=srv.operator_token, timeout=120)
        procs = [
            start_worker(srv, "sim", "--max-parallel", "1", log_name=f"worker{i}.log")
            for i in range(k)
        ]
        try:
            spec = dict(task=args.task, levels=5, method="random", sim_preset=args.preset)
            warm = api.create_experiment(name="warm-up", seed=99, **spec)
            api.suggest(warm["id"], n=3 * k)
            _wait_done(api, warm["id"], 3 * k)
            cpu0 = sum(cpu_s(pgid=p.pid) for p in procs)
            main0 = sum(cpu_s(pid=p.pid) for p in procs)
            srv0 = cpu_s(pid=srv.proc.pid)
            exp = api.create_experiment(name="throughput", seed=args.seed, **spec)
            for start in range(0, args.episodes, 100):
                api.suggest(exp["id"], n=min(100, args.episodes - start))
            trials = _wait_done(api, exp["id"], args.episodes)
            worker_cpu = (sum(cpu_s(pgid=p.pid) for p in procs) - cpu0) / args.episodes
            main_cpu = (sum(cpu_s(pid=p.pid) for p in procs) - main0) / args.episodes
            server_cpu = (cpu_s(pid=srv.proc.pid) - srv0) / args.episodes
        finally:
            for p in procs:
                stop_worker(p)
        bad = [t for t in trials if t["status"] != "completed"]
        if bad:
            raise RuntimeError(f"{len(bad)} trials did not complete: {bad[0]['status_reason']}")
        t0 = min(_ts(t["started_at"]) for t in trials)
        t1 = max(_ts(t["finished_at"]) for t in trials)
        rate = len(trials) / (t1 - t0)
        print(f"  worker main processes (HTTP, leases): {main_cpu:.4f} CPU s/episode", flush=True)
        return rate, worker_cpu, server_cpu, sorted(trials, key=lambda t: t["index"])


def run_simulator(
    k: int, trials: list[dict], args: argparse.Namespace
) -> tuple[float, float | None, list]:
    """The simulator alone on the same schedules (1 process, or a warm pool): episodes/s,
    CPU s/episode (in-process only) and the results."""
    schedules = [np.asarray(t["pressure_schedule_pa"]) for t in trials]
    releases = [t["release_step"] for t in trials]
    if k == 1:
        rollout(args.task, schedules[0], release_step=releases[0], preset=args.preset)  # model
        t0, c0 = time.perf_counter(), time.process_time()
        results = [
            rollout(args.task, s, release_step=r, preset=args.preset, record_qpos=True)
            for s, r in zip(schedules, releases, strict=True)
        ]
        cpu = (time.process_time() - c0) / len(results)
        return len(results) / (time.perf_counter() - t0), cpu, results
    with RolloutPool(args.task, preset=args.preset, n_workers=k, record_qpos=True) as pool:
        pool.warm_up()
        list(pool.map(schedules[: 2 * k], releases[: 2 * k]))  # build each process's model
        t0 = time.perf_counter()
        results = list(pool.map(schedules, releases))
        return len(results) / (time.perf_counter() - t0), None, results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="throw", choices=["throw", "hammer", "tip_speed"])
    parser.add_argument("--preset", default="reference")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()

    rows = []
    sim_cpu: list[float] = []
    with tempfile.TemporaryDirectory(prefix="handful-bench-") as tmp:
        for rep in range(args.repeats):
            for k in args.workers:
                w_rate, w_cpu, srv_cpu, trials = run_workers(k, args, Path(tmp) / f"r{rep}")
                s_rate, s_cpu, results = run_simulator(k, trials, args)
                if s_cpu is not None:
                    sim_cpu.append(s_cpu)
                diff = max(
                    abs(t["objective"] - r.objective) for t, r in zip(trials, results, strict=True)
                )
                rows.append((k, s_rate, w_rate, w_cpu, srv_cpu, diff))
                print(
                    f"k={k}: simulator {s_rate:.3f} ep/s, workers {w_rate:.3f} ep/s "
                    f"({100 * (1 - w_rate / s_rate):+.1f} %), worker CPU {w_cpu:.3f} s/ep, "
                    f"server CPU {srv_cpu:.3f} s/ep, max |Δobjective| {diff:.3g}",
                    flush=True,
                )
    base_cpu = float(np.median(sim_cpu)) if sim_cpu else float("nan")
    print(f"\n{args.task}, preset {args.preset}, {args.episodes} episodes per run")
    print(f"simulator alone: {base_cpu:.3f} CPU s/episode (median over runs)\n")
    print(
        "| processes | simulator alone (ep/s) | through workers (ep/s) | wall overhead "
        "| worker CPU s/ep | CPU overhead | server CPU s/ep | max Δobj |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for k, s, w, wc, sc, d in rows:
        print(
            f"| {k} | {s:.3f} | {w:.3f} | {100 * (1 - w / s):+.1f} % | {wc:.3f} "
            f"| {100 * (wc / base_cpu - 1):+.1f} % | {sc:.3f} | {d:.3g} |"
        )


if __name__ == "__main__":
    main()
