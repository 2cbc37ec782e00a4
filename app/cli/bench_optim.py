"""`handful bench optim`: the optimiser sweep that reproduces the paper's tables."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer


def _split(values: list[str] | None, default: list[str]) -> list[str]:
    """Options may repeat (``--levels 2 --levels 5``) or hold commas (``--levels 2,5``)."""
    if not values:
        return list(default)
    return [v.strip() for raw in values for v in raw.split(",") if v.strip()]


def _ints(name: str, values: list[str]) -> list[int]:
    try:
        return [int(v) for v in values]
    except ValueError:
        _fail(f"--{name} takes integers, got {', '.join(values)}")
        raise  # unreachable


def _key_values(name: str, items: list[str]) -> dict[str, object]:
    """``KEY=VALUE`` options as a dict; a VALUE is read as JSON when it parses, else text."""
    import json

    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            _fail(f"--{name} takes KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = json.loads(value)
        except ValueError:
            out[key.strip()] = value.strip()
    return out


def _fail(message: str) -> None:
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(2)


def _report_busy(busy: list[Any]) -> None:
    """Runs another process was writing (``app.bench.RunBusy``), left to it: one line each on
    stderr and exit 1, after the outputs were written from what is stored."""
    if busy:
        for exc in busy:
            typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1)


# The options `handful bench optim` and `handful bench paper` share (one declaration each).
PRESET = typer.Option(
    None,
    "--preset",
    help="simulator preset: reference, fast (default: the paper-matching) or fast-r1 (fast "
    "before session 12: the committed caches)",
)
COMMAND_HOLD = typer.Option(
    None,
    "--command-hold",
    help="zero (each row held) or linear (ramped over each step); default: paper-matching",
)
OBJECTIVE = typer.Option(
    None, "--objective", help="scoring rule: paper or published; default: paper-matching"
)
BACKEND = typer.Option("local", "--backend", help="local (process pool) or ray")
ADDRESS = typer.Option(None, "--address", help="Ray cluster address (with --backend ray)")
WORKERS = typer.Option(0, "--workers", help="parallel runs (default: all cores)")


def check_execution(backend: str, address: str | None, workers: int) -> None:
    """``--backend``, ``--address`` and ``--workers`` make sense together; one clear line and
    exit 2 otherwise."""
    if backend not in ("local", "ray"):
        _fail(f"--backend must be local or ray, got {backend!r}")
    if address and backend != "ray":
        _fail("--address needs --backend ray")
    if workers < 0:
        _fail(f"--workers must be ≥ 0, got {workers}")


def sim_settings(
    preset: str | None, command_hold: str | None, objective: str | None
) -> tuple[str, str, str]:
    """(preset, command hold, scoring rule): each the paper-matching one unless given; one
    clear line and exit 2 for an unknown one."""
    from app import bench

    preset = preset or bench.PAPER_PRESET
    command_hold = command_hold or bench.PAPER_COMMAND_HOLD
    objective = objective or bench.PAPER_OBJECTIVE_RULE
    if command_hold not in bench.COMMAND_HOLDS:
        _fail(
            f"unknown --command-hold {command_hold!r}; choose from {', '.join(bench.COMMAND_HOLDS)}"
        )
    if objective not in bench.OBJECTIVE_RULES:
        _fail(f"unknown --objective {objective!r}; choose from {', '.join(bench.OBJECTIVE_RULES)}")
    return preset, command_hold, objective


def optim(
    task: list[str] = typer.Option(
        None, "--task", help="throw, hammer, tip_speed (repeat or comma-separate; default throw)"
    ),
    levels: list[str] = typer.Option(None, "--levels", help="P values, e.g. 2,5 (default 2)"),
    budget: list[str] = typer.Option(
        None, "--budget", help="trial counts to report, e.g. 100,500; runs last the largest"
    ),
    seeds: int = typer.Option(3, "--seeds", help="number of seeds (0 .. N-1)"),
    methods: list[str] = typer.Option(None, "--methods", help="methods (default: all)"),
    preset: str = PRESET,
    command_hold: str = COMMAND_HOLD,
    objective: str = OBJECTIVE,
    out: Path = typer.Option(Path("bench_out/optim"), "--out", help="output (and cache) folder"),
    backend: str = BACKEND,
    address: str = ADDRESS,
    workers: int = WORKERS,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="show progress bars"),
    redq: list[str] = typer.Option(
        None,
        "--redq",
        help="a REDQ setting KEY=VALUE for the redq / redq-joints runs (repeatable), e.g. "
        "utd=16, pretrain_episodes=250, batch_size=256, hidden_sizes=[256,256]",
    ),
    cached_only: bool = typer.Option(
        False,
        "--cached-only",
        help="run nothing: write the outputs from the runs stored in DIR (unfinished ones too, "
        "up to the trials they reached)",
    ),
) -> None:
    """Run BO, CEM, random search, Optuna and CMA-ES (and, asked for, the RL baseline REDQ:
    ``--methods redq,redq-joints``) on the simulated tasks; write
    DIR/results.csv, DIR/summary.md and DIR/curves.png. Finished runs are cached and skipped;
    the outputs also show every other method's runs DIR holds for the same tasks, P, seeds and
    simulator settings (``--cached-only`` shows just the methods asked for).

    By default the simulator reproduces the paper's tables: preset, command hold and scoring
    rule of ``app.bench.PAPER_PRESET`` / ``PAPER_COMMAND_HOLD`` / ``PAPER_OBJECTIVE_RULE``."""
    from app import bench
    from app.bench.specs import RL_METHODS, SWEEP_METHODS
    from app.optim import METHODS, SettingsError

    preset, command_hold, objective = sim_settings(preset, command_hold, objective)

    tasks = _split(task, ["throw"])
    ps = _ints("levels", _split(levels, ["2"]))
    budgets = sorted(set(_ints("budget", _split(budget, ["100"]))))
    chosen = _split(methods, list(METHODS))
    check_execution(backend, address, workers)
    try:
        from app.sim import PRESETS
    except ImportError as exc:  # pragma: no cover - the simulator ships with handful
        _fail(f"the simulator is not available: {exc}")
    if preset not in PRESETS:
        _fail(f"unknown --preset {preset!r}; choose from {', '.join(PRESETS)}")
    grid: dict[str, Any] = {
        "tasks": tasks,
        "levels": ps,
        "budgets": budgets,
        "seeds": seeds,
        "preset": preset,
        "command_hold": command_hold,
        "objective_rule": objective,
    }
    try:
        rl_settings = _key_values("redq", redq or [])
        specs = bench.make_specs(methods=chosen, rl_settings=rl_settings, **grid)
        # every method's runs of the same grid: the outputs show those DIR holds, not only this
        # invocation's methods (a sweep is often run a few methods at a time); RL runs only
        # of the RL methods asked for, whose --redq settings name their runs
        others = [m for m in SWEEP_METHODS if m not in RL_METHODS and m not in chosen]
        whole = bench.make_specs(methods=[*chosen, *others], rl_settings=rl_settings, **grid)
    except SettingsError as exc:
        _fail(str(exc))
    busy: list[bench.RunBusy] = []  # runs another process was writing: left to it
    if cached_only:
        runs = {s: r for s in specs if (r := bench.stored_rows(s, out))}
        if not runs:
            _fail(f"no runs of this sweep stored in {out}")
        specs = [s for s in specs if s in runs]
    else:
        runs = bench.run_sweep(
            specs,
            out,
            backend=backend,
            address=address,
            workers=workers or None,
            progress=progress,
            busy=busy,
            stored=whole,
        )
        specs = [s for s in whole if s in runs] + [s for s in runs if s not in set(whole)]
    bench.write_outputs(out, specs, runs, budgets)
    typer.echo((out / "summary.md").read_text())
    typer.echo(f"wrote {out / 'results.csv'}, {out / 'summary.md'}, {out / 'curves.png'}")
    _report_busy(busy)


def register(bench_app: typer.Typer) -> None:
    """Add this benchmark to the `bench` group."""
    bench_app.command("optim")(optim)
