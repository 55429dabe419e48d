"""``sdc-serve``: the inference service under uvicorn. Flags override ``SDCNET_*`` variables.

The model is loaded before the server starts, so a missing or broken file is one clear line
and exit status 2, not a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import uvicorn
from pydantic import ValidationError

from sdcnet.export.runtime import ModelLoadError
from sdcnet.service.app import create_app, load_model
from sdcnet.service.settings import Settings

logger = logging.getLogger("sdcnet.service")


#: flag, setting, type; each setting is also the environment variable SDCNET_<SETTING>.
FLAGS = [
    ("--model", "model_path", Path),
    ("--provider", "provider", str),
    ("--threads", "threads", int),
    ("--host", "host", str),
    ("--port", "port", int),
    ("--max-in-flight", "max_in_flight", int),
    ("--retry-after", "retry_after_s", int),
    ("--max-pixels", "max_pixels", int),
    ("--max-upload-bytes", "max_upload_bytes", int),
    ("--log-level", "log_level", str),
]


def _help(setting: str) -> str:
    """The setting's description, its default and its environment variable."""
    field = Settings.model_fields[setting]
    plain_default = field.default_factory is None and field.default is not None
    default = f" (default: {field.default})" if plain_default else ""
    return f"{field.description}{default} [SDCNET_{setting.upper()}]"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sdc-serve",
        description="Serve SDCNet depth completion over HTTP (FastAPI + onnxruntime). Flags "
        "override the environment variables named in brackets.",
    )
    for flag, setting, kind in FLAGS:
        p.add_argument(flag, dest=setting, type=kind, help=_help(setting))
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        settings = Settings(**{k: v for k, v in vars(args).items() if v is not None})
    except ValidationError as exc:
        print(f"sdc-serve: invalid setting: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        model = load_model(settings)
    except ModelLoadError as exc:
        print(f"sdc-serve: {exc}", file=sys.stderr)
        return 2
    logger.info("execution provider: %s (%d threads)", model.provider, model.threads)
    uvicorn.run(
        create_app(settings, model),
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
        timeout_graceful_shutdown=10,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
