"""The test suite, a package so that its modules and ``tests.support`` have one name wherever
they are imported from: pytest (its default ``prepend`` import mode puts the repository root,
the first folder above without an ``__init__.py``, on ``sys.path``) and ``python -m
benchmarks.NAME`` run from the repository root."""
