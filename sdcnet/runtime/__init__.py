"""The exported model under an inference runtime. No torch.

- ``sdcnet.runtime.interface``: what every runtime shares and imports no runtime: the tensors,
  the file's metadata (``metadata_props``, ``ModelInfo``), the ``Runtime`` the service runs;
- ``sdcnet.runtime.registry``: the runtimes by name (the service's ``runtime`` setting), each
  imported only when chosen;
- ``sdcnet.runtime.onnx``: onnxruntime's (``OnnxModel``, execution providers).

Used by the service, the evaluation of exported files and the benchmarks.
"""
