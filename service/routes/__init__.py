"""The service's routes, one router per file: probes (liveness, readiness, metrics), model
metadata, and ``POST /complete``."""

from sdcnet.service.routes import complete, model, probes

ROUTERS = (probes.router, model.router, complete.router)
