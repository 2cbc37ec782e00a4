"""`handful worker sim|hardware`: run trials for a server, over HTTP only."""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

worker_app = typer.Typer(
    help="Workers that claim and run trials for a handful server.", no_args_is_help=True
)

ServerOpt = Annotated[
    str, typer.Option("--server", envvar="HANDFUL_SERVER", help="server URL, e.g. http://host:8000")
]
TokenOpt = Annotated[
    str | None,
    typer.Option(
        "--token",
        help="a worker token (visible to anyone running ps: prefer --token-file or HANDFUL_TOKEN)",
        show_default=False,
    ),
]
TokenFileOpt = Annotated[
    Path | None,
    typer.Option(
        "--token-file",
        envvar="HANDFUL_TOKEN_FILE",
        help="a file holding the worker token (first line)",
        show_default=False,
    ),
]
IdOpt = Annotated[str | None, typer.Option("--worker-id", help="name in the audit log")]
MaxTrialsOpt = Annotated[
    int | None, typer.Option("--max-trials", min=1, help="exit after this many trials")
]
IdleOpt = Annotated[
    float | None, typer.Option("--idle-exit", min=0.0, help="exit after this many idle seconds")
]
PollOpt = Annotated[float, typer.Option("--poll", min=0.05, help="longest pause between claims, s")]
LogOpt = Annotated[str, typer.Option("--log-level", help="DEBUG, INFO, WARNING")]


def _setup(log_level: str) -> None:
    logging.basicConfig(
        level=log_level.upper(),
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per request is noise


def resolve_token(token: str | None, token_file: Path | None) -> str:
    """The worker's token: from --token-file, else the HANDFUL_TOKEN environment variable,
    else --token (which ``ps`` shows to everyone on the machine)."""
    if token_file is not None:
        try:
            text = token_file.read_text().strip().splitlines()
        except OSError as exc:
            raise typer.BadParameter(f"cannot read the token file: {exc}") from None
        if not text or not text[0].strip():
            raise typer.BadParameter(f"the token file {token_file} is empty")
        return text[0].strip()
    env = os.environ.get("HANDFUL_TOKEN", "").strip()
    if env:
        return env
    if token:
        return token
    raise typer.BadParameter("give the worker's token: --token-file PATH or HANDFUL_TOKEN")


def _client(server: str, token: str):
    from app.client import HandfulClient

    # Retries live in the worker (app.workers.common.retry), with backoff across restarts.
    return HandfulClient(server, token=token, timeout=30.0)


def _parse_options(pairs: list[str]) -> dict[str, str]:
    options: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"driver option {pair!r} must look like KEY=VALUE")
        options[key.strip()] = value
    return options


def _run(worker: Any, max_trials: int | None, idle_exit: float | None) -> int:
    """Run a worker; a refusal from the server (bad token, wrong role) is one line, exit 1."""
    from app.workers.common import PermanentError

    try:
        return int(worker.run(max_trials=max_trials, idle_exit_s=idle_exit))
    except PermanentError as exc:
        typer.echo(f"error: the server refused the worker: {exc}", err=True)
        raise typer.Exit(1) from None


@worker_app.command("sim")
def sim(
    server: ServerOpt,
    token: TokenOpt = None,
    token_file: TokenFileOpt = None,
    max_parallel: Annotated[
        int | None,
        typer.Option(
            "--max-parallel",
            min=1,
            envvar="HANDFUL_MAX_PARALLEL",
            help="rollouts at once (default: all cores)",
        ),
    ] = None,
    worker_id: IdOpt = None,
    max_trials: MaxTrialsOpt = None,
    idle_exit: IdleOpt = None,
    poll: PollOpt = 1.0,
    prefetch: Annotated[
        int,
        typer.Option(
            "--prefetch", min=0, help="trials claimed ahead so no process waits on the network"
        ),
    ] = 1,
    no_qpos: Annotated[
        bool, typer.Option("--no-qpos", help="do not upload joint positions (no 3D replay)")
    ] = False,
    log_level: LogOpt = "INFO",
) -> None:
    """Claim queued sim trials, run them on all cores, upload objective and trajectory."""
    from app.workers.common import StopFlag
    from app.workers.sim import SimWorker

    _setup(log_level)
    stop = StopFlag()
    stop.install()
    worker = SimWorker(
        _client(server, resolve_token(token, token_file)),
        max_parallel=max_parallel,
        worker_id=worker_id,
        poll_s=poll,
        record_qpos=not no_qpos,
        prefetch=prefetch,
        stop=stop,
    )
    logging.getLogger("handful.worker").info(
        "sim worker %s on %s, %d process(es)", worker.worker_id, server, worker.max_parallel
    )
    ran = _run(worker, max_trials, idle_exit)
    typer.echo(f"sim worker {worker.worker_id}: {ran} trial(s) run, exiting")


@worker_app.command("hardware")
def hardware(
    server: ServerOpt,
    driver: Annotated[
        str,
        typer.Option(
            "--driver", help="driver name (e.g. standin), plug-in name, or 'module:factory'"
        ),
    ],
    token: TokenOpt = None,
    token_file: TokenFileOpt = None,
    driver_option: Annotated[
        list[str] | None,
        typer.Option("--driver-option", "-o", help="KEY=VALUE passed to the driver (repeatable)"),
    ] = None,
    worker_id: IdOpt = None,
    max_trials: MaxTrialsOpt = None,
    idle_exit: IdleOpt = None,
    poll: PollOpt = 1.0,
    log_level: LogOpt = "INFO",
) -> None:
    """Claim confirmed hardware trials and run them, one at a time, through a robot driver."""
    from app.workers.common import StopFlag
    from app.workers.drivers import DriverError, load_driver
    from app.workers.hardware import HardwareWorker

    _setup(log_level)
    try:
        robot = load_driver(driver, **_parse_options(driver_option or []))
    except DriverError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    stop = StopFlag()
    stop.install()
    client = _client(server, resolve_token(token, token_file))
    worker = HardwareWorker(client, robot, worker_id=worker_id, poll_s=poll, stop=stop)
    logging.getLogger("handful.worker").info(
        "hardware worker %s on %s, driver %s", worker.worker_id, server, driver
    )
    ran = _run(worker, max_trials, idle_exit)
    typer.echo(f"hardware worker {worker.worker_id}: {ran} trial(s) run, exiting")


@worker_app.command("drivers")
def drivers() -> None:
    """List the robot drivers this installation knows."""
    from app.workers.drivers import available_drivers

    for name, target in sorted(available_drivers().items()):
        typer.echo(f"{name}\t{target}")


def register(app: typer.Typer) -> None:
    """Add the `worker` group to the root app."""
    app.add_typer(worker_app, name="worker")
