"""The real service in a subprocess (``python -m sdcnet.service``, i.e. ``sdc-serve``) on a free
port of 127.0.0.1, and its memory and open files read from /proc."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx

from sdcnet.service.settings import shipped_model_path

_STARTED = re.compile(r"Uvicorn running on (http://\S+)")


@dataclass(frozen=True)
class Service:
    """A running ``sdc-serve``: its base URL and the process id /proc knows it by."""

    url: str
    pid: int


@contextmanager
def service_process(model: Path, log: Path, *flags: str) -> Iterator[Service]:
    """Start ``sdc-serve`` on a free port of 127.0.0.1 with ``flags`` (after ``--threads 1``
    and ``--frame-ms 0``, which flags of their own override); yield it once ``/ready``
    answers 200; stop it afterwards. Its output goes to ``log``. ``--frame-ms 0`` keeps the
    model's own budget, so that the service answers as the in-process pipeline does on any
    machine, rather than fewer working pixels on a slow one (``sdcnet.frame_budget``)."""
    command = [sys.executable, "-m", "sdcnet.service", "--model", str(model)]
    command += ["--host", "127.0.0.1", "--port", "0", "--threads", "1", "--frame-ms", "0"]
    command += flags
    with log.open("w") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    try:
        yield Service(_wait_ready(process, log), process.pid)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@contextmanager
def running_service(model: Path, log: Path, *flags: str) -> Iterator[str]:
    """``service_process``, yielding only the URL."""
    with service_process(model, log, *flags) as service:
        yield service.url


def benchmark_model(path: Path | None, workdir: Path) -> tuple[Path, str]:
    """The model a benchmark serves, and how to name it in its report: ``path`` when given,
    else the shipped ``models/sdcnet.onnx`` when it exists, else the real architecture with
    random weights (``random_model``, needs torch), exported into ``workdir``."""
    if path is not None:
        return path, f"`{path}`"
    if shipped_model_path().exists():
        return shipped_model_path(), "the shipped `models/sdcnet.onnx`"
    from tests.support.models import random_model

    return random_model(workdir), (
        "SDCNet with random weights (`models/sdcnet.onnx` does not exist yet; the "
        "segmentation bias is raised so that the whole crop is foreground)"
    )


@contextmanager
def temporary_service(model: Path | None, *flags: str) -> Iterator[tuple[Service, str]]:
    """``service_process`` on ``benchmark_model(model)``, its log in a temporary folder; yields
    the service and the model's description."""
    with tempfile.TemporaryDirectory() as work:
        path, description = benchmark_model(model, Path(work))
        with service_process(path, Path(work) / "serve.log", *flags) as service:
            yield service, description


def memory_kib(pid: int) -> dict[str, int]:
    """Resident memory of a process from /proc/PID/status, KiB: ``rss`` (VmRSS, now) and
    ``peak`` (VmHWM, the most it ever held)."""
    fields = dict(
        line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
    )
    return {"rss": int(fields["VmRSS"].split()[0]), "peak": int(fields["VmHWM"].split()[0])}


def open_fds(pid: int) -> int:
    """File descriptors the process holds open (entries of /proc/PID/fd)."""
    return len(os.listdir(f"/proc/{pid}/fd"))


def _wait_ready(process: subprocess.Popen, log: Path, timeout_s: float = 90.0) -> str:
    deadline = time.monotonic() + timeout_s
    url = None
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the service exited with {process.returncode}:\n{log.read_text()}")
        if url is None and (found := _STARTED.search(log.read_text())):
            url = found.group(1)
        if url is not None:
            try:
                if httpx.get(f"{url}/ready", timeout=2).status_code == 200:
                    return url
            except httpx.TransportError:
                pass
        time.sleep(0.1)
    raise RuntimeError(f"the service was not ready within {timeout_s} s:\n{log.read_text()}")
