"""Seconds per BO suggestion through handful's interface vs raw BoTorch, same fit + acquisition.

    python benchmarks/optim_latency.py --sizes 10 100 500 --dim 11 --repeats 3

Both sides fit the paper's GP (ARD Matérn-5/2, older Gamma priors, Normalize/Standardize,
double precision) with ``fit_gpytorch_mll`` on the same N observations and maximise LogEI with
``optimize_acqf`` (10 restarts, 512 raw samples, same seed). The interface's time includes
rebuilding from the observations (``observe_many``), as the trial service does on every suggest.
Runs alternate (interface, raw, interface, ...) and the median of the repeats is reported.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
import warnings

import numpy as np
import torch
from botorch.acquisition import LogExpectedImprovement
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from botorch.models.utils.gpytorch_modules import (
    get_gaussian_likelihood_with_gamma_prior,
    get_matern_kernel_with_gamma_prior,
)
from botorch.optim import optimize_acqf
from gpytorch.mlls import ExactMarginalLogLikelihood

from app.optim import Observation, make_optimizer
from app.optim.base import call_seed


def objective(x: np.ndarray) -> np.ndarray:
    """A deterministic bumpy test function of (N, D) θ → (N,)."""
    return np.sin(3.0 * x).sum(axis=1) + np.exp(-4.0 * ((x - 0.6) ** 2).sum(axis=1))


def interface_suggest(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    opt = make_optimizer(
        "bo-lei", x.shape[1], seed=seed, num_restarts=10, raw_samples=512, n_initial=2
    )
    opt.observe_many(Observation(tuple(xi), float(yi)) for xi, yi in zip(x, y, strict=True))
    return opt.suggest(1)


def raw_suggest(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    d = x.shape[1]
    tx = torch.as_tensor(x, dtype=torch.float64)
    ty = torch.as_tensor(y, dtype=torch.float64).unsqueeze(-1)
    bounds = torch.stack([torch.zeros(d, dtype=torch.float64), torch.ones(d, dtype=torch.float64)])
    # The same per-call seeds the interface derives, so both sides do identical work.
    fit_seed, acq_seed = call_seed(seed, len(y), 0, salt=1), call_seed(seed, len(y), 0)
    torch.manual_seed(fit_seed)
    model = SingleTaskGP(
        tx,
        ty,
        covar_module=get_matern_kernel_with_gamma_prior(ard_num_dims=d),
        likelihood=get_gaussian_likelihood_with_gamma_prior(),
        input_transform=Normalize(d=d, bounds=bounds),
        outcome_transform=Standardize(m=1),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
    torch.manual_seed(acq_seed)
    acq = LogExpectedImprovement(model, best_f=float(y.max()))
    cand, _ = optimize_acqf(
        acq, bounds=bounds, q=1, num_restarts=10, raw_samples=512, options={"seed": acq_seed}
    )
    return cand.detach().numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 500])
    ap.add_argument("--dim", type=int, default=11)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    results = []
    # Both get the intra-op threads the server gives its GP work (HANDFUL_TORCH_THREADS).
    from app.config import Settings
    from app.procs import set_torch_threads

    set_torch_threads(Settings().torch_threads)
    print(f"torch threads: {torch.get_num_threads()}")
    print("| N | interface (s) | raw BoTorch (s) | overhead | same suggestion |")
    print("|---:|---:|---:|---:|---|")
    for n in a.sizes:
        x = np.random.default_rng(n).random((n, a.dim))
        y = objective(x)
        t_if, t_raw, same = [], [], True
        for r in range(a.repeats):
            out = []
            for fn, acc in ((interface_suggest, t_if), (raw_suggest, t_raw)):
                t0 = time.perf_counter()
                out.append(fn(x, y, seed=r))
                acc.append(time.perf_counter() - t0)
            same &= bool(np.allclose(out[0], out[1], atol=1e-9))
        m_if, m_raw = statistics.median(t_if), statistics.median(t_raw)
        results.append({"n": n, "interface_s": t_if, "raw_s": t_raw, "same_suggestion": same})
        print(
            f"| {n} | {m_if:.3f} | {m_raw:.3f} | {100 * (m_if / m_raw - 1):+.1f} % | {same} |",
            flush=True,
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(results, fh, indent=1)


if __name__ == "__main__":
    main()
