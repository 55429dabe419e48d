"""The HTTP API fuzzed from its own OpenAPI schema (schemathesis), bounded: the real service in
a subprocess, every operation through schemathesis's coverage and fuzzing phases with all its
checks (no 5xx, responses as the schema says, invalid requests refused, valid ones accepted).
``python -m benchmarks.fuzz --max-examples N`` runs the same for longer."""

from __future__ import annotations

import httpx
import pytest

from tests.support.fuzzing import INFERENCE_OPERATIONS, fuzz_api, fuzz_targets
from tests.support.serving import running_service

MAX_EXAMPLES = 40  # per operation and phase: about 150 requests, a few seconds


@pytest.fixture(scope="module")
def url(tmp_path_factory, tiny_model_path):
    log = tmp_path_factory.mktemp("fuzz") / "serve.log"
    targets = fuzz_targets(tmp_path_factory.mktemp("targets"))
    flags = ("--max-pixels=1048576", "--body-timeout=5", f"--targets={targets}")
    with running_service(tiny_model_path, log, *flags) as address:
        yield address


def test_the_api_passes_every_schemathesis_check(url):
    report = fuzz_api(url, MAX_EXAMPLES, seed=0)
    assert not report.failures, report.summary()
    assert len(INFERENCE_OPERATIONS) >= 3  # /complete, v2 infer and /pose at least
    for operation in INFERENCE_OPERATIONS:  # every route that takes an inference slot
        statuses = report.statuses[operation]
        assert statuses.get(200, 0) >= 10, report.summary()  # valid frames were answered
        assert sum(n for status, n in statuses.items() if 400 <= status < 500) >= 30
        assert all(status is not None and status < 500 for status in statuses), report.summary()
    schema = httpx.get(f"{url}/openapi.json").json()
    operations = {
        f"{method.upper()} {path}" for path, item in schema["paths"].items() for method in item
    }
    assert set(report.statuses) == operations  # every operation of the schema was fuzzed
