"""``sdc-serve``: the inference service under uvicorn. Flags override ``SDCNET_*`` variables.

The camera file, the model and the targets are loaded before the server starts, so a missing
or broken file is one clear line and exit status 2, not a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import uvicorn
from pydantic import ValidationError

from sdcnet.calibration import CalibrationError
from sdcnet.cli import add_debug_flag, run_command
from sdcnet.runtime.interface import ModelLoadError
from sdcnet.service.app import create_app, load_model
from sdcnet.service.budget import budget
from sdcnet.service.camera import configured_camera
from sdcnet.service.inference import choose_frame_budget
from sdcnet.service.pose import configured_targets
from sdcnet.service.protocol import with_head_timeout
from sdcnet.service.settings import Settings
from sdcnet.targets import TargetError

logger = logging.getLogger("sdcnet.service")

#: flag, setting, type; each setting is also the environment variable SDCNET_<SETTING>.
FLAGS = [
    ("--model", "model_path", Path),
    ("--runtime", "runtime", str),
    ("--provider", "provider", str),
    ("--threads", "threads", int),
    ("--frame-ms", "frame_ms", float),
    ("--budget-window", "budget_window", int),
    ("--work-pixels", "work_pixels", int),
    ("--targets", "targets", Path),
    ("--camera", "camera", Path),
    ("--spin-wait", "spin_wait", str),  # true / false, parsed by the settings
    ("--host", "host", str),
    ("--port", "port", int),
    ("--max-in-flight", "max_in_flight", int),
    ("--max-requests", "max_requests", int),
    ("--queue-timeout", "queue_timeout_s", float),
    ("--retry-after", "retry_after_s", int),
    ("--max-pixels", "max_pixels", int),
    ("--max-points", "max_points", int),
    ("--max-returns", "max_returns", int),
    ("--max-upload-bytes", "max_upload_bytes", int),
    ("--body-timeout", "body_timeout_s", float),
    ("--min-rate", "min_rate", float),
    ("--request-timeout", "request_timeout_s", float),
    ("--head-timeout", "head_timeout_s", float),
    ("--keep-alive", "keep_alive_s", int),
    ("--log-level", "log_level", str),
]


#: Bytes of a request head at most (uvicorn's h11_max_incomplete_event_size, its default made
#: explicit): a head is a few hundred bytes; a larger one gets 400 from uvicorn.
MAX_HEAD_BYTES = 16 * 2**10


def connection_limits(settings: Settings) -> dict:
    """uvicorn's arguments for how connections are held: the head deadline of
    ``sdcnet.service.protocol`` (uvicorn has none), its own keep-alive timeout and head size
    bound, and no ``Server`` header (it names the software to a client that has no use for
    it)."""
    return {
        "http": with_head_timeout(settings.head_timeout_s),
        "timeout_keep_alive": settings.keep_alive_s,
        "h11_max_incomplete_event_size": MAX_HEAD_BYTES,
        "server_header": False,
    }


def _help(setting: str) -> str:
    """The setting's description, its default and its environment variable."""
    field = Settings.model_fields[setting]
    plain_default = field.default_factory is None and field.default is not None
    default = f" (default: {field.default})" if plain_default else ""
    return f"{field.description}{default} [SDCNET_{setting.upper()}]"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sdc-serve",
        description="Serve SDCNet depth completion over HTTP (FastAPI; onnxruntime unless "
        "--runtime says otherwise). Flags override the environment variables named in brackets.",
    )
    for flag, setting, kind in FLAGS:
        p.add_argument(flag, dest=setting, type=kind, help=_help(setting))
    add_debug_flag(p)
    return p


def invalid_settings(exc: ValidationError) -> str:
    """One line naming each invalid setting, the value given, its flag and variable."""
    flags = {setting: flag for flag, setting, _ in FLAGS}
    return "; ".join(
        f"{name} = {error['input']!r} ({flags.get(name, '')}, SDCNET_{name.upper()}): "
        f"{error['msg']}"
        for error in exc.errors(include_url=False)
        for name in [".".join(str(part) for part in error["loc"])]
    )


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_command("sdc-serve", lambda: serve(args), {}, args.debug)


def serve(args: argparse.Namespace) -> int:
    """Load the camera, the model and the targets, then serve until stopped; 2 with one line
    for a bad setting or file. Started by ``sdcnet.service.launch``, which sets up the
    allocator before anything else is imported."""
    given = {setting: getattr(args, setting) for _, setting, _ in FLAGS}
    try:
        settings = Settings(**{k: v for k, v in given.items() if v is not None})
    except ValidationError as exc:
        print(f"sdc-serve: invalid setting: {invalid_settings(exc)}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        camera = configured_camera(settings)
        model = load_model(settings)
        frame_budget = choose_frame_budget(model, settings.work_pixels, settings.frame_ms)
        targets = configured_targets(settings)
    except (CalibrationError, ModelLoadError, TargetError) as exc:
        print(f"sdc-serve: {exc}", file=sys.stderr)
        return 2
    logger.info("execution provider: %s (%d threads)", model.provider, model.threads)
    logger.info(budget(settings).describe(settings))
    try:
        uvicorn.run(
            create_app(settings, model, targets, camera, frame_budget),
            host=settings.host,
            port=settings.port,
            log_level=settings.log_level,
            timeout_graceful_shutdown=10,
            **connection_limits(settings),
        )
    except SystemExit as exc:  # uvicorn exits 3 when it cannot listen (its log says why)
        if exc.code:
            print(
                f"sdc-serve: cannot serve on {settings.host}:{settings.port} (see the error "
                "above), exiting",
                file=sys.stderr,
            )
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
