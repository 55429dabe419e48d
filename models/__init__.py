"""The shipped model (sdcnet.onnx) and its model card, found with importlib.resources."""
