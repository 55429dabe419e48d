"""``python -m benchmarks.hostile``: see ``benchmarks.hostile.run``."""

from benchmarks.hostile.run import main

if __name__ == "__main__":
    raise SystemExit(main())
