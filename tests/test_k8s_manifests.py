"""deploy/k8s without a cluster: the kustomize base and the example overlay render (here by
tests/kustomize.py, compared with ``kubectl kustomize`` where kubectl is installed); every
resource validates against the Kubernetes API's schemas (kubernetes-validate, strict: an
unknown field is an error), KEDA's ScaledObject against a schema of its fields
(tests/k8s_schemas, as kubernetes-validate has none for custom resources); and the wiring
holds: commands and AD_* variables the real CLIs and settings know, the Host check
admitting the Service and the pod, migrations before each server, tokens from Secrets,
probes, resources, and workers scaled on activedesign_queue_depth.
"""

from __future__ import annotations

import copy
import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import jsonschema
import kubernetes_validate
import pytest
import yaml

from adservice.metrics import DATABASE_GAUGES
from adservice.security import BrowserEdge
from adservice.settings import Settings
from tests.kustomize import Resource, load_documents, render
from tests.program_checks import check_command, check_environment

REPO = Path(__file__).resolve().parents[1]
K8S = REPO / "deploy" / "k8s"
BUILDS = {"base": K8S / "base", "example": K8S / "overlays" / "example"}
VERSIONS = ["1.30.0", kubernetes_validate.latest_version()]
"""The oldest Kubernetes the manifests are meant for, and the newest the validator knows."""
KEDA_SCHEMA = json.loads(
    (Path(__file__).parent / "k8s_schemas" / "keda.sh-v1alpha1-ScaledObject.json").read_text()
)
POD_IP = "10.244.3.7"
DEPLOY_DOC = REPO / "docs" / "deploy.md"


@pytest.fixture(scope="module", params=list(BUILDS))
def build(request: pytest.FixtureRequest) -> tuple[str, list[Resource]]:
    return request.param, render(BUILDS[request.param])


def component(resources: list[Resource], kind: str, name: str) -> Resource:
    (found,) = [
        r
        for r in resources
        if r["kind"] == kind
        and r["metadata"].get("labels", {}).get("app.kubernetes.io/component") == name
    ]
    return found


def pod_spec(workload: Resource) -> dict[str, Any]:
    spec: dict[str, Any] = workload["spec"]["template"]["spec"]
    return spec


def container(workload: Resource, name: str, kind: str = "containers") -> dict[str, Any]:
    (found,) = [c for c in pod_spec(workload).get(kind, []) if c["name"] == name]
    return found


def environment(spec: dict[str, Any]) -> dict[str, str]:
    """A container's environment as the kubelet makes it: ``$(NAME)`` expanded only from
    variables set earlier in the list; Secrets stand as ``<secret NAME/KEY>``."""
    env: dict[str, str] = {}
    for variable in spec.get("env", []):
        if "value" in variable:
            value = re.sub(
                r"\$\((\w+)\)",
                lambda m: env.get(m.group(1), m.group(0)),
                str(variable["value"]),
            )
        elif "secretKeyRef" in variable["valueFrom"]:
            ref = variable["valueFrom"]["secretKeyRef"]
            value = f"<secret {ref['name']}/{ref['key']}>"
        else:
            assert variable["valueFrom"]["fieldRef"]["fieldPath"] == "status.podIP"
            value = POD_IP
        assert "$(" not in value, f"{variable['name']} uses a variable not set before it: {value}"
        env[variable["name"]] = value
    return env


def secret_refs(resources: list[Resource]) -> set[tuple[str, str]]:
    found: set[tuple[str, str]] = set()

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            if "secretKeyRef" in node:
                found.add((node["secretKeyRef"]["name"], node["secretKeyRef"]["key"]))
            for value in node.values():
                walk(value)
        elif isinstance(node, list):
            for item in node:
                walk(item)

    walk(resources)
    return found


def quantity(value: str | int) -> float:
    units = {"m": 1e-3, "Ki": 2**10, "Mi": 2**20, "Gi": 2**30, "Ti": 2**40, "k": 1e3, "M": 1e6}
    text = str(value)
    for unit, factor in units.items():
        if text.endswith(unit):
            return float(text[: -len(unit)]) * factor
    return float(text)


# What is rendered, and how it is validated


def test_every_file_is_part_of_a_build() -> None:
    """No manifest sits in deploy/k8s unrendered, so none goes unvalidated."""
    used: set[Path] = set()
    for folder in [p.parent for p in K8S.rglob("kustomization.yaml")]:
        used.add(folder / "kustomization.yaml")
        kustomization = yaml.safe_load((folder / "kustomization.yaml").read_text())
        for entry in kustomization.get("resources", []):
            used.add((folder / entry).resolve())
        for patch in kustomization.get("patches", []):
            if "path" in patch:
                used.add((folder / patch["path"]).resolve())
    files = {p.resolve() for p in K8S.rglob("*.y*ml")}
    assert files <= used, sorted(str(p.relative_to(K8S)) for p in files - used)
    overlays = {p.parent for p in (K8S / "overlays").rglob("kustomization.yaml")}
    assert overlays == {BUILDS["example"]}


@pytest.mark.skipif(shutil.which("kubectl") is None, reason="no kubectl to compare with")
@pytest.mark.parametrize("name", list(BUILDS))
def test_the_python_renderer_agrees_with_kubectl_kustomize(name: str) -> None:
    done = subprocess.run(
        ["kubectl", "kustomize", str(BUILDS[name])],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr

    def canonical(resources: list[Resource]) -> list[str]:
        return sorted(json.dumps(r, sort_keys=True) for r in resources)

    theirs = [doc for doc in yaml.safe_load_all(done.stdout) if doc]
    assert canonical(render(BUILDS[name])) == canonical(theirs)
    # Order matters within env lists ($(VAR) expansion): kubectl's is the one checked.
    ours = {(r["kind"], r["metadata"]["name"]): r for r in render(BUILDS[name])}
    for resource in theirs:
        assert ours[resource["kind"], resource["metadata"]["name"]] == resource


def validate(resource: Resource) -> None:
    """Kubernetes' own kinds against the API's schemas; KEDA's against tests/k8s_schemas,
    with its HPA behavior against autoscaling/v2."""
    if resource["apiVersion"].startswith("keda.sh/"):
        jsonschema.validate(resource, KEDA_SCHEMA, cls=jsonschema.Draft202012Validator)
        spec = resource["spec"]
        behavior = spec.get("advanced", {}).get("horizontalPodAutoscalerConfig", {})
        hpa = {
            "apiVersion": "autoscaling/v2",
            "kind": "HorizontalPodAutoscaler",
            "metadata": {"name": resource["metadata"]["name"]},
            "spec": {
                "scaleTargetRef": {
                    "apiVersion": "apps/v1",
                    "kind": "Deployment",
                    "name": spec["scaleTargetRef"]["name"],
                },
                "minReplicas": max(1, spec.get("minReplicaCount", 1)),
                "maxReplicas": spec["maxReplicaCount"],
                **({"behavior": behavior["behavior"]} if "behavior" in behavior else {}),
            },
        }
        resource = hpa
    for version in VERSIONS:
        kubernetes_validate.validate(resource, version, strict=True)


def test_every_resource_validates(build: tuple[str, list[Resource]]) -> None:
    _name, resources = build
    kinds = {r["kind"] for r in resources}
    assert {"StatefulSet", "Deployment", "Service", "ScaledObject"} <= kinds
    for resource in resources:
        try:
            validate(resource)
        except (kubernetes_validate.ValidationError, jsonschema.ValidationError) as error:
            pytest.fail(f"{resource['kind']} {resource['metadata']['name']}: {error}")


def test_the_validators_refuse_what_a_cluster_would() -> None:
    resources = render(BUILDS["base"])
    deployment = copy.deepcopy(component(resources, "Deployment", "server"))
    pod_spec(deployment)["containers"][0]["readinesProbe"] = {}  # a typo
    with pytest.raises(kubernetes_validate.ValidationError):
        validate(deployment)
    scaled = component(resources, "ScaledObject", "worker")
    for broken in (
        {"spec": {**scaled["spec"], "trigers": []}},
        {"spec": {**scaled["spec"], "triggers": [{"type": "prometheus", "metadata": {}}]}},
        {"spec": {**scaled["spec"], "maxReplicaCount": "16"}},
    ):
        with pytest.raises(jsonschema.ValidationError):
            validate({**scaled, **broken})
    behavior = copy.deepcopy(scaled)
    policies = behavior["spec"]["advanced"]["horizontalPodAutoscalerConfig"]["behavior"]
    policies["scaleDown"]["policies"][0]["periodSecond"] = 60
    with pytest.raises(kubernetes_validate.ValidationError):
        validate(behavior)


# The wiring


def test_the_server_runs_two_replicas_behind_a_service_with_probes(
    build: tuple[str, list[Resource]],
) -> None:
    _name, resources = build
    deployment = component(resources, "Deployment", "server")
    assert deployment["spec"]["replicas"] == 2
    labels = deployment["spec"]["template"]["metadata"]["labels"]
    assert deployment["spec"]["selector"]["matchLabels"].items() <= labels.items()
    server = container(deployment, "adserver")
    ports = {port["name"]: port["containerPort"] for port in server["ports"]}
    assert "--port" in server["command"]
    assert str(ports["http"]) == server["command"][server["command"].index("--port") + 1]
    for probe in ("readinessProbe", "livenessProbe"):
        assert server[probe]["httpGet"] == {"path": "/healthz", "port": "http"}
    service = component(resources, "Service", "server")
    assert service["spec"]["selector"].items() <= labels.items()
    (port,) = service["spec"]["ports"]
    assert port["targetPort"] == "http"
    budget = component(resources, "PodDisruptionBudget", "server")
    assert budget["spec"]["minAvailable"] < deployment["spec"]["replicas"]


def test_migrations_run_in_an_init_container_before_each_replica(
    build: tuple[str, list[Resource]],
) -> None:
    """An init container per replica, not a Job: ``adserver migrate`` takes a PostgreSQL
    advisory lock (adservice.db.upgrade_to_head), so replicas that start together migrate
    one after the other, and no server starts on an old schema."""
    _name, resources = build
    deployment = component(resources, "Deployment", "server")
    migrate = container(deployment, "migrate", "initContainers")
    server = container(deployment, "adserver")
    assert migrate["command"] == ["adserver", "migrate"]
    check_command(migrate["command"])
    assert migrate["image"] == server["image"]
    database = environment(server)["AD_DATABASE_URL"]
    assert environment(migrate) == {"AD_DATABASE_URL": database}
    assert not [r for r in resources if r["kind"] == "Job"]


def test_the_servers_settings_admit_the_service_the_pod_and_the_public_host(
    build: tuple[str, list[Resource]], monkeypatch: pytest.MonkeyPatch
) -> None:
    name, resources = build
    deployment = component(resources, "Deployment", "server")
    server = container(deployment, "adserver")
    check_command(server["command"])
    env = environment(server)
    check_environment("adserver", env)
    assert env["AD_DATABASE_URL"] == "<secret activedesign-database/url>"
    for variable in list(Settings.model_fields):
        monkeypatch.delenv(f"AD_{variable.upper()}", raising=False)
    for key, value in env.items():
        if key.startswith("AD_") and key != "AD_DATABASE_URL":
            monkeypatch.setenv(key, value)
    settings = Settings()
    assert settings.auth is True
    assert str(settings.artifact_dir) == container_mount(deployment, "artifacts")
    edge = BrowserEdge(app=None, allowed_hosts=settings.resolved_allowed_hosts())  # type: ignore[arg-type]
    service = component(resources, "Service", "server")["metadata"]
    namespace = service.get("namespace")
    port = component(resources, "Service", "server")["spec"]["ports"][0]["port"]
    hosts = [service["name"], POD_IP]  # the Service; kubelet's probes and Prometheus
    if namespace:
        qualified = f"{service['name']}.{namespace}"
        hosts += [qualified, f"{qualified}.svc", f"{qualified}.svc.cluster.local"]
    assert settings.public_url is not None
    public = urlsplit(settings.public_url).hostname
    assert public is not None
    for host in [*hosts, public]:
        assert edge._host_allowed(f"{host}:{port}".encode()), host
    assert not edge._host_allowed(b"rebound.example.net"), "any Host is admitted"
    if name == "example":
        ingress = component(resources, "Ingress", "server")
        (rule,) = ingress["spec"]["rules"]
        assert rule["host"] == public and edge._host_allowed(rule["host"].encode())


def container_mount(workload: Resource, volume: str) -> str:
    (server,) = pod_spec(workload)["containers"]
    (mount,) = [m["mountPath"] for m in server["volumeMounts"] if m["name"] == volume]
    return str(mount)


def test_the_artifact_folder_is_shared_by_the_replicas(build: tuple[str, list[Resource]]) -> None:
    _name, resources = build
    deployment = component(resources, "Deployment", "server")
    (volume,) = [v for v in pod_spec(deployment)["volumes"] if v["name"] == "artifacts"]
    claim = component(resources, "PersistentVolumeClaim", "server")
    assert volume["persistentVolumeClaim"]["claimName"] == claim["metadata"]["name"]
    assert claim["spec"]["accessModes"] == ["ReadWriteMany"]


def test_postgres_keeps_its_data_on_a_volume_and_its_password_in_a_secret(
    build: tuple[str, list[Resource]],
) -> None:
    _name, resources = build
    postgres = component(resources, "StatefulSet", "database")
    (claim,) = postgres["spec"]["volumeClaimTemplates"]
    (database,) = pod_spec(postgres)["containers"]
    assert claim["metadata"]["name"] in {m["name"] for m in database["volumeMounts"]}
    env = environment(database)
    assert env["POSTGRES_PASSWORD"] == "<secret activedesign-database/password>"
    service = component(resources, "Service", "database")
    assert service["metadata"]["name"] == postgres["spec"]["serviceName"]
    labels = postgres["spec"]["template"]["metadata"]["labels"]
    assert service["spec"]["selector"].items() <= labels.items()
    assert service["spec"]["ports"][0]["port"] == 5432


def test_workers_lease_from_the_service_with_the_worker_token_secret(
    build: tuple[str, list[Resource]],
) -> None:
    _name, resources = build
    workers = component(resources, "Deployment", "worker")
    assert "replicas" not in workers["spec"], "KEDA sets the count: apply must not reset it"
    worker = container(workers, "adworker")
    check_command(worker["command"])
    env = environment(worker)
    check_environment("adworker", env)
    assert env["AD_TOKEN"] == "<secret activedesign-worker-token/token>"
    service = component(resources, "Service", "server")
    assert env["AD_SERVER_URL"] == (
        f"http://{service['metadata']['name']}:{service['spec']['ports'][0]['port']}"
    )
    # SIGTERM lets a worker finish its job: give it time.
    assert pod_spec(workers)["terminationGracePeriodSeconds"] >= 600


def test_workers_scale_on_the_queue_depth(build: tuple[str, list[Resource]]) -> None:
    _name, resources = build
    scaled = component(resources, "ScaledObject", "worker")
    workers = component(resources, "Deployment", "worker")
    assert scaled["spec"]["scaleTargetRef"] == {"name": workers["metadata"]["name"]}
    assert 0 <= scaled["spec"]["minReplicaCount"] < scaled["spec"]["maxReplicaCount"]
    (trigger,) = scaled["spec"]["triggers"]
    assert trigger["type"] == "prometheus"
    query = trigger["metadata"]["query"]
    assert "activedesign_queue_depth" in query and "activedesign_leases_active" in query
    # Every metric the query reads is one the server exposes, grouped by labels it has;
    # a selector names only ``job``, the label Prometheus' scrape adds.
    for name, selector in re.findall(r"(activedesign_\w+)\{([^}]*)\}", query):
        assert name in DATABASE_GAUGES, name
        assert re.findall(r"(\w+)\s*=", selector) == ["job"], selector
    for labels, name in re.findall(r"by \(([^)]*)\)\s*\((activedesign_\w+)", query):
        assert {label.strip() for label in labels.split(",")} <= set(DATABASE_GAUGES[name][1])
    # One worker per job its pod runs at once.
    command = container(workers, "adworker")["command"]
    concurrency = command[command.index("--concurrency") + 1]
    assert float(trigger["metadata"]["threshold"]) == float(concurrency)


def test_every_container_has_requests_and_limits_and_runs_unprivileged(
    build: tuple[str, list[Resource]],
) -> None:
    _name, resources = build
    for workload in [r for r in resources if r["kind"] in ("Deployment", "StatefulSet")]:
        spec = pod_spec(workload)
        assert spec["securityContext"]["runAsNonRoot"] is True
        assert spec["automountServiceAccountToken"] is False
        for item in spec["containers"] + spec.get("initContainers", []):
            resources_ = item["resources"]
            for kind in ("cpu", "memory"):
                request = quantity(resources_["requests"][kind])
                assert 0 < request <= quantity(resources_["limits"][kind]), item["name"]
            assert item["securityContext"]["allowPrivilegeEscalation"] is False


def test_deploy_doc_names_every_secret_and_how_to_make_it(
    build: tuple[str, list[Resource]],
) -> None:
    _name, resources = build
    doc = DEPLOY_DOC.read_text()
    for secret, key in secret_refs(resources):
        assert re.search(
            rf"create secret generic {secret}\b[^`]*--from-literal={key}=", doc, re.S
        ), f"docs/deploy.md does not say how to make {secret} ({key})"
    assert "kubectl apply -k deploy/k8s/overlays/example" in doc


def test_manifest_files_parse_as_plain_yaml() -> None:
    for path in K8S.rglob("*.yaml"):
        assert load_documents(path), path


def test_the_readme_links_the_deploy_doc() -> None:
    section = (REPO / "README.md").read_text().split("## Docs", 1)[1]
    assert "(docs/deploy.md)" in section
