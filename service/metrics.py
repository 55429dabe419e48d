"""Prometheus metrics, named after NVIDIA Triton's ``nv_inference_*`` with an ``sdcnet_`` prefix.

The ``sdcnet_inference_*`` metrics count the inference requests: those of every route that
takes an inference slot (``sdcnet.service.admission.TAKES_SLOT``: ``POST /complete``, ``POST
/v2/models/sdcnet/infer``, ``POST /pose``), which the admission middleware sees end.

- ``sdcnet_inference_request_success_total``: answered 2xx;
- ``sdcnet_inference_request_failure_total{reason}``: answered otherwise; ``reason`` is the
  error code of the JSON answer (``overloaded``, ``too_large``, ``no_returns``...);
- ``sdcnet_inference_request_duration_seconds``: successful requests, first byte in to last
  byte out;
- ``sdcnet_inference_phase_duration_seconds{phase}``: decode / queue / inference / encode (and
  the phases of a route's own, ``POST /pose``'s cloud and registration);
- ``sdcnet_inference_pending_requests``: requests admitted and not yet answered;
- ``sdcnet_model_info{version, provider, threads, work_pixels}``;
- ``sdcnet_frame_share``: the share of their budget frames get now
  (``sdcnet.frame_budget.ServedBudget``); and the process collector's ``process_*`` (CPU
  seconds, resident memory, open files).

Each application gets its own registry, so that two apps in one process do not collide.
"""

from __future__ import annotations

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    Info,
    ProcessCollector,
    disable_created_metrics,
    generate_latest,
)

#: Seconds; dense around the 100 ms budget of a 1024 x 1024 frame.
LATENCY_BUCKETS = (
    0.001,
    0.0025,
    0.005,
    0.01,
    0.025,
    0.05,
    0.075,
    0.1,
    0.15,
    0.25,
    0.5,
    1.0,
    2.5,
    5.0,
    10.0,
)

CONTENT_TYPE = CONTENT_TYPE_LATEST


class ServiceMetrics:
    """The service's metrics in their own registry."""

    def __init__(self) -> None:
        disable_created_metrics()  # no *_created series: noise to operators (process-wide)
        self.registry = CollectorRegistry()
        ProcessCollector(registry=self.registry)
        self.success = Counter(
            "sdcnet_inference_request_success",
            "Inference requests (every route that takes an inference slot) answered with 2xx",
            registry=self.registry,
        )
        self.failure = Counter(
            "sdcnet_inference_request_failure",
            "Inference requests answered otherwise, by error code",
            ["reason"],
            registry=self.registry,
        )
        self.request_duration = Histogram(
            "sdcnet_inference_request_duration_seconds",
            "Successful inference requests, first byte in to last byte out",
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.phase_duration = Histogram(
            "sdcnet_inference_phase_duration_seconds",
            "Successful inference requests by phase: decode, queue, inference, encode, and "
            "those of a route's own",
            ["phase"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.pending = Gauge(
            "sdcnet_inference_pending_requests",
            "Inference requests admitted and not yet answered",
            registry=self.registry,
        )
        self.model = Info("sdcnet_model", "The loaded model", registry=self.registry)
        self.frame_share = Gauge(
            "sdcnet_frame_share",
            "The share of their budget frames get now (GET /model's frame_budget)",
            registry=self.registry,
        )

    def observe_phases(self, seconds: dict[str, float]) -> None:
        for phase, value in seconds.items():
            self.phase_duration.labels(phase).observe(value)

    def render(self) -> bytes:
        """The text exposition format."""
        return generate_latest(self.registry)
