"""sdcnet.runtime: execution providers named short or in full, and the service running any
``Runtime`` (it reads the runtime's platform, not onnxruntime's)."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from sdcnet.runtime import ModelLoadError, OnnxModel, choose_providers, provider_name
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
    monkeypatch.setattr("sdcnet.runtime.ort.get_available_providers", lambda: ACCELERATED)
    assert provider_name(requested) == name
    assert choose_providers(requested) == [name]


def test_an_unavailable_provider_is_refused_in_either_form(monkeypatch):
    monkeypatch.setattr("sdcnet.runtime.ort.get_available_providers", lambda: ACCELERATED[3:])
    for requested in ("tensorrt", "TensorrtExecutionProvider", "no-such-runtime"):
        with pytest.raises(ModelLoadError, match="is not available here"):
            choose_providers(requested)
    assert choose_providers() == ["CPUExecutionProvider"]


class OtherRuntime:
    """A runtime other than onnxruntime, as the service sees one (``sdcnet.runtime.Runtime``):
    here the tiny ONNX model under another platform's name."""

    platform = "openvino"

    def __init__(self, model: OnnxModel):
        self.path, self.info, self.threads = model.path, model.info, model.threads
        self.provider, self.stride, self.run = "CPU", model.stride, model.run


def test_the_service_serves_any_runtime_and_reports_its_platform(tiny_model_path):
    model = OtherRuntime(OnnxModel(tiny_model_path, provider="cpu", threads=1))
    with TestClient(create_app(Settings(model_path=tiny_model_path), model)) as http:
        described = http.get("/model").json()
    assert (described["platform"], described["provider"]) == ("openvino", "CPU")
