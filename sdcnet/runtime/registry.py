"""The inference runtimes by name, as the service's ``runtime`` setting (``sdc-serve
--runtime``, ``SDCNET_RUNTIME``) chooses one.

Each entry names the module and the ``Loader`` (``sdcnet.runtime.interface``) in it, imported
only when that runtime is chosen: a runtime's package (onnxruntime, OpenVINO, TensorRT) is
needed where it runs, not where another one does. A new runtime is a module beside
``sdcnet.runtime.onnx`` and one line here.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from sdcnet.runtime.interface import Loader, Runtime

#: runtime name -> (module, its Loader's name)
RUNTIMES: dict[str, tuple[str, str]] = {
    "onnxruntime": ("sdcnet.runtime.onnx", "OnnxModel"),
}
DEFAULT_RUNTIME = "onnxruntime"


def loader(name: str) -> Loader:
    """The loader of the runtime ``name`` (a key of ``RUNTIMES``), its module imported now."""
    module, attribute = RUNTIMES[name]
    return getattr(importlib.import_module(module), attribute)


def load_runtime(
    name: str, path: str | Path, provider: str | None, threads: int | None, spin_wait: bool
) -> Runtime:
    """The model file ``path`` loaded under the runtime ``name`` (``Loader``'s arguments)."""
    return loader(name)(path, provider, threads, spin_wait)
