"""schemathesis over every operation of the OpenAPI document, as operator, viewer and
anonymous, with valid and invalid inputs (issue 16): no 5xx, and every reply's status code,
content type and body as the document declares. Bounded: ``HANDFUL_FUZZ_EXAMPLES``
examples per operation (20), each sent as each role.

Run alone: ``python -m pytest tests/api/test_fuzz.py -q -p no:cacheprovider``.
"""

from __future__ import annotations

import os

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from schemathesis.generation.modes import GenerationMode
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

pytestmark = pytest.mark.slow

SERVER_ENV = {"HANDFUL_LEASE_SECONDS": "60"}
EXAMPLES = int(os.environ.get("HANDFUL_FUZZ_EXAMPLES", "20"))
CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
]


def _seed(module_server) -> None:
    """Something to find: an experiment with a run trial (measurements, trajectory, audit)."""
    op = module_server.client("operator")
    exp = op.create_experiment(
        name="fuzz", task="tip_speed", levels=3, method="random", sim_preset="fast"
    )
    [trial] = op.suggest(exp["id"])
    op.run_trial(trial["id"])


def _fuzzer(operation, who: list[dict[str, str]], base_url: str):
    """A Hypothesis test sending each generated case (valid or not) as each of ``who``."""
    cases = st.one_of(
        operation.as_strategy(GenerationMode.POSITIVE),
        operation.as_strategy(GenerationMode.NEGATIVE),
    )

    @given(case=cases)
    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        derandomize=True,
        database=None,
    )
    def fuzz(case):
        for headers in who:
            case.call_and_validate(base_url=base_url, headers=headers, checks=CHECKS)

    return fuzz


def test_every_operation_keeps_its_documented_promises(module_server):
    _seed(module_server)
    schema = schemathesis.openapi.from_url(f"{module_server.url}/openapi.json")
    roles = {
        role: {"Authorization": f"Bearer {module_server.tokens[role]}"}
        for role in ("viewer", "operator")
    }
    roles["anonymous"] = {}
    failures: dict[str, str] = {}
    n_operations = 0
    for result in schema.get_all_operations():
        operation = result.ok()
        n_operations += 1
        # rotating would revoke the fixture's tokens: that route is fuzzed without one
        who = [{}] if operation.path == "/api/auth/rotate" else list(roles.values())
        fuzz = _fuzzer(operation, who, module_server.url)
        try:
            fuzz()
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # every operation's first failure, reported together
            failures[operation.label] = str(exc)[:3000]
    assert n_operations > 20
    assert not failures, "\n\n".join(f"== {k}\n{v}" for k, v in failures.items())
