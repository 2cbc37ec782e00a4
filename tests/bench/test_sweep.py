"""The sweep behind `handful bench optim`: formats, caching/resume, backends, bad arguments."""

from __future__ import annotations

import csv
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app import bench

HANDFUL = shutil.which("handful") or str(Path(sys.executable).with_name("handful"))


def handful(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run(
        [HANDFUL, *args], cwd=cwd, capture_output=True, text=True, timeout=300, env=env
    )


def test_cli_sweep_writes_results_summary_and_curves_and_skips_cached_runs(tmp_path):
    out = tmp_path / "sweep"
    # an earlier invocation's method in the same folder (same task, P, seeds, sim settings) and
    # one with another hold: the outputs keep the first, never mix in the second
    for hold, value in (("linear", 7.25), ("zero", 99.0)):
        for seed in range(2):
            spec = bench.RunSpec("optuna-tpe", "hammer", 2, seed, 4, "fast", command_hold=hold,
                                 objective_rule="published")  # fmt: skip
            bench.write_run(spec, out, [{"trial": t, "objective": value + seed, "wall_s": 0.1,
                                         "theta": [0.5] * 10} for t in range(1, 5)])  # fmt: skip
    args = ["bench", "optim", "--task", "hammer", "--levels", "2", "--budget", "2,4"]
    args += ["--seeds", "2", "--methods", "random,cem", "--preset", "fast"]
    args += ["--out", str(out), "--workers", "1", "--no-progress"]
    first = handful(*args, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    with open(out / "results.csv", newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == bench.RESULT_COLUMNS
        rows = list(reader)
    stored = [r for r in rows if r["method"] == "optuna-tpe"]
    assert sorted({float(r["best_so_far"]) for r in stored}) == [7.25, 8.25]
    rows = [r for r in rows if r["method"] != "optuna-tpe"]
    assert len(rows) == 2 * 2 * 4  # methods × seeds × trials
    runs: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        assert r["task"] == "hammer" and r["levels"] == "2"
        runs.setdefault((r["method"], r["seed"]), []).append(r)
    for run_rows in runs.values():
        assert [int(r["trial"]) for r in run_rows] == [1, 2, 3, 4]
        obj = np.array([float(r["objective"]) for r in run_rows])
        best = np.array([float(r["best_so_far"]) for r in run_rows])
        np.testing.assert_allclose(best, np.maximum.accumulate(obj), rtol=1e-5)
        assert all(float(r["wall_s"]) > 0 for r in run_rows)
        # by default the paper-matching simulator settings, named in every row
        assert {(r["preset"], r["command_hold"], r["objective_rule"]) for r in run_rows} == {
            ("fast", "linear", "published")
        }

    summary = (out / "summary.md").read_text()
    assert "## hammer: best objective so far, mean ± std over 2 seeds" in summary
    assert "(sim preset fast, command hold linear, objective published)" in summary
    assert "| Method | Trials | P=2 |" in summary
    for method in ("random", "cem"):
        for budget in (2, 4):
            vals = [
                float(r["best_so_far"])
                for r in rows
                if r["method"] == method and int(r["trial"]) == budget
            ]
            cell = f"{np.mean(vals):.3f} ± {np.std(vals):.3f}"
            assert re.search(rf"\| {method} \| {budget} \| \**{re.escape(cell)}\**", summary)
    assert re.search(r"\| optuna-tpe \| 4 \| \**7\.750 ± 0\.500\**", summary)
    assert (out / "curves.png").read_bytes()[:4] == b"\x89PNG"

    # A second run finds every run cached and writes identical results.
    before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()}
    again = handful(*args, cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()} == before
    with open(out / "results.csv", newline="") as fh:
        assert [r for r in csv.DictReader(fh) if r["method"] != "optuna-tpe"] == rows


def test_the_hold_and_rule_reach_the_episodes_and_keep_separate_caches(tmp_path):
    held = bench.RunSpec("random", "throw", 2, 0, 3, "fast")
    ramped = bench.RunSpec(
        "random", "throw", 2, 0, 3, "fast", command_hold="linear", objective_rule="published"
    )
    assert held.key != ramped.key
    rows_held, rows_ramped = bench.run_one(held, tmp_path), bench.run_one(ramped, tmp_path)
    assert [r["theta"] for r in rows_held] == [r["theta"] for r in rows_ramped]  # same θ
    f = bench.objective_fn("throw", 2, "fast", "linear", "published")
    assert [r["objective"] for r in rows_ramped] == [f(np.array(r["theta"])) for r in rows_held]
    assert [r["objective"] for r in rows_ramped] != [r["objective"] for r in rows_held]
    cached = bench.cached_rows(ramped, tmp_path)
    assert cached is not None
    assert [r["objective"] for r in cached] == [r["objective"] for r in rows_ramped]


def test_an_interrupted_or_extended_run_resumes_to_the_same_result(tmp_path):
    spec5 = bench.RunSpec("cem", "hammer", 2, 0, 5, "fast")
    spec3 = bench.RunSpec("cem", "hammer", 2, 0, 3, "fast")
    direct = bench.run_one(spec5, tmp_path / "a")
    bench.run_one(spec3, tmp_path / "b")  # a shorter finished run ...
    extended = bench.run_one(spec5, tmp_path / "b")  # ... extended by two trials
    assert [r["theta"] for r in extended] == [r["theta"] for r in direct]
    assert [r["objective"] for r in extended] == [r["objective"] for r in direct]
    # An interrupted run: a part file with its first two trials.
    part_dir = tmp_path / "c" / "runs"
    part_dir.mkdir(parents=True)
    bench.write_part(part_dir / f"{spec5.key}.part.csv", direct[:2])
    resumed = bench.run_one(spec5, tmp_path / "c")
    assert [r["objective"] for r in resumed] == [r["objective"] for r in direct]
    assert not (part_dir / f"{spec5.key}.part.csv").exists()
    assert len(bench.read_run(part_dir / f"{spec5.key}.csv")) == 5


def test_a_sweep_adds_the_stored_runs_of_its_grid_without_running_them(tmp_path):
    asked = bench.RunSpec("cem", "hammer", 2, 0, 3, "fast")
    finished = bench.RunSpec("cem", "hammer", 2, 1, 3, "fast")
    unfinished = bench.RunSpec("cem", "hammer", 2, 2, 3, "fast")
    absent = bench.RunSpec("cem", "hammer", 2, 3, 3, "fast")
    done = bench.run_one(finished, tmp_path)
    part = bench.run_dir(tmp_path) / f"{unfinished.key}.part.csv"
    bench.write_part(part, bench.run_one(unfinished, tmp_path / "elsewhere")[:2])
    runs = bench.run_sweep(
        [asked], tmp_path, workers=1, progress=False, stored=[asked, finished, unfinished, absent]
    )
    assert set(runs) == {asked, finished, unfinished}  # nothing of ``absent`` to show
    assert len(runs[asked]) == 3  # the one asked for ran
    assert runs[finished] == done
    assert len(runs[unfinished]) == 2 and part.exists()  # shown as it stands, not run on
    assert not (bench.run_dir(tmp_path) / f"{absent.key}.csv").exists()


def test_a_part_file_replaced_under_a_running_run_is_written_anew(tmp_path):
    """A git checkout (or stash) of the committed cache replaces a running run's part file:
    the run writes it anew from its own rows, so stopping it afterwards loses nothing."""
    spec = bench.RunSpec("cem", "hammer", 2, 0, 6, "fast")
    direct = bench.run_one(spec, tmp_path / "a")
    out = tmp_path / "b"
    part = out / "runs" / f"{spec.key}.part.csv"
    f = bench.objective_fn("hammer", 2, "fast")
    calls = 0

    def objective(theta):
        nonlocal calls
        calls += 1
        if calls == 3:  # an older version of the file, put in its place
            bench.write_part(part.with_name("old.csv"), bench.read_run(part)[:1])
            os.replace(part.with_name("old.csv"), part)
        if calls == 5:
            raise KeyboardInterrupt  # the run is stopped during trial 5
        return f(theta)

    with pytest.raises(KeyboardInterrupt):
        bench.run_one(spec, out, objective=objective)
    kept = bench.read_run(part)
    assert [r["objective"] for r in kept] == [r["objective"] for r in direct[:4]]
    resumed = bench.run_one(spec, out)
    assert [r["theta"] for r in resumed] == [r["theta"] for r in direct]


def test_summary_marks_the_best_mean_and_reports_each_budget():
    rows = []
    for method, base in (("a", 1.0), ("b", 2.0)):
        for seed in range(2):
            spec = bench.RunSpec(method, "throw", 5, seed, 3)
            objs = [base + seed, base, base + 2 * seed + 0.5]
            trial_rows = [
                {"trial": i + 1, "objective": v, "wall_s": 0.1} for i, v in enumerate(objs)
            ]
            rows += bench.result_rows(spec, trial_rows)
    text = bench.summary_markdown(rows, [1, 3])
    assert "| a | 1 | 1.500 ± 0.500 |" in text
    assert "| b | 1 | **2.500 ± 0.500** |" in text
    assert "| b | 3 | **3.500 ± 1.000** |" in text


def _rows_of(finals: dict[str, list[float]], task: str = "hammer") -> list[dict]:
    """Result rows where each (method, seed) run ends at the given best value."""
    rows = []
    for method, values in finals.items():
        for seed, v in enumerate(values):
            spec = bench.RunSpec(method, task, 5, seed, 2)
            rows += bench.result_rows(
                spec,
                [
                    {"trial": 1, "objective": v - 1.0, "wall_s": 0.1},
                    {"trial": 2, "objective": v, "wall_s": 0.1},
                ],
            )
    return rows


def test_head_to_head_gives_the_difference_and_welch_p():
    from scipy.stats import ttest_ind

    ref, near, far = [3.0, 3.2, 2.9, 3.1], [3.1, 2.8, 3.0, 3.3], [1.0, 1.2, 0.9, 1.1, 1.0]
    rows = _rows_of({"bo-x": ref, "near": near, "far": far, "solo": [9.0]})
    pairs = {h["peer"]: h for h in bench.head_to_head(rows, 2, "bo-x")}
    assert set(pairs) == {"near", "far", "solo"}
    assert pairs["far"]["diff"] == pytest.approx(np.mean(ref) - np.mean(far))
    assert pairs["far"]["p"] == pytest.approx(ttest_ind(ref, far, equal_var=False).pvalue)
    assert pairs["far"]["p"] < 1e-4 < 0.3 < pairs["near"]["p"]
    assert pairs["solo"]["p"] is None and pairs["solo"]["peer_n"] == 1
    text = bench.summary_markdown(rows, [1, 2], reference="bo-x")
    assert "## bo-x against each peer after 2 trials" in text
    assert "| hammer | 5 | far | 3.050 (4) | 1.040 (5) | +2.010 |" in text
    assert bench.head_to_head(rows, 2, "missing") == []


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--methods", "bogus"], "unknown method 'bogus'"),
        (["--budget", "0"], "budget must be ≥ 1 trial, got 0"),
        (["--levels", "1"], "levels (P) must be ≥ 2, got 1"),
        (["--preset", "ultra"], "unknown --preset 'ultra'"),
        (["--command-hold", "cubic"], "unknown --command-hold 'cubic'; choose from zero, linear"),
        (["--objective", "best"], "unknown --objective 'best'; choose from paper, published"),
    ],
)
def test_bad_arguments_exit_nonzero_with_one_clear_line(tmp_path, args, message):
    res = handful("bench", "optim", *args, "--out", str(tmp_path / "o"), cwd=tmp_path)
    assert res.returncode != 0
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and message in lines[0], res.stderr
    assert not (tmp_path / "o" / "results.csv").exists()


@pytest.mark.slow
def test_a_tiny_sweep_on_local_ray_agrees_with_the_local_backend(tmp_path, sweep_both_ways):
    specs = bench.make_specs(
        methods=["random", "cem"],
        tasks=["hammer"],
        levels=[2],
        budgets=[3],
        seeds=2,
        preset="fast",
    )
    local, remote = sweep_both_ways(specs, workers=2)
    for s in specs:
        assert [r["objective"] for r in remote[s]] == [r["objective"] for r in local[s]]
        assert [r["theta"] for r in remote[s]] == [r["theta"] for r in local[s]]
    a = bench.write_outputs(tmp_path / "local", specs, local, [3])
    b = bench.write_outputs(tmp_path / "ray", specs, remote, [3])
    strip = [{k: v for k, v in r.items() if k != "wall_s"} for r in a]
    assert strip == [{k: v for k, v in r.items() if k != "wall_s"} for r in b]


def test_a_cache_line_cut_short_is_dropped_on_resume(tmp_path):
    rows = [
        {"trial": i + 1, "objective": float(i), "wall_s": 0.1, "theta": [0.5]} for i in range(3)
    ]
    path = tmp_path / "x.part.csv"
    bench.write_part(path, rows)
    with open(path, "a") as fh:
        fh.write('4,1.5,0.1,"[0.2')  # interrupted mid-write
    assert bench.read_run(path) == rows


def test_curves_tell_a_dozen_methods_apart(tmp_path, monkeypatch):
    """Past tab10's ten colours each method still gets its own colour and dash pattern."""
    from matplotlib.figure import Figure

    from app.bench import plot_curves

    saved: list[Figure] = []
    real_savefig = Figure.savefig
    monkeypatch.setattr(
        Figure, "savefig", lambda fig, *a, **k: (saved.append(fig), real_savefig(fig, *a, **k))
    )
    rows = [
        {"task": "throw", "levels": 2, "method": f"m{i}", "seed": s, "best_so_far": v}
        for i in range(12)
        for s in range(2)
        for v in (1.0, 2.0 + i)
    ]
    plot_curves(rows, tmp_path / "curves.png")
    [ax] = [a for a in saved[0].axes if a.lines]
    styles = {(str(line.get_color()), line.get_linestyle()) for line in ax.lines}
    assert len(ax.lines) == 12 and len(styles) == 12


def test_a_run_another_process_writes_is_left_to_it_and_named(tmp_path):
    """Two writers of one run would interleave their trials in its part file: the second is
    refused (RunBusy, naming the writer's pid); a sweep goes on without that run and the CLI
    writes its outputs, then says which runs it left, one line each, and exits 1."""
    from app.bench.cache import RunBusy, run_dir, run_lock

    out = tmp_path / "sweep"
    held = bench.RunSpec("random", "hammer", 2, 0, 3, "fast", command_hold="linear",
                         objective_rule="published")  # fmt: skip
    free = bench.RunSpec("random", "hammer", 2, 1, 3, "fast", command_hold="linear",
                         objective_rule="published")  # fmt: skip
    holder = subprocess.Popen(  # another process writing `held`
        [sys.executable, "-c", "import sys, time; from pathlib import Path; "
         "from app import bench; from app.bench.cache import run_lock; "
         "spec = bench.RunSpec('random', 'hammer', 2, 0, 3, 'fast', command_hold='linear', "
         "objective_rule='published'); "
         "lock = run_lock(spec, Path(sys.argv[1])); lock.__enter__(); print('held', flush=True); "
         "time.sleep(120)", str(out)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(RunBusy, match=rf"hammer_P2_random_s0_fast.*pid {holder.pid}\)"):
            bench.run_one(held, out)
        busy: list[RunBusy] = []
        runs = bench.run_sweep([held, free], out, workers=1, progress=False, busy=busy)
        assert list(runs) == [free] and len(runs[free]) == 3
        assert [str(e).split(" in ")[0] for e in busy] == [f"run {held.key}"]
        with pytest.raises(RunBusy):  # without a list to put it in, it is raised
            bench.run_sweep([held], out, workers=1, progress=False)
        args = ["bench", "optim", "--task", "hammer", "--levels", "2", "--budget", "3",
                "--seeds", "2", "--methods", "random", "--out", str(out), "--workers", "1",
                "--no-progress"]  # fmt: skip
        cli = handful(*args, cwd=tmp_path)
        assert cli.returncode == 1, cli.stderr
        lines = cli.stderr.strip().splitlines()
        assert len(lines) == 1 and f"pid {holder.pid}" in lines[0] and held.key in lines[0]
        assert (out / "summary.md").exists()  # the outputs, from what is stored
    finally:
        holder.kill()
        holder.wait()
    # the system let go of the killed holder's lock: the run goes on, and leaves no lock file
    assert len(bench.run_one(held, out)) == 3
    assert not list(run_dir(out).glob("*.lock"))
    # one process, a second writer: refused too
    with (
        run_lock(held, out),
        pytest.raises(RunBusy, match=rf"pid {os.getpid()}\)"),
        run_lock(held, out),
    ):
        pass
