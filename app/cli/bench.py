"""`handful bench ...`: benchmark scripts behind one command group."""

from __future__ import annotations

import typer

from app.cli import bench_optim, bench_paper, bench_sim

bench_app = typer.Typer(help="Benchmarks; numbers go to docs/BENCHMARKS.md.", no_args_is_help=True)
bench_sim.register(bench_app)
bench_optim.register(bench_app)
bench_paper.register(bench_app)


def register(app: typer.Typer) -> None:
    """Add the `bench` group to the root app."""
    app.add_typer(bench_app, name="bench")
