"""Shared fixtures: a migrated SQLite file, users with tokens, and a real uvicorn server.

Everything is real: the database is built by running the Alembic migrations, the server is a
uvicorn subprocess on a free 127.0.0.1 port, and tests talk to it through ``app.client``.

Fixtures (reuse them; they are documented for the workers and dashboard tests):

- ``migrated_db(tmp_path) -> str``: SQLAlchemy URL of a fresh, migrated SQLite file.
- ``server_factory(**options) -> ServerHandle``: start a server over a fresh data folder
  (users ``operator``/``viewer``/``worker`` with tokens in ``handle.tokens``); options:
  ``env={"HANDFUL_LEASE_SECONDS": "2", ...}``, ``dashboard=False``, ``use_cli=False``
  (``True`` starts it with ``handful serve``, migrations included). The handle can
  ``kill9()``, ``stop()``, ``start()`` (same data folder and port) and make clients.
  All servers are killed at the end of the test.
- ``live_server``: one server shared by the whole session (dashboard off, 60 s leases).
  Tests sharing it must create their own experiments and never assume global counts; they
  must not claim trials (workers would take other tests' queued trials): use
- ``module_server``: one server per test module, configured by the module's ``SERVER_ENV``
  (and ``SERVER_DASHBOARD``) globals; for worker/lease tests.
- ``api`` / ``viewer_api`` / ``worker_api`` / ``anon_api``: ``HandfulClient`` on
  ``live_server`` with the operator / viewer / worker token / no token.
- ``new_exp(client, **fields)``: an experiment through the API (module defaults: ``NEW_EXP``).
- ``hw_exp(client, **fields)``: a hardware throw experiment through the API (``HW_THROW``).
- ``error_of(call, *args, **kwargs)``: the ``HandfulAPIError`` a client call raises.
- ``db``, ``make_experiment``, ``make_trial``: the service layer over a migrated SQLite file.
- ``sweep_both_ways(specs, workers)``: a sweep run on the local backend and on a local Ray.
- ``dashboard_server``, ``browser``, ``page``, ``screenshots``: the dashboard and Chromium.
"""

from __future__ import annotations

import shutil
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from app.client import HandfulAPIError, HandfulClient
from app.db.migrate import upgrade
from app.db.models import Trial
from app.db.session import Database
from app.devserver import ServerProcess, free_port
from app.service import experiments, trials
from app.service.auth import Actor, add_user, create_token
from app.service.schemas import ExperimentCreate

ROLES = ("operator", "viewer", "worker")
#: the tests' hardware limits: 100 kPa nominal ± 30 kPa, 205 kPa supply
HARDWARE_LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}
#: ``hw_exp``'s experiment: a hardware throw scored in metres (the tape), P = 3, two random
#: initial trials, the fast simulator preset for its previews
HW_THROW = {
    "name": "hw",
    "task": "throw",
    "target": "hardware",
    "levels": 3,
    "n_initial": 2,
    "sim_preset": "fast",
    "objective_unit": "m",
    "limits": HARDWARE_LIMITS,
}
OPERATOR = Actor("olivia", "operator")  # the actor the service-level factories act as
PASSWORD = "correct horse battery"  # every fixture user's password


def sqlite_url(path: Path) -> str:
    return f"sqlite:///{path.resolve()}"


def make_migrated_db(data_dir: Path) -> str:
    """Run the migrations on ``data_dir/handful.db``; return its URL."""
    data_dir.mkdir(parents=True, exist_ok=True)
    url = sqlite_url(data_dir / "handful.db")
    upgrade(url)
    return url


def seed_users(url: str) -> dict[str, str]:
    """Users named after their role (password ``PASSWORD``), one token each: role → token."""
    db = Database(url)
    tokens = {}
    try:
        with db.write() as s:
            for role in ROLES:
                add_user(s, role, role, password=PASSWORD)
                tokens[role] = create_token(s, role, label="tests")
    finally:
        db.dispose()
    return tokens


@dataclass
class ServerHandle(ServerProcess):
    """A ``ServerProcess`` over a migrated SQLite file, with users and their tokens."""

    tokens: dict[str, str] = field(default_factory=dict)
    _clients: list[HandfulClient] = field(default_factory=list)

    @property
    def db_url(self) -> str:
        return sqlite_url(self.data_dir / "handful.db")

    def client(self, role: str | None = "operator", **kwargs: object) -> HandfulClient:
        """A client with ``role``'s token (None: no token). Closed at teardown."""
        c = HandfulClient(self.url, self.tokens[role] if role else None, **kwargs)  # type: ignore[arg-type]
        self._clients.append(c)
        return c

    def close(self) -> None:
        for c in self._clients:
            c.close()
        self.stop(kill=False)


def claim_until_empty(handle: ServerHandle, n_workers: int, target: str = "sim") -> list[int]:
    """``n_workers`` threads, each with its own worker client, claim 2 trials at a time until
    none is left; the ids of every trial handed out (a trial handed out twice appears twice)."""
    got: list[int] = []
    lock = threading.Lock()

    def claim_all(i: int) -> None:
        c = handle.client("worker")
        while claims := c.claim(f"w{i}", target, max_trials=2):
            with lock:
                got.extend(x["trial"]["id"] for x in claims)

    threads = [threading.Thread(target=claim_all, args=(i,)) for i in range(n_workers)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    return got


def _new_server(
    root: Path, *, env: dict[str, str] | None, dashboard: bool, use_cli: bool
) -> ServerHandle:
    data_dir = root / "data"
    url = make_migrated_db(data_dir)
    tokens = seed_users(url)
    full_env = {
        "HANDFUL_DASHBOARD_ENABLED": "1" if dashboard else "0",
        "HANDFUL_LEASE_SWEEP_INTERVAL_S": "0.5",
        **(env or {}),
    }
    handle = ServerHandle(
        data_dir=data_dir, port=free_port(), tokens=tokens, env=full_env, use_cli=use_cli
    )
    handle.start()
    return handle


@pytest.fixture(scope="session")
def _migrated_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One SQLite file migrated to head per session; tests get copies of it."""
    data_dir = tmp_path_factory.mktemp("template")
    make_migrated_db(data_dir)
    return data_dir / "handful.db"


@pytest.fixture
def migrated_db(tmp_path: Path, _migrated_template: Path) -> str:
    """URL of a fresh SQLite file built by running the migrations (a copy of one per session)."""
    data_dir = tmp_path / "data"
    data_dir.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(_migrated_template, data_dir / "handful.db")
    return sqlite_url(data_dir / "handful.db")


@pytest.fixture
def server_factory(tmp_path: Path) -> Iterator[Callable[..., ServerHandle]]:
    """Start servers on demand (each over its own data folder); all stopped at teardown."""
    handles: list[ServerHandle] = []

    def factory(
        *, env: dict[str, str] | None = None, dashboard: bool = False, use_cli: bool = False
    ) -> ServerHandle:
        root = tmp_path / f"server{len(handles)}"
        handle = _new_server(root, env=env, dashboard=dashboard, use_cli=use_cli)
        handles.append(handle)
        return handle

    yield factory
    for h in handles:
        h.close()


@pytest.fixture(scope="session")
def live_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerHandle]:
    """One server for the session (dashboard off)."""
    handle = _new_server(tmp_path_factory.mktemp("live"), env=None, dashboard=False, use_cli=False)
    yield handle
    handle.close()


@pytest.fixture(scope="module")
def module_server(
    tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Iterator[ServerHandle]:
    """A server for one test module; the module's ``SERVER_ENV`` dict (if any) sets its env,
    e.g. ``SERVER_ENV = {"HANDFUL_LEASE_SECONDS": "2"}``; ``SERVER_DASHBOARD = True``."""
    handle = _new_server(
        tmp_path_factory.mktemp("module"),
        env=getattr(request.module, "SERVER_ENV", None),
        dashboard=getattr(request.module, "SERVER_DASHBOARD", False),
        use_cli=False,
    )
    yield handle
    handle.close()


@pytest.fixture
def api(live_server: ServerHandle) -> HandfulClient:
    """Operator client on the shared server."""
    return live_server.client("operator")


@pytest.fixture
def viewer_api(live_server: ServerHandle) -> HandfulClient:
    return live_server.client("viewer")


@pytest.fixture
def worker_api(live_server: ServerHandle) -> HandfulClient:
    return live_server.client("worker")


@pytest.fixture
def anon_api(live_server: ServerHandle) -> HandfulClient:
    return live_server.client(None)


@pytest.fixture
def op(module_server: ServerHandle) -> HandfulClient:
    """The operator's client on this module's ``module_server``."""
    return module_server.client("operator")


@pytest.fixture
def worker(module_server: ServerHandle) -> HandfulClient:
    """A worker's client on this module's ``module_server``."""
    return module_server.client("worker")


@pytest.fixture
def new_exp(request: pytest.FixtureRequest) -> Callable[..., dict]:
    """``new_exp(client, **fields)``: create an experiment through the API and return it: a
    sim tip_speed experiment with P = 3 and random search, named "exp", updated by the test
    module's ``NEW_EXP`` dict (e.g. ``{"sim_preset": "fast"}``), then by ``fields``. A
    hardware experiment without limits gets ``HARDWARE_LIMITS``."""
    module_defaults = getattr(request.module, "NEW_EXP", {})

    def make(client: HandfulClient, **fields: object) -> dict:
        spec = {"name": "exp", "task": "tip_speed", "levels": 3, "method": "random"}
        spec = {**spec, **module_defaults, **fields}
        if spec.get("target") == "hardware":
            spec.setdefault("limits", HARDWARE_LIMITS)
        return client.create_experiment(**spec)

    return make


@pytest.fixture
def hw_exp() -> Callable[..., dict]:
    """``hw_exp(client, **fields)``: create ``HW_THROW`` updated by ``fields`` through the
    API and return it."""

    def make(client: HandfulClient, **fields: object) -> dict:
        return client.create_experiment(**{**HW_THROW, **fields})

    return make


@pytest.fixture
def error_of() -> Callable[..., HandfulAPIError]:
    """``error_of(call, *args, **kwargs)``: call a client method that must be refused and
    return its ``HandfulAPIError`` (the test fails if the call succeeds)."""

    def refused(call: Callable[..., Any], *args: Any, **kwargs: Any) -> HandfulAPIError:
        with pytest.raises(HandfulAPIError) as info:
            call(*args, **kwargs)
        return info.value

    return refused


@pytest.fixture
def db(migrated_db: str) -> Iterator[Database]:
    """The service's Database over a freshly migrated SQLite file."""
    database = Database(migrated_db)
    yield database
    database.dispose()


@pytest.fixture
def make_experiment(db: Database) -> Callable[..., int]:
    """Create an experiment (sim tip_speed, P=3, random search by default); returns its id."""

    def factory(**fields: Any) -> int:
        spec = {"name": "test", "task": "tip_speed", "levels": 3, "method": "random", **fields}
        if spec.get("target") == "hardware" and "limits" not in spec:
            spec["limits"] = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0}
        with db.write() as s:
            return experiments.create_experiment(s, ExperimentCreate(**spec), actor=OPERATOR).id

    return factory


@pytest.fixture
def make_trial(db: Database) -> Callable[..., int]:
    """Attach a trial with θ (default all 0.5) and force its status; returns its id."""

    def factory(experiment_id: int, status: str | None = None, theta: Any = None) -> int:
        with db.write() as s:
            exp = experiments.get_experiment(s, experiment_id)
            t = trials.attach(s, experiment_id, theta or [0.5] * exp.dim, note="", actor=OPERATOR)
        if status is not None:
            with db.write() as s:
                row = s.get(Trial, t.id)
                assert row is not None
                row.status = status
        return t.id

    return factory


@pytest.fixture
def sweep_both_ways(tmp_path: Path) -> Callable[..., tuple[dict, dict]]:
    """``sweep_both_ways(specs, workers)``: ``app.bench.run_sweep`` the specs on the local
    backend (``workers`` processes, into tmp_path/local), then on a local Ray with 2 CPUs
    (into tmp_path/ray, shut down after); returns (local, ray) rows per spec."""

    def run(specs: list[Any], workers: int) -> tuple[dict, dict]:
        import ray

        from app import bench

        local = bench.run_sweep(specs, tmp_path / "local", workers=workers, progress=False)
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        try:
            remote = bench.run_sweep(specs, tmp_path / "ray", backend="ray", progress=False)
        finally:
            ray.shutdown()
        return local, remote

    return run


# --- the dashboard and headless Chromium (tests/web, tests/viz) ---------------------------------
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
SCREENSHOTS = Path(__file__).resolve().parents[1] / "test-output" / "screenshots"


@pytest.fixture
def dashboard_server_factory(server_factory: Callable[..., Any]) -> Callable[..., Any]:
    """Start servers with the dashboard mounted and viser on a free loopback port."""

    def start(**env: str) -> Any:
        return server_factory(dashboard=True, env={"HANDFUL_VISER_PORT": str(free_port()), **env})

    return start


@pytest.fixture
def dashboard_server(dashboard_server_factory: Callable[..., Any]) -> Any:
    """A server with the dashboard mounted and viser on its own free loopback port."""
    return dashboard_server_factory()


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """Headless Debian Chromium driven by Playwright (no browser download)."""
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        raise RuntimeError(f"{CHROMIUM} is missing: apt-get install -y chromium (scripts/dev.sh)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    """A fresh 1280×800 tab (own storage); page errors fail the test at teardown."""
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    tab = context.new_page()
    errors: list[str] = []
    tab.on("pageerror", lambda exc: errors.append(str(exc)))
    tab.set_default_timeout(60_000)  # a loaded 2-core CI machine renders slowly
    yield tab
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


@pytest.fixture(scope="session")
def screenshots() -> Path:
    """Where page screenshots go (look at them: passing is not looking right)."""
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS
