"""I: ``sdc-serve`` started on broken targets folders (bad manifests, paths out of the folder,
meshes with no area)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from benchmarks.hostile.client import Context, Outcome
from tests.support.targets import probe_mesh, write_targets


def broken_targets(kind: str) -> Callable[[Context], Outcome]:
    """``sdc-serve --targets`` on a folder broken as ``kind`` says: it must stop with exit
    status 2 and one line, loading nothing from outside the folder."""

    def attack(ctx: Context) -> Outcome:
        folder = targets_folder(ctx.work / f"targets-{kind}", kind)
        command = [sys.executable, "-m", "sdcnet.service", "--model", str(ctx.model)]
        command += ["--targets", str(folder), "--host", "127.0.0.1", "--port", "0"]
        log = ctx.work / f"serve-{kind}.log"
        start = time.perf_counter()
        with log.open("w") as out:
            process = subprocess.Popen(command, stdout=out, stderr=out)
        started = False
        while process.poll() is None and time.perf_counter() - start < 120:
            if "Uvicorn running" in log.read_text():
                started = True
                break
            time.sleep(0.2)
        process.kill()
        process.wait()
        seconds = time.perf_counter() - start
        if started:
            return Outcome("started and served (took the manifest as it is)", seconds, False)
        text = log.read_text()
        lines = text.strip().splitlines()
        last = lines[-1] if lines else ""
        ok = process.returncode == 2 and "Traceback" not in text and last.startswith("sdc-serve:")
        return Outcome(f"exit {process.returncode}: {last[:160]}", seconds, ok)

    return attack


def targets_folder(folder: Path, kind: str) -> Path:
    """A targets folder broken as ``kind`` says (one mesh, ``probe.stl``)."""
    folder.mkdir(parents=True, exist_ok=True)
    write_targets(folder, {"probe": (probe_mesh(), 6.3)})
    elsewhere = folder.parent / "elsewhere.stl"
    probe_mesh().export(elsewhere)
    entry: dict = {"file": "probe.stl", "longest_m": 6.3}
    manifest: object = [entry]
    if kind == "file_not_text":
        entry["file"] = 5
    elif kind == "file_outside":
        entry["file"] = "../elsewhere.stl"
    elif kind == "symlink_outside":
        (folder / "link.stl").symlink_to(elsewhere)
        entry["file"] = "link.stl"
    elif kind == "longest_true":
        entry["longest_m"] = True
    elif kind == "longest_infinite":
        (folder / "manifest.json").write_text('[{"file": "probe.stl", "longest_m": 1e999}]')
        return folder
    elif kind == "longest_nan":
        (folder / "manifest.json").write_text('[{"file": "probe.stl", "longest_m": NaN}]')
        return folder
    elif kind == "degenerate_mesh":
        (folder / "flat.stl").write_text(
            "solid flat\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
            "vertex 2 0 0\nendloop\nendfacet\nendsolid flat\n"
        )
        entry["file"] = "flat.stl"
    elif kind == "manifest_not_a_list":
        manifest = entry
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder
