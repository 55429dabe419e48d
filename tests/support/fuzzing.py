"""The HTTP API fuzzed from its own OpenAPI schema with schemathesis (``tests/test_fuzz.py``,
``benchmarks/fuzz.py``). Needs schemathesis (the ``test-runtime`` and ``dev`` extras)."""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute

from sdcnet.camera import PAPER_CAMERA, Intrinsics, IntrinsicsError, check_intrinsics
from sdcnet.formats.v2 import HEADER_LENGTH
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense
from sdcnet.service.admission import slot_routes
from sdcnet.service.forms import frame_form
from sdcnet.service.routes import ROUTERS
from tests.support.frames import png_bytes, v2_inputs
from tests.support.targets import write_targets

V2_INFER = "POST /v2/models/sdcnet/infer"
POSE = "POST /pose"
FUZZ_TARGET = "box"  # the target fuzz_targets() writes


def _operations(routes: list[APIRoute]) -> frozenset[str]:
    """schemathesis's names of the routes' operations ("POST /complete")."""
    return frozenset(f"{method} {route.path}" for route in routes for method in route.methods)


def _takes_frame_form(dependant: Dependant) -> bool:
    return any(sub.call is frame_form or _takes_frame_form(sub) for sub in dependant.dependencies)


#: The service's inference operations, those that take an inference slot (``TAKES_SLOT``): each
#: must answer the fuzzer's valid cases, read from the routes so that a new one is fuzzed as
#: such without a list to edit here.
INFERENCE_OPERATIONS = _operations(list(slot_routes(ROUTERS)))
#: The operations whose body is one frame's form (``sdcnet.service.forms.FrameForm``): their
#: valid cases get a real frame (``real_files_for_valid_cases``).
FRAME_FORM_OPERATIONS = _operations(
    [
        route
        for router in ROUTERS
        for route in router.routes
        if isinstance(route, APIRoute) and _takes_frame_form(route.dependant)
    ]
)


def fuzz_targets(folder: Path) -> Path:
    """A targets folder of one small box (``FUZZ_TARGET``, 2 m), for ``sdc-serve --targets``:
    the fuzzed service's ``POST /pose`` then has a target to register."""
    return write_targets(folder, {FUZZ_TARGET: (trimesh.creation.box((2.0, 1.0, 0.5)), None)})


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


def fuzz_arrays() -> tuple[np.ndarray, np.ndarray]:
    """A valid 64 x 64 frame: a bright gray gradient (uint8 128-254: foreground to the tiny
    model, so that ``POST /pose`` gets a cloud) and 256 returns at 100-115 m (dense)."""
    gray = (128 + np.add.outer(np.arange(64), np.arange(64))).astype(np.uint8)
    sparse = np.zeros((64, 64), np.float32)
    sparse[::4, ::4] = 100 + np.arange(256, dtype=np.float32).reshape(16, 16) / 16
    return gray, sparse


def fuzz_frame(depth_scale: float | None, as_returns: bool = False) -> dict[str, bytes]:
    """``fuzz_arrays`` as the files of POST /complete: gray PNG and the returns as a ``.npy``
    map or, when ``depth_scale`` (metres per unit) is given, a 16-bit PNG; or, ``as_returns``,
    a ``.npy`` list (field ``returns``)."""
    gray, sparse = fuzz_arrays()
    if as_returns:
        return {"gray": png_bytes(gray), "returns": npy_bytes(returns_from_dense(sparse))}
    if depth_scale is None:
        return {"gray": png_bytes(gray), "sparse": npy_bytes(sparse)}
    units = np.clip(np.round(sparse / depth_scale), 0, 65535).astype(np.uint16)
    units[::4, ::4] = np.maximum(units[::4, ::4], 1)  # a return stays a return at any scale
    return {"gray": png_bytes(gray), "sparse": png_bytes(units)}


def fuzz_inputs(binary: bool) -> tuple[list[dict], bytes]:
    """``fuzz_arrays`` as the inputs of POST /v2/models/sdcnet/infer (``v2_inputs``)."""
    gray, sparse = fuzz_arrays()
    return v2_inputs(gray, returns_from_dense(sparse), binary)


def real_files_for_valid_cases(context, case, kwargs: dict) -> None:
    """schemathesis ``before_call`` hook: a positive (schema-valid) inference case is sent
    with a real frame in place of its generated images and tensors.

    The schema can say that ``gray`` and ``sparse`` are files, not that they are a decodable
    image and a depth map of the same size (nor that a form gives one of ``sparse`` and
    ``returns``); it can say that v2 inputs are tensors, not which names, shapes and bytes make
    a frame (nor that an output is asked for once). Without this, every "valid" case would be
    refused (rightly) and the positive_data_acceptance check would test nothing. Every other
    field keeps its generated value (intrinsics, depth_scale, outlier_removal, format; the v2
    request's id, parameters and outputs), intrinsics only where they fit the frame
    (``_fitting_intrinsics``); so for every operation that takes a frame's form
    (``FRAME_FORM_OPERATIONS``). ``POST /pose`` takes that form and more: its valid cases also
    name the fuzzed service's target (``fuzz_targets``), send a pose as ``init`` when they send
    one, and keep the frame's own intrinsics and depths (see ``_pose_fields``). The frame goes
    in the transport's arguments, so the case itself (and its positive label) is left as
    generated. Negative cases are sent as generated.
    """
    meta = case.meta
    if meta is None or meta.generation.mode.value != "positive":
        return
    operation = f"{case.method.upper()} {case.path}"
    if operation in FRAME_FORM_OPERATIONS and isinstance(case.body, dict):
        fields = {k: v for k, v in case.body.items() if k not in ("gray", "sparse", "returns")}
        fields = _pose_fields(fields) if operation == POSE else _fitting_intrinsics(fields)
        as_returns = "returns" in case.body and "sparse" not in case.body
        frame = fuzz_frame(fields.get("depth_scale"), as_returns and "depth_scale" not in fields)
        kwargs["files"] = {name: (f"{name}.bin", data) for name, data in frame.items()}
        kwargs["data"] = {k: v if isinstance(v, str) else json.dumps(v) for k, v in fields.items()}
    elif operation == V2_INFER and isinstance(case.body, dict):
        body = {**case.body, "inputs": fuzz_inputs(binary=False)[0]}
        if isinstance(body.get("parameters"), dict):
            body["parameters"] = _fitting_intrinsics(body["parameters"])
        if body.get("outputs") is not None:
            once = {output["name"]: output for output in reversed(body["outputs"])}
            body["outputs"] = list(reversed(once.values())) or None
        kwargs["json"] = body
    elif operation == V2_INFER:  # the binary form: a JSON header, then the tensors' bytes
        inputs, binary = fuzz_inputs(binary=True)
        header = json.dumps({"inputs": inputs}).encode()
        kwargs["data"] = header + binary
        # (the transport takes headers from the case only; an undeclared header keeps it valid)
        case.headers = {**(case.headers or {}), HEADER_LENGTH: str(len(header))}


INTRINSICS = ("fx", "fy", "cx", "cy")


def _fitting_intrinsics(fields: dict) -> dict:
    """A valid case's fields without its intrinsics when they cannot describe the fuzzed
    64 x 64 frame (``sdcnet.camera.check_intrinsics``, the model's camera for those not
    given): the schema states the bounds that do not depend on the frame's size only, so a
    focal length of 1e-300 px or one pixel is schema-valid, and rightly refused (422)."""
    default = PAPER_CAMERA.intrinsics().scaled(64, 64)
    given = {k: fields.get(k, getattr(default, k)) for k in INTRINSICS}
    try:
        check_intrinsics(Intrinsics(**{k: float(v) for k, v in given.items()}, width=64, height=64))
    except (IntrinsicsError, TypeError, ValueError):
        return {k: v for k, v in fields.items() if k not in INTRINSICS}
    return fields


def _pose_fields(fields: dict) -> dict:
    """A valid ``POST /pose`` case's other fields: the known target, a pose as ``init`` (when
    one is sent), and none of the intrinsics, ``depth_scale`` or ``max_sigma``. The schema
    cannot say that a focal length of 1e-300 px, or a depth scale of 1e-6 m per unit on depths
    of 100 m, turn the frame into a cloud light-years wide or millimetres small, nor that a
    max_sigma of 1e-300 m leaves no point in it, which ``/pose`` refuses (422) where
    ``/complete`` completes it."""
    dropped = ("fx", "fy", "cx", "cy", "depth_scale", "max_sigma")
    kept = {k: v for k, v in fields.items() if k not in dropped}
    kept["target"] = FUZZ_TARGET
    if "init" in kept:
        kept["init"] = json.dumps({"R": np.eye(3).tolist(), "t": [0.0, 0.0, 100.0]})
    return kept


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
