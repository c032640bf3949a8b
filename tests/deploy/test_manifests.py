"""The Kubernetes manifests (deploy/kubernetes/*.yaml): valid against the Kubernetes schemas
(kubernetes-validate, strict: no unknown fields), and consistent with the service and the image:
probes on /healthz and /readyz, CPU = AOCNN_CONCURRENCY x AOCNN_THREADS, env names the service reads."""

from __future__ import annotations

import re
from pathlib import Path

import kubernetes_validate
import pytest
import yaml

from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
MANIFESTS = sorted((ROOT / "deploy" / "kubernetes").glob("*.yaml"))
KUBERNETES_VERSIONS = ["1.31.0", kubernetes_validate.utils.latest_version()]
"""1.31: the oldest minor release the manifests are for; and the newest whose schemas the package ships."""


def documents() -> list[dict]:
    return [d for path in MANIFESTS for d in yaml.safe_load_all(path.read_text()) if d]


def by_kind() -> dict[str, dict]:
    out = {}
    for d in documents():
        assert d["kind"] not in out, f"two {d['kind']} manifests"
        out[d["kind"]] = d
    return out


def cpu(quantity) -> float:
    q = str(quantity)
    return int(q[:-1]) / 1000 if q.endswith("m") else float(q)


def memory(quantity: str) -> int:
    units = {"Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "K": 10**3, "M": 10**6, "G": 10**9}
    m = re.fullmatch(r"(\d+)([KMG]i?)?", quantity)
    return int(m[1]) * units.get(m[2] or "", 1)


def container() -> dict:
    (c,) = by_kind()["Deployment"]["spec"]["template"]["spec"]["containers"]
    return c


def env() -> dict[str, dict]:
    return {e["name"]: e for e in container()["env"]}


def test_the_manifests_exist():
    assert {"Deployment", "Service", "HorizontalPodAutoscaler"} <= set(by_kind())


@pytest.mark.parametrize("version", KUBERNETES_VERSIONS)
@pytest.mark.parametrize("path", MANIFESTS, ids=lambda p: p.name)
def test_valid_against_the_kubernetes_schemas(path, version):
    for doc in yaml.safe_load_all(path.read_text()):
        kubernetes_validate.validate(doc, version, strict=True)


def test_the_validator_rejects_a_broken_manifest():
    """Strict mode catches a misspelt field and a wrong type (so the test above means something)."""
    deployment = by_kind()["Deployment"]
    bad = yaml.safe_load(yaml.safe_dump(deployment))
    bad["spec"]["template"]["spec"]["containers"][0]["readinesProbe"] = {"httpGet": {"path": "/readyz", "port": "http"}}
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(bad, KUBERNETES_VERSIONS[0], strict=True)
    bad = yaml.safe_load(yaml.safe_dump(deployment))
    bad["spec"]["replicas"] = "two"
    with pytest.raises(kubernetes_validate.ValidationError):
        kubernetes_validate.validate(bad, KUBERNETES_VERSIONS[0], strict=True)


def test_probes():
    c = container()
    port = {p["name"]: p["containerPort"] for p in c["ports"]}
    assert c["livenessProbe"]["httpGet"]["path"] == "/healthz"
    assert c["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert c["startupProbe"]["httpGet"]["path"] == "/healthz"
    for probe in ("livenessProbe", "readinessProbe", "startupProbe"):
        assert c[probe]["httpGet"]["port"] in port
    # the startup probe allows at least the Dockerfile HEALTHCHECK's start period (120 s)
    startup = c["startupProbe"]
    assert startup["periodSeconds"] * startup["failureThreshold"] >= 120


def test_resources_match_the_thread_settings():
    e, res = env(), container()["resources"]
    concurrency, threads = int(e["AOCNN_CONCURRENCY"]["value"]), int(e["AOCNN_THREADS"]["value"])
    assert cpu(res["requests"]["cpu"]) == concurrency * threads
    assert cpu(res["limits"]["cpu"]) == cpu(res["requests"]["cpu"])        # whole CPUs, no throttling surprise
    assert memory(res["limits"]["memory"]) >= memory(res["requests"]["memory"]) >= 256 * 2**20


def test_env_is_what_the_service_reads():
    fields = {f"AOCNN_{name.upper()}" for name in Settings.model_fields}
    e = env()
    assert set(e) <= fields, set(e) - fields
    assert e["AOCNN_HOST"]["value"] == "0.0.0.0"
    port = {p["name"]: p["containerPort"] for p in container()["ports"]}
    assert int(e["AOCNN_PORT"]["value"]) == port["http"]
    # every value parses as the service's settings do
    values = {k.removeprefix("AOCNN_").lower(): v["value"] for k, v in e.items() if "value" in v}
    Settings(**values)
    assert e["AOCNN_API_KEYS"]["valueFrom"]["secretKeyRef"]["optional"] is True


def test_service_and_autoscaler_point_at_the_deployment():
    k = by_kind()
    deployment, service, hpa = k["Deployment"], k["Service"], k["HorizontalPodAutoscaler"]
    labels = deployment["spec"]["template"]["metadata"]["labels"]
    assert deployment["spec"]["selector"]["matchLabels"].items() <= labels.items()
    assert service["spec"]["selector"].items() <= labels.items()
    assert service["spec"]["ports"][0]["targetPort"] in {p["name"] for p in container()["ports"]}
    assert hpa["spec"]["scaleTargetRef"] == {"apiVersion": "apps/v1", "kind": "Deployment",
                                             "name": deployment["metadata"]["name"]}
    assert 1 <= hpa["spec"]["minReplicas"] <= hpa["spec"]["maxReplicas"]
    (metric,) = hpa["spec"]["metrics"]
    assert metric["resource"]["name"] == "cpu" and 0 < metric["resource"]["target"]["averageUtilization"] <= 100
    if "PodDisruptionBudget" in k:
        assert k["PodDisruptionBudget"]["spec"]["minAvailable"] < hpa["spec"]["minReplicas"]


def test_runs_as_the_image_user_read_only():
    pod = by_kind()["Deployment"]["spec"]["template"]["spec"]
    dockerfile = (ROOT / "Dockerfile").read_text()
    (user,) = re.findall(r"^USER\s+(\d+)", dockerfile, re.M)
    assert pod["securityContext"]["runAsNonRoot"] is True
    assert str(pod["securityContext"]["runAsUser"]) == user
    c = container()
    assert c["securityContext"]["readOnlyRootFilesystem"] is True
    assert "/tmp" in {m["mountPath"] for m in c["volumeMounts"]}           # uploads are spooled there
