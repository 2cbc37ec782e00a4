"""`handful bench paper`: the paper's grid, cell filters, runs per cell, and paper.md."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.bench import paper
from app.bench.stats import result_rows
from app.optim import DEFAULT_METHOD, SettingsError

from .test_sweep import handful


def test_the_grid_holds_every_number_of_the_papers_two_tables():
    cells = paper.grid(available=())
    table_cells = [c for c in cells if c.method in paper.PAPER_METHODS]
    # 2 tasks × 4 P × (BO-UCB 2 + BO-LEI 2 + CEM 3 + random 3 trial counts)
    assert len(table_cells) == 2 * 4 * 10
    assert all(paper.paper_value(c.task, c.method, c.levels, c.trials) for c in table_cells)
    assert paper.paper_value("throw", "bo-lei", 7, 500) == (40.878, 1.375)
    assert paper.paper_value("hammer", "random", 10, 10_000) == (2.281, 0.303)
    assert {c.method for c in cells} == {*paper.PAPER_METHODS, DEFAULT_METHOD}  # no REDQ here
    with_redq = paper.grid(available=("redq", "redq-joints"))
    assert len(with_redq) - len(cells) == 2 * 2 * 3  # tasks × agents × (250, 500, 10K)


def test_cell_filters_are_anded_and_check_the_grid():
    cells = paper.select(paper.grid(available=()), ["P=7", "trials<=500"])
    assert {c.levels for c in cells} == {7} and {c.trials for c in cells} == {100, 500}
    assert len(cells) == 2 * 5 * 2  # tasks × methods (4 + default) × trial counts
    some = paper.select(paper.grid(available=()), ["P=2,5", "method=cem,random", "task=hammer"])
    assert {(c.levels, c.method) for c in some} == {
        (p, m) for p in (2, 5) for m in ("cem", "random")
    }
    assert {c.trials for c in some} == {100, 500, 10_000}
    assert paper.select(paper.grid(available=()), ["trials=10K", "method=bo-lei"]) == []


@pytest.mark.parametrize(
    ("term", "message"),
    [
        ("P=1", "P=1 is not in the paper's grid"),
        ("trials=20000", "nothing above 10K"),
        ("trials<=50K", "nothing above 10K"),
        ("trials=200", "not in the paper's grid"),
        ("method=sgd", "unknown method 'sgd'"),
        ("task=juggle", "not in the paper's tables"),
        ("P~7", "cannot read the cell filter"),
        ("P=two", "whole numbers"),
    ],
)
def test_bad_cells_get_one_clear_line(term, message):
    with pytest.raises(SettingsError, match=re.escape(message)):
        paper.parse_term(term)


def test_runs_share_cells_and_bo_settings_key_their_caches():
    cells = paper.select(paper.grid(available=()), ["P=2", "task=throw", "method=bo-lei,cem"])
    sim = {"preset": "fast", "command_hold": "linear", "objective_rule": "published"}
    specs = paper.run_specs(cells, seeds=2, **sim, bo_settings={"fit_mode": "warm"})
    budgets = {(s.method, s.seed): s.budget for s in specs}
    assert budgets == {
        ("bo-lei", 0): 500,
        ("bo-lei", 1): 500,
        ("cem", 0): 10_000,
        ("cem", 1): 10_000,
    }
    bo = next(s for s in specs if s.method == "bo-lei")
    cem = next(s for s in specs if s.method == "cem")
    assert bo.settings == {"fit_mode": "warm"}
    assert cem.settings == {"init_std": pytest.approx(0.288675)}  # the paper's CEM: 1/√12
    assert (cem.command_hold, cem.objective_rule) == ("linear", "published")
    keys = set()
    for settings in paper.BO_FITS.values():  # --bo-fit full / warm / fast
        other = paper.run_specs(cells, seeds=1, **sim, bo_settings=settings)
        keys.add(next(s for s in other if s.method == "bo-lei").key)
        assert next(s for s in other if s.method == "cem").key == cem.key  # shared: same runs
    assert len(keys) == 3 and bo.key in keys  # BO runs of each --bo-fit never mixed


def test_redq_settings_key_runs_but_where_they_compute_does_not():
    cells = paper.select(paper.grid(), ["method=redq", "task=hammer", "trials=500"])
    sim = {"preset": "fast", "command_hold": "linear", "objective_rule": "published"}
    plain = paper.run_specs(cells, seeds=1, **sim)[0]
    on_gpu = paper.run_specs(cells, seeds=1, **sim, rl_settings={"device": "cuda"})[0]
    often = paper.run_specs(cells, seeds=1, **sim, rl_settings={"checkpoint_every": 5})[0]
    fewer = paper.run_specs(cells, seeds=1, **sim, rl_settings={"utd": 4})[0]
    assert on_gpu.settings == {"device": "cuda"}  # the run is told where to compute ...
    assert plain.key == on_gpu.key == often.key  # ... but continues the same cache
    assert fewer.key != plain.key  # another algorithm: never mixed
    with pytest.raises(SettingsError, match="utd"):
        paper.run_specs(cells, seeds=1, **sim, rl_settings={"utd": 0})


def _rows(method: str, task: str, levels: int, finals: list[float], n: int) -> list[dict]:
    """Result rows of one run per value in ``finals``: flat at 0 then ``final`` from trial n/2."""
    from app.bench import RunSpec

    out = []
    for seed, final in enumerate(finals):
        raw = [
            {"trial": t, "objective": (final if t >= n // 2 else 0.0), "wall_s": 0.5, "theta": []}
            for t in range(1, n + 1)
        ]
        out += result_rows(RunSpec(method, task, levels, seed, n), raw)
    return out


def test_paper_md_sets_each_number_beside_the_papers_and_marks_two_sigma_gaps():
    # Paper, throw, random, P=2, 100 trials: 27.435 ± 1.349. Ours 28.0 (inside), P=7 ours
    # 30.0 against 19.167 ± 1.795 (6 σ away), hammer untouched.
    rows = _rows("random", "throw", 2, [27.5, 28.5], 100) + _rows("random", "throw", 7, [30.0], 100)
    chosen = paper.select(paper.grid(available=()), ["method=random", "task=throw", "trials=100"])
    text = paper.paper_markdown(rows, chosen, header=["preset X"], available=())
    line = next(ln for ln in text.splitlines() if ln.startswith("| Random search | 100 |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[2] == "**28.00 ± 0.50** (2)" and cells[3] == "27.43 ± 1.35"
    assert cells[6] == "**30.00 ± 0.00** (1) ⚠" and cells[7] == "19.17 ± 1.79"
    assert cells[4] == "*unfinished*"  # P=5 asked for, not run
    later = next(ln for ln in text.splitlines() if ln.startswith("| Random search | 500 |"))
    assert "*not run*" in later and "**" not in later  # nothing extrapolated to 500 trials
    assert "*not in this build*" in text  # REDQ
    assert "| throw | random | 2 | 100 | 2 | 50.0 |" in text  # measured cost: 100 × 0.5 s


def test_cli_refuses_bad_cells_with_one_line(tmp_path):
    for args, message in (
        (["--cells", "P=1"], "P=1 is not in the paper's grid"),
        (["--cells", "method=sgd"], "unknown method 'sgd'"),
        (["--trials", "20000"], "nothing above 10K"),
        (["--cells", "method=redq", "--trials", "100"], "no cell of the paper's grid matches"),
        (["--bo-fit", "quick"], "--bo-fit must be one of full, warm, fast, got 'quick'"),
        (["--command-hold", "cubic"], "unknown --command-hold 'cubic'"),
        (["--cells", "method=redq", "--redq", "utd=0"], "REDQ utd"),
        (["--cells", "method=redq", "--redq", "observations=pixels"], "unknown observation set"),
        (["--cells", "method=redq", "--redq", "utd"], "--redq takes KEY=VALUE"),
    ):
        res = handful("bench", "paper", *args, "--out", str(tmp_path / "o"), cwd=tmp_path)
        assert res.returncode == 2, (args, res.stderr)
        assert message in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert not (tmp_path / "o").exists()


def _store_flat_run(out, cells: str, objectives: list[float], trials: int) -> None:
    """Write finished runs of ``cells`` (fast, linear, published) into ``out``'s cache, one
    seed per value of ``objectives``, every trial scoring that value."""
    from app.bench import write_run

    chosen = paper.select(paper.grid(available=()), cells.split())
    specs = paper.run_specs(
        chosen, seeds=len(objectives), preset="fast", command_hold="linear",
        objective_rule="published",
    )  # fmt: skip
    for spec, value in zip(specs, objectives, strict=True):
        rows = [{"trial": t, "objective": value, "wall_s": 0.5, "theta": [0.5] * 11}
                for t in range(1, trials + 1)]  # fmt: skip
        write_run(spec, out, rows)


@pytest.mark.slow
def test_cli_runs_a_slice_writes_paper_md_and_resumes_from_its_cache(tmp_path):
    out = tmp_path / "paper"
    # an earlier slice's runs in the same folder: the tables keep showing them
    _store_flat_run(out, "P=2 task=throw method=random trials=100", [12.5, 13.5], 100)
    args = ["bench", "paper", "--cells", "P=2 task=hammer method=random", "--trials", "100"]
    args += ["--seeds", "2", "--preset", "fast", "--out", str(out), "--workers", "2"]
    first = handful(*args, "--no-progress", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    text = (out / "paper.md").read_text()
    assert "BO GP fits `fast`" in text  # the default: docs/bench/optim.md (g″)
    throw_line, line = [ln for ln in text.splitlines() if ln.startswith("| Random search | 100 |")]
    assert "**13.00 ± 0.50** (2)" in throw_line  # stored, not asked for this time
    assert throw_line.count("*not run*") == 3  # the other P: neither asked nor stored
    ours = re.search(r"\*\*([\d.]+) ± ([\d.]+)\*\* \(2\)", line)
    assert ours, line
    assert (out / "paper_curves.png").stat().st_size > 10_000
    rows = [r for r in (out / "results.csv").read_text().splitlines()[1:] if ",hammer," in r]
    assert len(rows) == 2 * 100
    best = [float(r.split(",")[6]) for r in rows]
    finals = [best[99], best[199]]
    assert float(ours.group(1)) == pytest.approx(np.mean(finals), abs=6e-4)
    again = handful(*args, "--no-progress", cwd=tmp_path)  # all cached: same table, no runs
    assert again.returncode == 0 and (out / "paper.md").read_text() == text


def test_projected_cost_sums_measured_trials_and_extends_bo_by_its_fitted_curve():
    flat = np.full(100, 0.5)
    assert paper.projected_run_s(flat, 10_000, grows=False) == pytest.approx(5_000.0)
    assert paper.projected_run_s(flat, 40, grows=False) == pytest.approx(20.0)  # measured only
    # BO whose suggestion cost grows as 1e-5·i² + 0.1: the fit extends it to 500 trials
    i = np.arange(1, 101, dtype=float)
    truth = 1e-5 * np.arange(1, 501, dtype=float) ** 2 + 0.1
    got = paper.projected_run_s(1e-5 * i**2 + 0.1, 500, grows=True)
    assert got == pytest.approx(truth.sum(), rel=0.02)
    # a stall of three slow trials on a shared machine does not make a flat BO curve explode
    stalled = np.full(100, 0.5)
    stalled[40:43] = 20.0
    assert paper.projected_run_s(stalled, 500, grows=True) < 1.2 * (stalled.sum() + 400 * 0.5)
    assert paper.projected_run_s(1e-5 * i**2 + 0.1, 500, grows=False) < 0.5 * truth.sum()
    assert paper.lpt_makespan_s([10, 5, 5, 4], 2) == 14
    assert paper.lpt_makespan_s([10, 5, 5, 4], 48) == 10


def test_projection_says_which_runs_are_measured_borrowed_or_missing():
    rows = _rows("random", "throw", 2, [27.5, 28.5], 100)  # wall 0.5 s a trial
    text = "\n".join(paper.projection_markdown(rows, seeds=5, available=()))
    assert "| throw | random | 2 | 10,000 | 100 | measured | 5,000 |" in text
    assert "| hammer | random | 10 | 10,000 | 0 | borrowed | 5,000 |" in text
    assert "throw/bo-lei/P=7" in text.split("Not projected")[1]
    # random: 8 (task, P) × 5 seeds × 5,000 s on one core
    assert "One core: **55.6 h** (40 runs)" in text


def _flat(method: str, task: str, levels: int, finals: list[float], n: int) -> list[dict]:
    """Result rows of one run per value in ``finals``: ``final`` from the first trial on."""
    from app.bench import RunSpec

    out = []
    for seed, final in enumerate(finals):
        raw = [
            {"trial": t, "objective": final, "wall_s": 0.5, "theta": []} for t in range(1, n + 1)
        ]
        out += result_rows(RunSpec(method, task, levels, seed, n), raw)
    return out


def test_default_is_set_against_every_peer_with_welch_p_redq_at_each_p_and_10k_runs():
    rows = (
        _flat(DEFAULT_METHOD, "throw", 7, [40.0, 41.0, 42.0], 500)
        + _flat("cem", "throw", 7, [28.0, 29.0, 30.0], 100)  # clearly behind: a lead
        + _flat("bo-lei", "throw", 7, [39.0, 43.0, 40.0], 100)  # overlapping: not significant
        + _flat("redq", "throw", 0, [13.0, 14.0], 500)  # no P: set against P=7
        + _flat("random", "throw", 7, [45.0, 44.0], 10_000)  # its 10K beats the default's 500
        + _flat(DEFAULT_METHOD, "throw", 2, [30.0], 100)  # one seed: no p-value
        + _flat("cem", "throw", 2, [28.0, 29.0], 100)
    )
    found = {
        (r["levels"], r["trials"], r["peer"], r["peer_trials"]): r
        for r in paper.default_vs_peers(rows)
    }
    lead = found[(7, 100, "cem", 100)]
    assert lead["diff"] == pytest.approx(12.0) and lead["p"] < 0.05
    assert found[(7, 100, "bo-lei", 100)]["p"] > 0.05
    assert found[(7, 500, "redq", 500)]["diff"] == pytest.approx(41.0 - 13.5)
    assert found[(7, 500, "random", 10_000)]["diff"] == pytest.approx(41.0 - 44.5)
    assert (7, 500, "random", 500) in found and (7, 100, "random", 100) in found
    assert found[(2, 100, "cem", 100)]["p"] is None
    assert not any(k[2] == DEFAULT_METHOD for k in found)
    text = "\n".join(paper.default_vs_peers_markdown(rows))
    assert "| throw | 7 | 100 | 41.00 (3) | cem | 100 | 29.00 (3) | +12.00 |" in text
    assert "| throw | 7 | 500 | 41.00 (3) | random | 10,000 | 44.50 (2) | -3.50 |" in text
    lines = {
        ln.split("|")[5].strip() + "@" + ln.split("|")[6].strip(): ln
        for ln in text.splitlines()
        if ln.startswith("| throw | 7 |")
    }
    assert lines["cem@100"].endswith("| **lead** |")
    assert lines["bo-lei@100"].endswith("| ahead |")
    assert "**behind** (p < 0.05)" in lines["random@10,000"]
