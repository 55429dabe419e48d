"""Start-up faults of ``sdc-serve``: a missing, empty, truncated or non-ONNX model file, an ONNX
file that is not an sdcnet model (or only looks like one), an execution provider that is not
there, a bad setting, a busy port, a targets folder whose manifest is wrong. Each must end the
process with a non-zero status and one clear line on stderr, never a traceback and never a
service that is up but cannot serve.

All cases start at once (one subprocess each, real ``python -m sdcnet.service``) in one
module fixture, so the whole file costs about one start-up.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import onnx
import onnxruntime as ort
import pytest
import trimesh
from onnx import TensorProto, helper

from tests.support.models import graph_model

_MISSING_PROVIDER = next(
    name
    for name in ("cuda", "tensorrt", "rocm", "openvino")
    if f"{name.upper()}ExecutionProvider".lower()
    not in {p.lower() for p in ort.get_available_providers()}
)


@dataclass(frozen=True)
class Outcome:
    returncode: int
    stderr: str

    @property
    def last_line(self) -> str:
        lines = self.stderr.strip().splitlines()
        return lines[-1] if lines else ""


def model_files(base: Path, good: Path) -> dict[str, Path]:
    """The broken model files in ``base``, made from the ``good`` (tiny) sdcnet model."""
    data = good.read_bytes()
    metadata = {p.key: p.value for p in onnx.load(good).metadata_props}
    files = {
        "truncated": data[: len(data) // 2],
        "empty": b"",
        "not_onnx": b"# a text file with a .onnx name\n" * 20,
    }
    paths = {}
    for name, content in files.items():
        paths[name] = base / f"{name}.onnx"
        paths[name].write_bytes(content)
    paths["directory"] = base / "directory.onnx"
    paths["directory"].mkdir(exist_ok=True)
    identity = helper.make_node("Identity", ["x"], ["y"])
    paths["not_sdcnet"] = base / "identity.onnx"
    onnx.save(graph_model([identity], ("x",), ("y",)), paths["not_sdcnet"])
    # sdcnet's names and metadata, but intrinsics that are not JSON
    paths["broken_metadata"] = base / "broken-metadata.onnx"
    broken = onnx.load(good)
    next(p for p in broken.metadata_props if p.key == "intrinsics").value = "{not json"
    onnx.save(broken, paths["broken_metadata"])
    # sdcnet's names and metadata on a graph that reshapes every frame to 7 x 7: it loads,
    # and would fail every request
    paths["impostor"] = base / "impostor.onnx"
    nodes = [
        helper.make_node("Reshape", ["gray", "shape"], ["depth"]),
        helper.make_node("Identity", ["sparse"], ["foreground"]),
        helper.make_node("Identity", ["sparse"], ["sigma"]),
    ]
    seven = helper.make_tensor("shape", TensorProto.INT64, [4], [1, 1, 7, 7])
    onnx.save(graph_model(nodes, metadata=metadata, initializers=(seven,)), paths["impostor"])
    paths["good"] = good
    return paths


def target_folders(base: Path) -> dict[str, Path]:
    """Targets folders of one mesh, each broken one way: the folder's key is
    ``targets_<way>``."""
    mesh = trimesh.creation.box((2.0, 1.0, 0.5))
    outside = base / "outside.stl"
    mesh.export(outside)
    folders = {}
    ways = {
        "file_not_text": [{"file": 5}],
        "outside": [{"file": "../outside.stl"}],
        "link_out": [{"file": "link.stl"}],
        "longest_true": [{"file": "box.stl", "longest_m": True}],
        "flat_mesh": [{"file": "flat.stl"}],
    }
    for way, manifest in ways.items():
        folder = base / f"targets-{way}"
        folder.mkdir(exist_ok=True)
        mesh.export(folder / "box.stl")
        (folder / "flat.stl").write_text(
            "solid flat\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
            "vertex 2 0 0\nendloop\nendfacet\nendsolid flat\n"
        )
        if way == "link_out" and not (folder / "link.stl").exists():
            (folder / "link.stl").symlink_to(outside)
        (folder / "manifest.json").write_text(json.dumps(manifest))
        folders[f"targets_{way}"] = folder
    return folders


#: case -> (model file, more flags, environment, what the last line of stderr says); "{model}",
#: "{absent}" (a path with no file) and "{busy_port}" are filled in when the case starts.
CASES: dict[str, tuple[str | None, list[str], dict[str, str], str]] = {
    "missing_file_by_environment": (
        None,
        [],
        {"SDCNET_MODEL_PATH": "{absent}"},
        "sdc-serve: model file not found: {absent}",
    ),
    "directory": ("directory", [], {}, "sdc-serve: {model} is a directory, not an ONNX model"),
    "empty_file": ("empty", [], {}, "sdc-serve: cannot load {model} as an ONNX model"),
    "truncated_onnx": ("truncated", [], {}, "sdc-serve: cannot load {model} as an ONNX model"),
    "not_onnx": ("not_onnx", [], {}, "sdc-serve: cannot load {model} as an ONNX model"),
    "onnx_but_not_sdcnet": ("not_sdcnet", [], {}, "{model} is not an sdcnet model: metadata"),
    "sdcnet_metadata_that_does_not_parse": (
        "broken_metadata",
        [],
        {},
        "{model} is not a usable sdcnet model: its metadata does not parse",
    ),
    "sdcnet_lookalike_that_cannot_run": (
        "impostor",
        [],
        {},
        "{model} loads but cannot complete a 64 x 64 test frame",
    ),
    "unavailable_provider_flag": (
        "good",
        ["--provider", _MISSING_PROVIDER],
        {},
        f"sdc-serve: execution provider '{_MISSING_PROVIDER}' is not available here",
    ),
    "unavailable_provider_environment": (
        "good",
        [],
        {"SDCNET_PROVIDER": "NoSuchExecutionProvider"},
        "execution provider 'NoSuchExecutionProvider' is not available here",
    ),
    "invalid_setting": ("good", [], {"SDCNET_MAX_IN_FLIGHT": "0"}, "sdc-serve: invalid setting"),
    "busy_port": ("good", ["--port", "{busy_port}"], {}, "sdc-serve: cannot serve on"),
    "more_working_pixels_than_the_models": (
        "good",
        ["--work-pixels", "1000000000"],
        {},
        "work_pixels must be between 1 and the model's",
    ),
    # targets manifests: types checked, files of the folder only (a crash with exit 70, and
    # meshes loaded from outside the folder, before), no mesh without area
    "targets_file_not_text": (
        "good",
        ["--targets", "{targets_file_not_text}"],
        {},
        "'file' must be a file name, got 5",
    ),
    "targets_outside_the_folder": (
        "good",
        ["--targets", "{targets_outside}"],
        {},
        "../outside.stl lies outside the folder",
    ),
    "targets_link_out_of_the_folder": (
        "good",
        ["--targets", "{targets_link_out}"],
        {},
        "link.stl lies outside the folder",
    ),
    "targets_longest_true": (
        "good",
        ["--targets", "{targets_longest_true}"],
        {},
        "longest_m must be a positive number of metres, got True",
    ),
    "targets_flat_mesh": ("good", ["--targets", "{targets_flat_mesh}"], {}, "is degenerate"),
}


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory, tiny_model_path) -> dict[str, tuple[Outcome, str]]:
    """Start every case at once; (outcome, expected message) per case."""
    base = tmp_path_factory.mktemp("faults")
    paths = model_files(base, tiny_model_path)
    folders = target_folders(base)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        started = {}
        for name, (model, flags, env, expected) in CASES.items():
            values = {
                "model": paths.get(model, ""),
                "absent": paths["good"].parent / "absent.onnx",
                "busy_port": busy.getsockname()[1],
                **folders,
            }
            command = [sys.executable, "-m", "sdcnet.service", "--host", "127.0.0.1"]
            command += ["--model", str(values["model"])] if model else []
            command += [flag.format(**values) for flag in flags]
            process = subprocess.Popen(
                command,
                env={**os.environ, **{k: v.format(**values) for k, v in env.items()}},
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )
            started[name] = (process, expected.format(**values))
        finished = {}
        for name, (process, expected) in started.items():
            try:
                _, stderr = process.communicate(timeout=120)
            except subprocess.TimeoutExpired:  # it started serving: the fault was missed
                process.kill()
                _, stderr = process.communicate()
            finished[name] = (Outcome(process.returncode, stderr), expected)
    return finished


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_start_up_fault_exits_non_zero_with_one_clear_line(outcomes, case):
    outcome, expected = outcomes[case]
    assert outcome.returncode != 0, outcome.stderr
    assert expected in outcome.last_line, outcome.stderr
    assert outcome.last_line.startswith("sdc-serve: ")
    assert "Traceback" not in outcome.stderr
    if case == "busy_port":  # the model loads, then uvicorn cannot listen: its status 3
        assert "address already in use" in outcome.stderr and outcome.returncode == 3
    else:  # refused before the server starts
        assert outcome.returncode == 2 and "Uvicorn running" not in outcome.stderr
