"""Suggestion latency through the API against the raw optimiser on the same data.

For N observations (N = 10, 100, 500): the API's ``POST /experiments/{id}/suggest`` (the
server rebuilds the optimiser from the database, asks, predicts mean/std, stores the trial)
against ``make_optimizer`` + ``observe_many`` + ``suggest`` in this process on the very same
observations (the stateless ask the service has to do). ``n_initial=5`` in both, so every N
is past the initial design and the GP is fitted. Runs alternate API/raw; medians.
Each API suggestion is abandoned right after, so every repeat sees the same data.

On a shared, loaded machine the GP fit's wall time varies by ±50 % between runs, far more
than the service adds; so the server also reports (``Server-Timing``) how long its own
optimiser call took, and the API's overhead is measured as API wall time minus that:
everything else the request costs (HTTP, auth, database reads/writes, decoding, predict).

    python benchmarks/service_suggest.py [--sizes 10 100 500] [--repeats 3] [--method bo-lei]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from service_common import bench_server

from app.client import HandfulClient
from app.optim import Observation, make_optimizer


def objective(theta: np.ndarray) -> float:
    """A smooth synthetic tip speed (m/s) over θ (D,)."""
    return float(2.0 + np.sin(6.0 * theta).sum() / len(theta) + 0.5 * theta[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 500])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--method", default="bo-lei")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp, bench_server(Path(tmp)) as srv:
        api = HandfulClient(srv.url, srv.token, timeout=600)
        for n in args.sizes:
            exp = api.create_experiment(
                name=f"bench N={n}",
                task="tip_speed",
                levels=5,
                method=args.method,
                seed=1,
                n_initial=5,
            )
            rng = np.random.default_rng(n)
            thetas = rng.uniform(size=(n, 10))
            obs = [{"theta": t.tolist(), "objective": objective(t)} for t in thetas]
            for i in range(0, n, 500):
                api.import_observations(exp["id"], obs[i : i + 500])
            observations = [Observation(tuple(o["theta"]), o["objective"], None) for o in obs]
            api_s, raw_s, over_s = [], [], []
            api_theta = raw_theta = None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                [trial], timing = api.suggest_timed(exp["id"], n=1)
                wall = time.perf_counter() - t0
                api_s.append(wall)
                over_s.append(wall - timing["optimizer"] / 1e3)
                api.abandon_trial(trial["id"], "benchmark")
                api_theta = trial["theta"]
                t0 = time.perf_counter()
                opt = make_optimizer(args.method, 10, seed=1, n_initial=5)
                opt.observe_many(observations)
                raw_theta = opt.suggest(1)[0].tolist()
                raw_s.append(time.perf_counter() - t0)
            a, r, o = statistics.median(api_s), statistics.median(raw_s), statistics.median(over_s)
            rows.append(
                {
                    "n": n,
                    "api_s": a,
                    "raw_s": r,
                    "api_overhead_s": o,
                    "overhead_vs_raw": o / r,
                    "api_over_raw": a / r,
                    "same_theta": api_theta == raw_theta,
                }
            )
            print(
                f"N={n:4d}  API {a:8.3f} s   raw {r:8.3f} s   API/raw {a / r:6.3f}   "
                f"API overhead {o * 1e3:7.1f} ms = {100 * o / r:5.2f} % of raw   "
                f"same θ: {api_theta == raw_theta}",
                flush=True,
            )
        api.close()
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
