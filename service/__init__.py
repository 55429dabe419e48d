"""The inference service: POST /complete on onnxruntime."""
