"""ONNX export of SDCNet with a parity check, and the onnxruntime wrapper the service uses."""
