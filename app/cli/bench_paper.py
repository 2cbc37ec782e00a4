"""`handful bench paper`: the paper's grid, run (or resumed) and written as the paper's tables
with handful's number beside each of the paper's."""

from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

import typer

from app.cli.bench_optim import (
    ADDRESS,
    BACKEND,
    COMMAND_HOLD,
    OBJECTIVE,
    PRESET,
    WORKERS,
    _fail,
    _key_values,
    _report_busy,
    check_execution,
    sim_settings,
)


def paper(
    cells: list[str] = typer.Option(
        None,
        "--cells",
        help="which cells of the grid, e.g. P=7, P=2,5, trials<=500, task=throw, "
        "method=bo-lei,cem (terms are ANDed: repeat --cells or separate terms by spaces; "
        "default: the whole grid)",
    ),
    trials: str = typer.Option(
        None, "--trials", help="trial counts, e.g. 100 or 100,500 (same as --cells trials=...)"
    ),
    seeds: int = typer.Option(5, "--seeds", help="seeds per cell (0 .. N-1; the paper ran 5)"),
    out: Path = typer.Option(Path("bench_out/paper"), "--out", help="output (and cache) folder"),
    bo_fit: str = typer.Option(
        "fast",
        "--bo-fit",
        help="BO's GP fits: fast (a full fit every 10 trials or 10 %% of N, its "
        "hyperparameters kept between, the acquisition on a once-factorised posterior; "
        "5x faster than full over 500 trials, no loss measured), warm (refitted from the last "
        "full fit's hyperparameters after every trial) or full (the paper: from scratch after "
        "every trial)",
    ),
    preset: str = PRESET,
    command_hold: str = COMMAND_HOLD,
    objective: str = OBJECTIVE,
    backend: str = BACKEND,
    address: str = ADDRESS,
    workers: int = WORKERS,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bars and ETA"),
    redq: list[str] = typer.Option(
        None,
        "--redq",
        help="a REDQ setting KEY=VALUE for the REDQ rows (repeatable), e.g. device=cuda or "
        "batch_size=64; settings other than device and checkpoint_every give the runs their "
        "own cache key",
    ),
    cached_only: bool = typer.Option(
        False, "--cached-only", help="run nothing: write paper.md from the runs stored in DIR"
    ),
) -> None:
    """Run the paper's grid (BO-UCB, BO-LEI, CEM and random search on throwing and hammering,
    P in 2, 5, 7, 10, after 100 / 500 / 10K trials; plus handful's default method) and write
    DIR/paper.md (the paper's tables with handful's numbers beside them), DIR/results.csv and
    DIR/paper_curves.png. Finished runs are cached: run again to resume or extend."""
    from app.bench import RunBusy, run_sweep, stored_rows
    from app.bench import paper as grid_mod
    from app.bench.report import plot_curves, write_results_csv
    from app.bench.specs import SWEEP_METHODS as METHODS
    from app.bench.stats import result_rows
    from app.optim import SettingsError

    # Terms are ANDed: repeat --cells or separate them by spaces or ';' (commas list values).
    terms = [t for raw in cells or [] for t in re.split(r"[\s;&]+", raw) if t]
    if trials:
        terms.append(f"trials={trials}")
    preset, command_hold, objective = sim_settings(preset, command_hold, objective)
    if bo_fit not in grid_mod.BO_FITS:
        _fail(f"--bo-fit must be one of {', '.join(grid_mod.BO_FITS)}, got {bo_fit!r}")
    check_execution(backend, address, workers)
    from app.sim import PRESETS

    if preset not in PRESETS:
        _fail(f"unknown --preset {preset!r}; choose from {', '.join(PRESETS)}")
    try:
        for t in terms:
            grid_mod.parse_term(t)
        whole = grid_mod.grid(METHODS)
        chosen = grid_mod.select(whole, terms)
        if not chosen:
            _fail(f"no cell of the paper's grid matches {' '.join(terms)}")
        settings = {
            "seeds": seeds,
            "preset": preset,
            "command_hold": command_hold,
            "objective_rule": objective,
            "bo_settings": dict(grid_mod.BO_FITS[bo_fit]),
            "rl_settings": _key_values("redq", redq or []),
        }
        specs = grid_mod.run_specs(chosen, **settings)
        # the tables show every run DIR holds with these settings, not only this slice's
        stored_specs = grid_mod.run_specs(whole, **settings)
    except SettingsError as exc:
        _fail(str(exc))
    busy: list[RunBusy] = []  # runs another process was writing: left to it
    if cached_only:
        runs = {s: r for s in specs if (r := stored_rows(s, out))}
        if not runs:
            _fail(f"no runs of these cells stored in {out}")
    else:
        n_trials = sum(s.budget for s in specs)
        typer.echo(f"{len(chosen)} cells → {len(specs)} runs, {n_trials:,} trials; cache {out}")
        runs = run_sweep(
            specs,
            out,
            backend=backend,
            address=address,
            workers=workers or None,
            progress=progress,
            busy=busy,
            stored=stored_specs,
        )
    rows = [r for s, run in runs.items() for r in result_rows(s, run)]
    out.mkdir(parents=True, exist_ok=True)
    write_results_csv(out / "results.csv", rows)
    header = [
        f"Simulator preset `{preset}`, command hold `{command_hold}`, scoring rule "
        f"`{objective}`; BO GP fits `{bo_fit}`; {seeds} seeds asked per cell; std over seeds "
        "with ddof 0. Every run stored in this folder with these settings is shown, not only "
        "the cells this command asked for.",
        "",
        "Command: `handful bench paper "
        + shlex.join(sys.argv[3:] if len(sys.argv) > 3 else [])
        + "`",
    ]
    text = grid_mod.paper_markdown(rows, chosen, header=header, available=METHODS)
    (out / "paper.md").write_text(text)
    if rows:
        plot_curves(rows, out / "paper_curves.png")
    typer.echo(text)
    typer.echo(f"wrote {out / 'paper.md'}, {out / 'results.csv'}, {out / 'paper_curves.png'}")
    _report_busy(busy)


def register(bench_app: typer.Typer) -> None:
    """Add this benchmark to the `bench` group."""
    bench_app.command("paper")(paper)
