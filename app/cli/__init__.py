"""The ``handful`` command line. Each sub-module registers its own commands on the root app."""

from __future__ import annotations

import importlib

import typer

app = typer.Typer(
    name="handful",
    help="Learn dynamic soft-arm skills in a handful of trials (BayesOpt, human in the loop).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

# Sub-modules, each exposing ``register(app: typer.Typer) -> None``.
_COMMAND_MODULES = ("sim", "bench", "serve", "users", "worker", "demo", "backup")


@app.callback()
def _root() -> None:
    """handful: BayesOpt with a person in the loop, for a pneumatic soft arm."""


@app.command()
def version() -> None:
    """Print handful's version."""
    from importlib.metadata import version as _v

    typer.echo(_v("handful"))


for _name in _COMMAND_MODULES:
    importlib.import_module(f"app.cli.{_name}").register(app)


def main() -> None:
    """Console-script entry point."""
    app()
