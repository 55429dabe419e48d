"""The service's routes, one router per file: probes (liveness, readiness, metrics), model
metadata, ``POST /complete`` and ``POST /pose``."""

from sdcnet.service.routes import complete, model, pose, probes

ROUTERS = (probes.router, model.router, complete.router, pose.router)
