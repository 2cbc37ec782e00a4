"""`handful sim`: run one simulated episode from θ, a schedule file, or a random θ.

Options are parsed by hand (as strings) so that every bad input ends in one line on stderr
and a non-zero exit, never a traceback or a multi-line usage box.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

EXIT_BAD_INPUT = 2
EXIT_DIVERGED = 3
DEFAULT_LEVELS = 7


class BadInput(Exception):
    """A one-line complaint about the command line or an input file."""


def _fail(message: str, code: int = EXIT_BAD_INPUT) -> typer.Exit:
    typer.echo(f"handful sim: error: {message}", err=True)
    return typer.Exit(code)


def _parse_int(name: str, raw: str, lo: int, hi: int) -> int:
    try:
        value = int(raw)
    except ValueError:
        raise BadInput(f"{name} must be an integer, got {raw!r}") from None
    if not lo <= value <= hi:
        raise BadInput(f"{name} must be in {lo}..{hi}, got {value}")
    return value


def _parse_theta(raw: str) -> np.ndarray:
    parts = [p.strip() for p in raw.split(",") if p.strip()]
    if not parts:
        raise BadInput("--theta needs comma-separated numbers in [0, 1], e.g. 0.1,0.7,...")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise BadInput(f"--theta must be comma-separated numbers, got {raw!r}") from None
    return np.asarray(values)


def _read_schedule(path: Path, task: str) -> tuple[np.ndarray, int | None]:
    from app.policy import RELEASE_TASKS, PolicyError, check_release_step

    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise BadInput(f"cannot read {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise BadInput(f"{path} is not valid JSON: {exc.msg} (line {exc.lineno})") from None
    if not isinstance(doc, dict) or "pressures_pa" not in doc:
        raise BadInput(
            f'{path} must hold {{"pressures_pa": [[12 numbers], ...], "release_step": k}}'
        )
    rows = doc["pressures_pa"]
    if (
        not isinstance(rows, list)
        or not rows
        or not all(isinstance(r, list) and len(r) == 12 for r in rows)
    ):
        raise BadInput(f"{path}: pressures_pa must be a non-empty list of rows of 12 numbers (Pa)")
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for r in rows for v in r):
        raise BadInput(f"{path}: pressures_pa must contain only numbers (Pa)")
    schedule = np.asarray(rows, dtype=np.float64)
    try:
        release = check_release_step(
            doc.get("release_step"),
            horizon=len(rows),
            with_release=task in RELEASE_TASKS,
            owner=task,
        )
    except PolicyError as exc:
        raise BadInput(f"{path}: {exc}") from None
    return schedule, release


def _summary_line(summary: dict[str, Any]) -> str:
    parts = [
        f"task={summary['task']}",
        f"preset={summary['preset']}",
        f"command_hold={summary['command_hold']}",
        f"objective_rule={summary['objective_rule']}",
        f"objective={summary['objective']:.4f}",
        f"max_tip_speed={summary['max_tip_speed']:.3f} m/s",
        f"wall={summary['wall_s']:.3f} s",
    ]
    if summary.get("release_step") is not None:
        parts.append(f"release_step={summary['release_step']}")
    if summary.get("bend_limit_hits"):
        parts.append(f"bend_limit_hits={summary['bend_limit_hits']}")
    return "  ".join(parts)


def sim(
    task: Annotated[str, typer.Option(help="throw, hammer or tip_speed.")] = "",
    preset: Annotated[
        str,
        typer.Option(
            help="reference, fast, or fast-r1 (fast before session 12, for stored results)."
        ),
    ] = "reference",
    command_hold: Annotated[
        str, typer.Option(help="zero (held each step) or linear (ramped from the last).")
    ] = "zero",
    objective: Annotated[
        str, typer.Option(help="Scoring rule: paper (as printed) or published (its code).")
    ] = "paper",
    theta: Annotated[
        str | None, typer.Option(help="θ as comma-separated numbers in [0,1].")
    ] = None,
    levels: Annotated[
        str | None, typer.Option(help="P, pressure levels per paired command.")
    ] = None,
    schedule: Annotated[
        Path | None, typer.Option(help='JSON {"pressures_pa": [[12]×H], "release_step": k}.')
    ] = None,
    random: Annotated[bool, typer.Option("--random", help="A random θ (see --seed).")] = False,
    seed: Annotated[str | None, typer.Option(help="Seed for --random (default 0).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    save_trajectory: Annotated[
        Path | None, typer.Option(help="Write the trajectory (.npz, with qpos).")
    ] = None,
    export_xml: Annotated[
        Path | None, typer.Option(help="Write the compiled model (.xml).")
    ] = None,
) -> None:
    """Simulate one 5 s episode and print its objective (and, with --json, the tip-speed trace)."""
    try:
        summary = _run(
            task,
            preset,
            theta,
            levels,
            schedule,
            random,
            seed,
            save_trajectory,
            export_xml,
            command_hold,
            objective,
        )
    except BadInput as exc:
        raise _fail(str(exc)) from None
    except _Diverged as exc:
        raise _fail(str(exc), EXIT_DIVERGED) from None
    if summary is None:
        return
    if as_json:
        typer.echo(json.dumps(summary))
    else:
        typer.echo(_summary_line(summary))


class _Diverged(Exception):
    pass


def _run(
    task: str,
    preset: str,
    theta: str | None,
    levels: str | None,
    schedule_path: Path | None,
    random: bool,
    seed: str | None,
    save_trajectory: Path | None,
    export_xml_path: Path | None,
    command_hold: str = "zero",
    objective: str = "paper",
) -> dict[str, Any] | None:
    from app.policy import RELEASE_TASKS, Policy, PolicyError
    from app.sim import (
        COMMAND_HOLDS,
        OBJECTIVE_RULES,
        PRESETS,
        TASKS,
        SimulationDiverged,
        export_xml,
        rollout,
    )

    if not task:
        raise BadInput(f"--task is required: one of {', '.join(TASKS)}")
    if task not in TASKS:
        raise BadInput(f"unknown task {task!r}; choose one of {', '.join(TASKS)}")
    if preset not in PRESETS:
        raise BadInput(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    if command_hold not in COMMAND_HOLDS:
        raise BadInput(
            f"unknown --command-hold {command_hold!r}; choose one of {', '.join(COMMAND_HOLDS)}"
        )
    if objective not in OBJECTIVE_RULES:
        raise BadInput(
            f"unknown --objective {objective!r}; choose one of {', '.join(OBJECTIVE_RULES)}"
        )
    sources = [
        name
        for name, on in (
            ("--theta", theta is not None),
            ("--schedule", schedule_path is not None),
            ("--random", random),
        )
        if on
    ]
    if len(sources) > 1:
        raise BadInput(f"give only one of --theta, --schedule, --random (got {', '.join(sources)})")
    if seed is not None and not random:
        raise BadInput("--seed applies only with --random")
    if levels is not None and schedule_path is not None:
        raise BadInput("--levels applies to --theta or --random, not --schedule")

    if export_xml_path is not None:
        try:
            export_xml(task, export_xml_path, preset=preset)
        except OSError as exc:
            raise BadInput(f"cannot write {export_xml_path}: {exc.strerror or exc}") from None
    if not sources:
        if export_xml_path is not None:
            return None  # export only
        raise BadInput("give one of --theta, --schedule FILE.json or --random [--seed N]")

    info: dict[str, Any] = {}
    try:
        if schedule_path is not None:
            pressure_schedule_pa, release_step = _read_schedule(schedule_path, task)
        else:
            p_levels = _parse_int("--levels", levels, 2, 1000) if levels is not None else None
            policy = Policy(levels=p_levels or DEFAULT_LEVELS, with_release=task in RELEASE_TASKS)
            if random:
                rng_seed = _parse_int("--seed", seed, 0, 2**63 - 1) if seed is not None else 0
                th = np.random.default_rng(rng_seed).uniform(size=policy.dim)
                info["seed"] = rng_seed
            else:
                assert theta is not None
                th = _parse_theta(theta)
            decoded = policy.decode(th)
            pressure_schedule_pa, release_step = decoded.pressure_schedule_pa, decoded.release_step
            info.update(
                theta=[float(v) for v in th],
                levels=policy.levels,
                action_indices=[int(a) for a in decoded.action_indices],
            )
        res = rollout(
            task,
            pressure_schedule_pa,
            release_step=release_step,
            preset=preset,
            record_qpos=save_trajectory is not None,
            command_hold=command_hold,
            objective_rule=objective,
        )
    except PolicyError as exc:
        raise BadInput(str(exc)) from None
    except SimulationDiverged as exc:
        raise _Diverged(str(exc)) from None
    except ValueError as exc:
        raise BadInput(str(exc)) from None

    if save_trajectory is not None:
        try:
            res.trajectory.to_npz(save_trajectory)
        except OSError as exc:
            raise BadInput(f"cannot write {save_trajectory}: {exc.strerror or exc}") from None
    summary = res.to_summary()
    summary.update(info)
    summary["pressures_pa"] = np.asarray(pressure_schedule_pa).tolist()
    if not all(math.isfinite(v) for v in summary["tip_speed_100hz"]):  # pragma: no cover
        raise _Diverged("non-finite tip speed")
    return summary


def register(app: typer.Typer) -> None:
    """Add `handful sim` to the root app."""
    app.command("sim")(sim)
