"""Hostile and careless clients against the real service (``python -m benchmarks.hostile``;
the run, its verdicts and its report: ``run``).

- ``client``: the limits, the running service's context, the requests attacks are made of.
- ``connections``: A, uploads that trickle; F, requests never finished; K1, answers never read.
- ``memory``: B, the largest inputs and answers; C, long CSV files.
- ``inputs``: D, E, H, K2, K3, values the parsers must refuse; J, what the answers say.
- ``overload``: G, more clients than the service serves.
- ``targets``: I, ``sdc-serve`` on broken targets folders.
- ``catalogue``: ``ATTACKS``, every attack by key, what it sends and what must happen.
- ``run``: starts the service, runs the attacks in turn, writes the report.
"""
