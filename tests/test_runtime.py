"""sdcnet.runtime: execution providers named short or in full, the model's info from its
metadata, the interface imported without onnxruntime, and the service running any ``Runtime``
(it reads the runtime's platform, not onnxruntime's), chosen by its ``runtime`` setting."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError

from sdcnet.runtime.interface import ModelInfo, ModelLoadError, metadata_props
from sdcnet.runtime.onnx import OnnxModel, choose_providers, provider_name
from sdcnet.runtime.registry import RUNTIMES
from sdcnet.service.app import create_app
from sdcnet.service.settings import Settings

ACCELERATED = [
    "TensorrtExecutionProvider",
    "OpenVINOExecutionProvider",
    "CUDAExecutionProvider",
    "CPUExecutionProvider",
]


@pytest.mark.parametrize(
    ("requested", "name"),
    [
        ("cpu", "CPUExecutionProvider"),
        ("cuda", "CUDAExecutionProvider"),
        ("tensorrt", "TensorrtExecutionProvider"),
        ("TensorRT", "TensorrtExecutionProvider"),
        ("openvino", "OpenVINOExecutionProvider"),
        ("TensorrtExecutionProvider", "TensorrtExecutionProvider"),
        ("openvinoexecutionprovider", "OpenVINOExecutionProvider"),
        ("CPUExecutionProvider", "CPUExecutionProvider"),
    ],
)
def test_a_provider_is_chosen_by_its_short_or_full_name(monkeypatch, requested, name):
    monkeypatch.setattr("sdcnet.runtime.onnx.ort.get_available_providers", lambda: ACCELERATED)
    assert provider_name(requested) == name
    assert choose_providers(requested) == [name]


def test_an_unavailable_provider_is_refused_in_either_form(monkeypatch):
    monkeypatch.setattr("sdcnet.runtime.onnx.ort.get_available_providers", lambda: ACCELERATED[3:])
    for requested in ("tensorrt", "TensorrtExecutionProvider", "no-such-runtime"):
        with pytest.raises(ModelLoadError, match="is not available here"):
            choose_providers(requested)
    assert choose_providers() == ["CPUExecutionProvider"]


class OtherRuntime:
    """A runtime other than onnxruntime, as the service sees one
    (``sdcnet.runtime.interface.Runtime``): here the tiny ONNX model under another platform's
    name."""

    platform = "openvino"

    def __init__(self, model: OnnxModel):
        self.path, self.info, self.threads = model.path, model.info, model.threads
        self.provider, self.stride, self.run = "CPU", model.stride, model.run


def test_the_service_serves_any_runtime_and_reports_its_platform(tiny_model_path):
    model = OtherRuntime(OnnxModel(tiny_model_path, provider="cpu", threads=1))
    with TestClient(create_app(Settings(model_path=tiny_model_path), model)) as http:
        described = http.get("/model").json()
    assert (described["platform"], described["provider"]) == ("openvino", "CPU")


def other_runtime(
    path: str | Path, provider: str | None, threads: int | None, spin_wait: bool
) -> OtherRuntime:
    """``OtherRuntime``'s loader (``sdcnet.runtime.interface.Loader``)."""
    return OtherRuntime(OnnxModel(path, "cpu", threads, spin_wait))


def test_the_runtime_setting_chooses_the_runtime_from_the_registry(monkeypatch, tiny_model_path):
    monkeypatch.setitem(RUNTIMES, "other", ("tests.test_runtime", "other_runtime"))
    monkeypatch.setenv("SDCNET_RUNTIME", "other")
    settings = Settings(model_path=tiny_model_path, threads=1)
    with TestClient(create_app(settings)) as http:  # the app loads the model itself
        described = http.get("/model").json()
    assert (described["platform"], described["provider"]) == ("openvino", "CPU")


def test_an_unknown_runtime_is_an_invalid_setting():
    with pytest.raises(ValidationError, match=r"not a runtime here.*'onnxruntime'"):
        Settings(runtime="tensorrt")


def test_the_model_info_comes_from_the_files_metadata_whatever_the_runtime():
    path = Path("model.bin")
    info = ModelInfo.from_metadata(metadata_props("m-1", stride=16, factor=2), path)
    assert (info.version, info.stride, info.factor) == ("m-1", 16, 2)
    with pytest.raises(ModelLoadError, match="not an sdcnet model: metadata lacks"):
        ModelInfo.from_metadata({"sdcnet_version": "0"}, path)
    broken = {**metadata_props("m-1", stride=16), "stride": "sixteen"}
    with pytest.raises(ModelLoadError, match="not a usable sdcnet model: its metadata does not"):
        ModelInfo.from_metadata(broken, path)


def test_the_runtime_interface_and_registry_import_no_onnxruntime():
    code = (
        "import sys\n"
        "sys.modules['onnxruntime'] = None  # any import of it fails\n"
        "import sdcnet.runtime.interface, sdcnet.runtime.registry, sdcnet.service.settings\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
