"""The service's routes, one router per file: probes (liveness, readiness, metrics), model
metadata, ``POST /complete``, the Open Inference Protocol's ``POST /v2/models/sdcnet/infer``
and ``POST /pose``."""

from sdcnet.service.routes import complete, model, pose, probes, v2_infer

ROUTERS = (probes.router, model.router, complete.router, v2_infer.router, pose.router)
