"""The HTTP API fuzzed from its own OpenAPI schema with schemathesis (``tests/test_fuzz.py``,
``benchmarks/fuzz.py``). Needs schemathesis (the ``test-runtime`` and ``dev`` extras)."""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from sdcnet.devtools.frames import png_bytes
from sdcnet.npyio import npy_bytes

COMPLETE = "POST /complete"


@dataclass
class FuzzReport:
    """What a schemathesis run did: statuses per operation, failures (check, message, curl)."""

    statuses: dict[str, dict[int | None, int]]
    failures: list[str]
    seconds: float

    @property
    def requests(self) -> int:
        return sum(sum(counts.values()) for counts in self.statuses.values())

    def summary(self) -> str:
        """A markdown table of statuses per operation, then the failures."""
        codes = sorted({c for counts in self.statuses.values() for c in counts}, key=str)
        lines = [
            "| operation | requests | " + " | ".join(str(c) for c in codes) + " |",
            "|---|---|" + "---|" * len(codes),
        ]
        for operation, counts in sorted(self.statuses.items()):
            cells = " | ".join(str(counts.get(c, 0)) for c in codes)
            lines.append(f"| {operation} | {sum(counts.values())} | {cells} |")
        lines.append(
            f"\n{self.requests} requests in {self.seconds:.1f} s, {len(self.failures)} failures"
        )
        return "\n".join(lines + self.failures)


def fuzz_frame(depth_scale: float | None) -> dict[str, bytes]:
    """A valid 64 x 64 frame for POST /complete: a gray gradient and 256 returns at 100-115 m,
    as a ``.npy`` or, when ``depth_scale`` (metres per unit) is given, a 16-bit PNG."""
    gray = np.add.outer(np.arange(64), np.arange(64)).astype(np.uint8)
    sparse = np.zeros((64, 64), np.float32)
    sparse[::4, ::4] = 100 + np.arange(256, dtype=np.float32).reshape(16, 16) / 16
    if depth_scale is None:
        return {"gray": png_bytes(gray), "sparse": npy_bytes(sparse)}
    units = np.clip(np.round(sparse / depth_scale), 0, 65535).astype(np.uint16)
    units[::4, ::4] = np.maximum(units[::4, ::4], 1)  # a return stays a return at any scale
    return {"gray": png_bytes(gray), "sparse": png_bytes(units)}


def real_files_for_valid_cases(context, case, kwargs: dict) -> None:
    """schemathesis ``before_call`` hook: a positive (schema-valid) ``POST /complete`` case is
    sent with a real frame in place of its generated ``gray`` and ``sparse`` bytes.

    The schema can say that both are files, not that they are a decodable image and a depth
    map of the same size; without this, every "valid" case would be refused (rightly) and the
    positive_data_acceptance check would test nothing. Every other field keeps its generated
    value (intrinsics, depth_scale, outlier_removal, format). The frame goes in the transport's
    ``files`` and ``data``, so the case itself (and its positive label) is left as generated.
    Negative cases are sent as generated.
    """
    meta = case.meta
    positive = meta is not None and meta.generation.mode.value == "positive"
    if f"{case.method.upper()} {case.path}" != COMPLETE or not positive:
        return
    if not isinstance(case.body, dict):
        return
    fields = {k: v for k, v in case.body.items() if k not in ("gray", "sparse")}
    frame = fuzz_frame(fields.get("depth_scale"))
    kwargs["files"] = {name: (f"{name}.bin", data) for name, data in frame.items()}
    kwargs["data"] = {k: v if isinstance(v, str) else json.dumps(v) for k, v in fields.items()}


def fuzz_api(url: str, max_examples: int, seed: int = 0) -> FuzzReport:
    """Run schemathesis (examples, coverage and fuzzing phases, every check) on every
    operation of the service at ``url``, from its /openapi.json; ``max_examples`` per
    operation and phase. Leaves nothing in the working directory."""
    import hypothesis.configuration
    import schemathesis
    from schemathesis.engine import events, from_schema
    from schemathesis.hooks import GLOBAL_HOOK_DISPATCHER

    config = schemathesis.Config.from_dict(
        {
            "seed": seed,
            "cache": {"enabled": False},
            "workers": 1,
            "continue-on-failure": True,
            "generation": {"max-examples": max_examples, "database": "none"},
        }
    )
    statuses: dict[str, dict[int | None, int]] = {}
    failures: list[str] = []
    start = time.monotonic()
    hook = schemathesis.hook("before_call")(real_files_for_valid_cases)
    try:
        with tempfile.TemporaryDirectory() as home:
            hypothesis.configuration.set_hypothesis_home_dir(home)
            schema = schemathesis.openapi.from_url(f"{url}/openapi.json", config=config)
            for event in from_schema(schema).execute():
                if isinstance(event, events.ScenarioFinished):
                    _record(event.recorder, statuses, failures)
                elif isinstance(event, events.NonFatalError | events.FatalError):
                    failures.append(f"- error: {event}")
    finally:
        GLOBAL_HOOK_DISPATCHER.unregister(hook)
    return FuzzReport(statuses, failures, time.monotonic() - start)


def _record(recorder, statuses: dict, failures: list[str]) -> None:
    counts = statuses.setdefault(recorder.label, {})
    for interaction in recorder.interactions.values():
        status = interaction.response.status_code if interaction.response else None
        counts[status] = counts.get(status, 0) + 1
    for checks in recorder.checks.values():
        for check in checks:
            if check.failure_info is not None:
                failure = check.failure_info.failure
                failures.append(
                    f"- {recorder.label}: {check.name}: {failure.title}: {failure.message}\n"
                    f"  {check.failure_info.code_sample}"
                )
