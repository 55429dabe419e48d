"""deploy/: the Kubernetes manifests, validated offline against the Kubernetes API schemas
(kubernetes-validate, strict: an unknown or misplaced field fails), and held to what the image
and the service really use: the Dockerfile's port, user and health check, the settings'
SDCNET_* variables, the service's probe routes and sdc-data's own argument parser."""

from __future__ import annotations

import re
from pathlib import Path

import kubernetes_validate
import pytest
import yaml

from sdcnet.service.app import create_app
from sdcnet.service.budget import budget
from sdcnet.service.settings import Settings
from sdcnet.training.data.cli import parser as sdc_data_parser
from tests.test_docker import stages

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
KUBERNETES = kubernetes_validate.latest_version()


def documents(name: str) -> list[dict]:
    return [d for d in yaml.safe_load_all((DEPLOY / name).read_text()) if d]


def one(kind: str) -> dict:
    """The one manifest of ``kind`` in deploy/."""
    found = [d for f in sorted(DEPLOY.glob("*.yaml")) for d in documents(f.name)]
    found = [d for d in found if d.get("kind") == kind]
    assert len(found) == 1, f"{len(found)} manifests of kind {kind}"
    return found[0]


def image(stage: str) -> dict:
    """What a Dockerfile stage promises: port, user, health-check path, environment."""
    text = stages()[stage].replace("\\\n", " ")
    env = dict(re.findall(r"(\w+)=(\S+)", " ".join(re.findall(r"^ENV (.*)$", text, re.M))))
    healthcheck = re.search(r"HEALTHCHECK .*?(/v2/\S+?)'", text)
    expose = re.search(r"^EXPOSE (\d+)$", text, re.M)
    return {
        "port": int(expose.group(1)) if expose else None,
        "user": int(re.search(r"^USER (\d+):(\d+)$", text, re.M).group(1)),
        "health": healthcheck.group(1) if healthcheck else None,
        "env": env,
        "entrypoint": re.search(r'^(?:ENTRYPOINT|CMD) \["([^"]+)"', text, re.M).group(1),
    }


def pod_of(manifest: dict) -> dict:
    """The pod spec a workload manifest runs."""
    if manifest["kind"] == "InferenceService":
        return manifest["spec"]["predictor"]
    return manifest["spec"]["template"]["spec"]


CORE = [
    (f.name, d["kind"])
    for f in sorted(DEPLOY.glob("*.yaml"))
    for d in documents(f.name)
    if d.get("apiVersion", "").split("/")[0] in ("v1", "apps", "autoscaling", "batch")
]


def test_deploy_holds_the_kinds_the_cluster_needs():
    kinds = sorted(kind for _, kind in CORE)
    assert kinds == sorted(
        ["Deployment", "Service", "HorizontalPodAutoscaler", "PersistentVolumeClaim", "Job"]
    )
    assert one("InferenceService")["apiVersion"] == "serving.kserve.io/v1beta1"
    listed = documents("kustomization.yaml")[0]["resources"]
    assert listed == ["deployment.yaml", "service.yaml", "hpa.yaml"]


@pytest.mark.parametrize(("file", "kind"), CORE)
def test_core_manifests_are_valid_kubernetes(file, kind):
    for manifest in documents(file):
        if manifest["kind"] == kind:
            kubernetes_validate.validate(manifest, KUBERNETES, strict=True)


def test_a_typo_is_caught_by_the_validation():
    manifest = one("Deployment")
    manifest["spec"]["template"]["spec"]["containers"][0]["prots"] = []
    with pytest.raises(kubernetes_validate.ValidationError, match="'prots' was unexpected"):
        kubernetes_validate.validate(manifest, KUBERNETES, strict=True)


def test_the_kserve_predictor_is_a_valid_pod_spec():
    """KServe's schema is a CRD, not bundled: its predictor's pod part is checked as a Pod."""
    predictor = one("InferenceService")["spec"]["predictor"]
    pod_fields = {k: v for k, v in predictor.items() if k in ("containers", "securityContext")}
    pod = {"apiVersion": "v1", "kind": "Pod", "metadata": {"name": "sdcnet"}, "spec": pod_fields}
    kubernetes_validate.validate(pod, KUBERNETES, strict=True)
    assert [c["name"] for c in predictor["containers"]] == ["kserve-container"]


@pytest.mark.parametrize("kind", ["Deployment", "InferenceService"])
def test_ports_probes_and_user_are_the_images(kind):
    served = image("cpu")
    routes = create_app().openapi()["paths"]  # GET routes of the service
    pod = pod_of(one(kind))
    (container,) = pod["containers"]
    ports = {p.get("name"): p["containerPort"] for p in container["ports"]}
    assert list(ports.values()) == [served["port"]]
    env = {e["name"]: e["value"] for e in container["env"]}
    assert int(env["SDCNET_PORT"]) == served["port"] == int(served["env"]["SDCNET_PORT"])
    assert env["SDCNET_HOST"] == served["env"]["SDCNET_HOST"] == "0.0.0.0"
    probes = {name: container[name]["httpGet"] for name in container if name.endswith("Probe")}
    assert probes["readinessProbe"]["path"] == served["health"] == "/v2/health/ready"
    assert probes["livenessProbe"]["path"] == "/v2/health/live"
    for probe in probes.values():
        assert "get" in routes[probe["path"]]
        assert probe["port"] in (served["port"], *[n for n in ports if n])
    assert pod["securityContext"]["runAsUser"] == served["user"] == 10001
    assert pod["securityContext"]["runAsNonRoot"] is True


@pytest.mark.parametrize("kind", ["Deployment", "InferenceService"])
def test_environment_variables_are_the_services_settings(kind, monkeypatch):
    (container,) = pod_of(one(kind))["containers"]
    env = {e["name"]: e["value"] for e in container["env"]}
    fields = {f"SDCNET_{name.upper()}" for name in Settings.model_fields}
    assert set(env) <= fields, f"not a setting: {set(env) - fields}"
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    settings = Settings()  # every value parses and passes the settings' own checks
    cpus = container["resources"]["limits"]["cpu"]
    assert settings.threads == int(cpus) == int(container["resources"]["requests"]["cpu"])
    if kind == "InferenceService":
        assert one("InferenceService")["spec"]["predictor"]["scaleTarget"] == (
            settings.max_in_flight
        )


def mebibytes(quantity: str) -> float:
    """A Kubernetes memory or storage quantity ("512Mi", "1Gi") in MiB."""
    number, unit = re.fullmatch(r"(\d+)(Mi|Gi)", quantity).groups()
    return float(number) * {"Mi": 1, "Gi": 1024}[unit]


@pytest.mark.parametrize("kind", ["Deployment", "InferenceService"])
def test_memory_follows_the_services_budget(kind, monkeypatch):
    """The pod's memory holds the warm service, max_in_flight requests at their budget and
    the spools (sdcnet.service.budget, for the settings the manifest gives); the Deployment's
    /tmp holds the spools' files."""
    pod = pod_of(one(kind))
    (container,) = pod["containers"]
    for variable in container["env"]:
        monkeypatch.setenv(variable["name"], variable["value"])
    needed = budget(Settings())
    resources = container["resources"]
    assert mebibytes(resources["limits"]["memory"]) >= needed.memory_mib
    assert mebibytes(resources["requests"]["memory"]) >= needed.memory_mib
    if kind == "Deployment":
        (tmp,) = [v for v in pod["volumes"] if v["name"] == "tmp"]
        assert mebibytes(tmp["emptyDir"]["sizeLimit"]) >= needed.disk_mib
        mounts = {m["name"]: m["mountPath"] for m in container["volumeMounts"]}
        assert mounts["tmp"] == "/tmp"


def test_service_and_autoscaler_point_at_the_deployment():
    deployment, service, hpa = one("Deployment"), one("Service"), one("HorizontalPodAutoscaler")
    labels = deployment["spec"]["template"]["metadata"]["labels"]
    assert service["spec"]["selector"].items() <= labels.items()
    (container,) = deployment["spec"]["template"]["spec"]["containers"]
    named = {p["name"] for p in container["ports"]}
    assert {p["targetPort"] for p in service["spec"]["ports"]} <= named
    target = hpa["spec"]["scaleTargetRef"]
    assert (target["kind"], target["name"]) == ("Deployment", deployment["metadata"]["name"])
    assert container["resources"]["requests"]["cpu"]  # utilisation needs a request


def test_the_indexed_job_runs_one_shard_per_index_with_sdc_datas_own_syntax():
    job = one("Job")
    spec = job["spec"]
    assert spec["completionMode"] == "Indexed"
    pod = spec["template"]["spec"]
    (container,) = pod["containers"]
    data = image("data")
    assert container["command"] == [data["entrypoint"]] == ["sdc-data"]
    assert pod["securityContext"]["runAsUser"] == data["user"] == 10001
    env = {e["name"]: e["valueFrom"]["fieldRef"]["fieldPath"] for e in container["env"]}
    assert "batch.kubernetes.io/job-completion-index" in env["JOB_COMPLETION_INDEX"]
    for index in (0, spec["completions"] - 1):
        argv = [a.replace("$(JOB_COMPLETION_INDEX)", str(index)) for a in container["args"]]
        args = sdc_data_parser().parse_args(argv)
        assert args.command == "generate"
        assert args.shard == (index, spec["completions"])  # INDEX/COUNT, COUNT = completions
    claim = one("PersistentVolumeClaim")["metadata"]["name"]
    volumes = {v["name"]: v["persistentVolumeClaim"]["claimName"] for v in pod["volumes"]}
    mounts = {m["name"]: m["mountPath"] for m in container["volumeMounts"]}
    assert volumes == {"data": claim} and args.out.is_relative_to(mounts["data"])


def test_the_hostile_benchmark_reads_the_deployments_memory_limit():
    """benchmarks.hostile (B5) holds four worst-case requests to this limit."""
    from benchmarks.hostile.memory import deployment_limit_mib

    (container,) = pod_of(one("Deployment"))["containers"]
    assert deployment_limit_mib() == mebibytes(container["resources"]["limits"]["memory"])
