"""Robot drivers: the plug-in interface, the lookup by name, and the built-in `standin` robot.

A driver NAME resolves, in order, to:
1. a built-in driver (`standin`, or `recording`, a logging wrapper around another);
2. an installed plug-in: an entry point named NAME in the group ``handful.drivers``;
3. an import path ``package.module:factory``.
The factory (usually the driver class) is called with the ``--driver-option KEY=VALUE`` pairs
as string keyword arguments and must return an object with the `Driver` interface.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

from app.workers.drivers.base import (
    Driver,
    DriverCommand,
    DriverError,
    Execution,
    SampleCallback,
    TipTracking,
    TrackingSample,
)

ENTRY_POINT_GROUP = "handful.drivers"
BUILTIN_DRIVERS: dict[str, str] = {
    "standin": "app.workers.drivers.standin:StandinDriver",
    "recording": "app.workers.drivers.recording:RecordingDriver",
}

__all__ = [
    "BUILTIN_DRIVERS",
    "ENTRY_POINT_GROUP",
    "Driver",
    "DriverCommand",
    "DriverError",
    "Execution",
    "SampleCallback",
    "TipTracking",
    "TrackingSample",
    "available_drivers",
    "load_driver",
]


def _import_target(target: str) -> Callable[..., Any]:
    module_name, _, attr = target.partition(":")
    if not module_name or not attr:
        raise DriverError(f"driver path {target!r} must look like 'package.module:factory'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise DriverError(f"cannot import driver module {module_name!r}: {exc}") from None
    try:
        obj = module
        for part in attr.split("."):
            obj = getattr(obj, part)
    except AttributeError:
        raise DriverError(f"module {module_name!r} has no driver factory {attr!r}") from None
    if not callable(obj):
        raise DriverError(f"driver factory {target!r} is not callable")
    return obj


def available_drivers() -> dict[str, str]:
    """Name → target of every built-in and installed driver."""
    found = dict(BUILTIN_DRIVERS)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(ep.name, ep.value)
    return found


def resolve_driver(name: str) -> Callable[..., Any]:
    """The factory behind a driver NAME (built-in, entry point, or 'module:factory')."""
    if name in BUILTIN_DRIVERS:
        return _import_target(BUILTIN_DRIVERS[name])
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name == name:
            try:
                obj = ep.load()
            except Exception as exc:
                raise DriverError(f"driver plug-in {name!r} failed to load: {exc}") from None
            return obj
    if ":" in name:
        return _import_target(name)
    known = ", ".join(sorted(available_drivers()))
    raise DriverError(
        f"unknown driver {name!r}: known drivers are {known}; "
        "or give an import path 'package.module:factory'"
    )


def load_driver(name: str, **options: str) -> Driver:
    """Build the driver NAME with string options; check it has the `Driver` interface."""
    factory = resolve_driver(name)
    try:
        driver = factory(**options)
    except TypeError as exc:
        raise DriverError(
            f"driver {name!r} rejected its options {sorted(options)}: {exc}"
        ) from None
    missing = [m for m in ("execute", "abort", "close") if not callable(getattr(driver, m, None))]
    if missing:
        raise DriverError(f"driver {name!r} lacks the method(s) {', '.join(missing)}")
    return driver
