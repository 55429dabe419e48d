"""Fuzz the service's HTTP API from its own OpenAPI schema with schemathesis (bounded).

    python -m benchmarks.fuzz --max-examples 500 [--model PATH] [--seed 0]

Starts the real service (``sdc-serve`` on 127.0.0.1, a free port; the shipped model, else
SDCNet with random weights; one known target for ``POST /pose``), reads its ``/openapi.json``
and runs schemathesis's examples, coverage (boundary values and each kind of invalid input the
schema implies) and fuzzing phases on every operation, ``--max-examples`` cases per operation
and phase, with all its checks: no 5xx, statuses, content types, headers and bodies as the
schema says, schema-invalid requests refused, schema-valid ones accepted (positive
``POST /complete`` and ``POST /pose`` cases carry a real frame:
``tests.support.fuzzing.real_files_for_valid_cases``), unexpected methods answered 405.

Prints the statuses per operation and every failure with a curl command that reproduces it;
exit status 1 on any failure. ``tests/test_fuzz.py`` runs the same with a few examples.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from tests.support.fuzzing import fuzz_api, fuzz_targets
from tests.support.serving import temporary_service


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--max-examples", type=int, default=200, help="per operation and phase")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    args = p.parse_args(argv)

    with tempfile.TemporaryDirectory() as work:
        flags = ("--threads=2", "--max-pixels=1048576", f"--targets={fuzz_targets(Path(work))}")
        with temporary_service(args.model, *flags) as (service, name):
            print(f"fuzzing {service.url} ({name}), {args.max_examples} examples, seed {args.seed}")
            report = fuzz_api(service.url, args.max_examples, args.seed)
    print(report.summary())
    return 1 if report.failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
