"""What the tests and the benchmarks share: starting ``sdc-serve`` in a subprocess, frames and
multipart bodies, small ONNX models, known targets and their frames for the pose tests, the
schemathesis driver.

Not part of the runtime: nothing in ``sdcnet``, ``service`` or ``client`` imports it. It lives in
the package (rather than in ``tests/``) so that ``python -m benchmarks.NAME``, the tests and
``docker/`` import one copy from anywhere, and a benchmark never depends on the test suite.
Each module needs only the runtime extras (``serve``, ``client``) at import; what needs more is
imported where it is used and says which extra brings it: ``onnx`` for the tiny model (the
``test-runtime`` and ``train`` extras), torch for the random-weights model (``train``), the
generator for rendered frames (``data``), schemathesis for fuzzing (``test-runtime``, ``dev``).
"""
