"""What the tests and the benchmarks share: starting ``sdc-serve`` in a subprocess, frames and
multipart bodies, small ONNX models, known targets and their frames for the pose tests, the
schemathesis driver, hostile clients.

Not part of the runtime: nothing in ``sdcnet``, ``training``, ``export``, ``service`` or
``client`` imports it (``tests/test_imports.py``), and the wheel does not install it
(``tests/test_wheel.py``). The benchmarks import it from the repository root
(``python -m benchmarks.NAME``), never a test module.
Each module needs only the runtime extras (``serve``, ``client``) at import, so that ``make
test-runtime`` (no torch) can use it; what needs more is imported where it is used and says
which extra brings it: ``onnx`` for the tiny model (the ``test-runtime`` and ``train`` extras),
torch for the random-weights model (``train``), the generator for rendered frames (``data``),
schemathesis for fuzzing (``test-runtime``, ``dev``).
"""
