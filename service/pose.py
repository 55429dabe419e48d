"""One ``POST /pose``: the frame completed as ``POST /complete`` completes it, then the
known target registered to the completed cloud (``sdcnet.registration``), in a worker thread.

decode (``service.decode.decode_form``: the same form, sparse map or returns list, as
``POST /complete``, then ``service.camera.camera_frame``) -> queue -> inference -> cloud
(``service.inference.complete_frame``, the path every protocol shares, then the LIDAR returns
back-projected too) -> registration. The target and ``init`` are checked before any image is
decoded.

The registration gets the points it can trust: those whose sigma (the depth's 1-sigma
uncertainty) is within the request's ``max_sigma`` when it gives one, else within the
frame's own ``POSE_SIGMA_QUANTILE`` of sigma, so that the most uncertain tenth (flying pixels
between surfaces, far from any return) leaves the cloud whatever the scale of the frame. The
LIDAR returns, measured, are all used.
"""

from __future__ import annotations

import json
import logging
import re
import time
from dataclasses import dataclass

import numpy as np
from fastapi.responses import JSONResponse

from sdcnet.pointcloud import POSE_SIGMA_QUANTILE, back_project
from sdcnet.registration import PoseEstimate, UnusableCloudError, estimate_pose
from sdcnet.rigid import Pose, parse_pose
from sdcnet.service.camera import ServiceCamera, camera_frame
from sdcnet.service.decode import CompletionRequest, InputLimits, decode_form
from sdcnet.service.errors import ApiError
from sdcnet.service.inference import Answer, Engine, PhaseTimer, complete_frame
from sdcnet.service.pose_schemas import PoseAlternative, PoseResponse, PoseTimings, PoseValue
from sdcnet.service.schemas import FrameSummary
from sdcnet.service.settings import Settings
from sdcnet.service.spool import Spool
from sdcnet.targets import Target, load_targets

logger = logging.getLogger("sdcnet.service")


def configured_targets(settings: Settings) -> dict[str, Target]:
    """The targets of ``settings.targets`` (none when unset), prepared and logged; raises
    ``sdcnet.targets.TargetError`` with the reason."""
    if settings.targets is None:
        return {}
    started = time.perf_counter()
    targets = load_targets(settings.targets)
    logger.info(
        "%d targets from %s prepared in %.1f s: %s",
        len(targets),
        settings.targets,
        time.perf_counter() - started,
        ", ".join(f"{t.name} ({t.longest_m:.1f} m)" for t in targets.values()),
    )
    return targets


@dataclass(frozen=True)
class PoseRequest:
    frame: CompletionRequest
    target: str
    init: str | None = None  # JSON of a previous answer's `pose`


def find_target(targets: dict[str, Target], name: str) -> Target:
    """The named target, or 404 ``unknown_target`` (no such target here) listing the known
    ones."""
    if name in targets:
        return targets[name]
    known = ", ".join(sorted(targets)) or "none (start sdc-serve with --targets DIR)"
    raise ApiError(404, "unknown_target", f"unknown target {name!r}; known targets: {known}")


#: Longest ``init`` read, characters: a pose as the service writes it takes about 600.
MAX_INIT_CHARS = 16 * 2**10
#: Deepest nesting of ``init``: a pose's rotation matrix is a list of lists in an object (3).
MAX_INIT_DEPTH = 4
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')


def read_init(text: str | None) -> Pose | None:
    """``init`` as a pose, or 422 ``invalid_init`` saying what is wrong with it; its length
    and nesting are checked before it is parsed."""
    if text is None:
        return None
    if len(text) > MAX_INIT_CHARS:
        raise ApiError(
            422,
            "invalid_init",
            f"init holds {len(text)} characters, more than the {MAX_INIT_CHARS} a pose needs",
        )
    if _depth(text) > MAX_INIT_DEPTH:
        raise ApiError(
            422,
            "invalid_init",
            f"init is nested more than {MAX_INIT_DEPTH} levels deep: a pose is "
            '{"R": 3 x 3, "t": 3} or {"quaternion_wxyz": 4, "t": 3}',
        )
    try:  # integers read as floats: a 5000-digit one is infinite, and refused as such
        value = json.loads(text, parse_int=float, parse_constant=_not_a_number)
    except json.JSONDecodeError as exc:
        raise ApiError(
            422,
            "invalid_init",
            f"init is not valid JSON (line {exc.lineno}, column {exc.colno})",
        ) from None
    except ValueError as exc:
        raise ApiError(422, "invalid_init", f"init: {exc}") from None
    try:
        return parse_pose(value)
    except ValueError as exc:
        raise ApiError(422, "invalid_init", f"init: {exc}") from None


def _depth(text: str) -> int:
    """How deep the arrays and objects of JSON ``text`` nest (its strings skipped)."""
    depth = deepest = 0
    for char in _JSON_STRING.sub('""', text):
        if char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def _not_a_number(name: str) -> float:
    raise ValueError(f"{name} is not a number of JSON")


def _pose_value(pose: Pose) -> PoseValue:
    return PoseValue(**pose.as_dict())


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def pose_response(
    target: Target,
    estimate: PoseEstimate,
    completion: FrameSummary,
    sigma_limit: float | None,
    timer: PhaseTimer,
) -> PoseResponse:
    covariance = estimate.covariance
    finite = bool(np.all(np.isfinite(covariance)))
    return PoseResponse(
        target=target.name,
        pose=_pose_value(estimate.pose),
        tracked=estimate.tracked,
        verdict=estimate.verdict,
        reasons=estimate.reasons,
        fitness=estimate.fitness,
        rmse_m=_finite(estimate.rmse_m),
        returns_rmse_m=None
        if estimate.returns_rmse_m is None
        else _finite(estimate.returns_rmse_m),
        consistency=estimate.consistency,
        converged=estimate.converged,
        covariance=covariance.tolist() if finite else None,
        rotation_sigma_deg=_finite(estimate.rotation_sigma_deg) if finite else None,
        translation_sigma_m=_finite(estimate.translation_sigma_m) if finite else None,
        ambiguous=estimate.ambiguous,
        alternatives=[
            PoseAlternative(
                pose=_pose_value(h.pose),
                consistency=h.consistency,
                returns_error_m=_finite(h.returns_error_m),
            )
            for h in estimate.alternatives
        ],
        hypotheses=estimate.hypotheses,
        sigma_limit_m=sigma_limit,
        completion=completion,
        timings=PoseTimings(
            **timer.milliseconds(POSE_PHASES),
            search_ms=estimate.timings_ms.get("search_ms", 0.0),
            registration_cpu_ms=estimate.timings_ms["cpu_ms"],
        ),
    )


POSE_PHASES = ("decode", "queue", "inference", "cloud", "registration")


def answer_pose(
    engine: Engine,
    targets: dict[str, Target],
    req: PoseRequest,
    limits: InputLimits,
    camera: ServiceCamera | None = None,
) -> Answer:
    """Check, complete (in the ``camera``'s frame), register one request, its answer a
    ``PoseResponse`` as JSON; raises ``ApiError`` for bad input."""
    target = find_target(targets, req.target)
    init = read_init(req.init)
    timer = PhaseTimer()
    with timer("decode"):
        frame = camera_frame(decode_form(req.frame, limits), camera)
    done = complete_frame(
        engine, frame, timer, cloud_phase="cloud", sigma_quantile=POSE_SIGMA_QUANTILE
    )
    with timer("cloud"):
        used = done.completion.used_returns  # the completion's, its strays left out
        returns = back_project(used, used > 0, done.intrinsics)
    with timer("registration"):
        try:
            estimate = estimate_pose(target.model, done.points, returns, init, done.intrinsics)
        except UnusableCloudError as exc:
            raise ApiError(
                422, exc.code, f"the completed cloud cannot be registered to {target.name}: {exc}"
            ) from exc
    completion = done.frame_summary(engine.model)
    response = pose_response(target, estimate, completion, done.sigma_limit, timer)
    spool = Spool()
    spool.write(JSONResponse(response.model_dump()).body)  # Starlette's JSON rendering
    return Answer(spool, timer, media_type="application/json", phases=POSE_PHASES)
