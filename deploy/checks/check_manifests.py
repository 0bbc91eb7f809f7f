#!/usr/bin/env python3
"""Parses the operator files written in YAML/TOML/INI and checks that they
agree with each other and with the service's configuration:

- Kubernetes (deploy/kubernetes): every document has apiVersion/kind/name;
  the kustomizations name files that exist; the StatefulSet has one replica, a
  headless governing Service, a volume claim mounted at the configuration's
  store.data_dir, the configuration mounted where `--config` points,
  HTTP probes on the metrics port (the gRPC port speaks TLS), TLS from a
  mounted Secret and tokens on the volume, resource requests, a non-root
  security context;
  humem.toml binds 0.0.0.0 on the container ports; the Service and the
  ServiceMonitor select what they should; the GPU overlay asks for a GPU and
  the CUDA provider; the PrometheusRule generator reproduces the rules file.
- Prometheus, Grafana provisioning and docker/compose.yaml: the job name,
  mounts, service names and ports line up with deploy/ and docker/humem.toml.
- systemd (deploy/systemd): the unit, the sidecar configuration, the
  sysusers and tmpfiles snippets name the same user, config and data dir, and
  the sidecar binds loopback only.

Needs PyYAML (the only non-stdlib module of the checks).

  check_manifests.py REPO
"""

import configparser
import ipaddress
import os
import subprocess
import sys
import tomllib

import yaml

from common import Report


def load_yaml_docs(path: str) -> list[dict]:
    with open(path, encoding="utf-8") as f:
        return [d for d in yaml.safe_load_all(f) if d is not None]


def load_toml(path: str) -> dict:
    with open(path, "rb") as f:
        return tomllib.load(f)


def host_port(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    return host.strip("[]"), int(port)


def check_kubernetes(repo: str, r: Report) -> None:
    base = os.path.join(repo, "deploy/kubernetes")
    kustomization = load_yaml_docs(os.path.join(base, "kustomization.yaml"))[0]
    docs = []
    for resource in kustomization.get("resources", []):
        path = os.path.join(base, resource)
        if r.check(os.path.isfile(path), f"kustomization resource {resource} exists"):
            docs += load_yaml_docs(path)
    generators = {g["name"]: g for g in kustomization.get("configMapGenerator", [])}
    for g in generators.values():
        for file in g.get("files", []):
            r.check(os.path.isfile(os.path.join(base, file.split("=")[-1])), f"configMapGenerator {g['name']}: {file} exists")
    for doc in docs + load_yaml_docs(os.path.join(base, "monitoring/servicemonitor.yaml")):
        r.check(bool(doc.get("apiVersion") and doc.get("kind") and doc.get("metadata", {}).get("name")),
                f"{doc.get('kind')}/{doc.get('metadata', {}).get('name')}: apiVersion, kind, metadata.name")
    by_kind = {}
    for doc in docs:
        by_kind.setdefault(doc["kind"], {})[doc["metadata"]["name"]] = doc
    sts = by_kind.get("StatefulSet", {}).get("humem")
    if not r.check(sts is not None, "StatefulSet humem"):
        return
    spec = sts["spec"]
    pod = spec["template"]
    pod_labels = pod["metadata"]["labels"]
    r.check(spec.get("replicas") == 1, "StatefulSet: one replica (one store, one writer)")
    r.check(spec["selector"]["matchLabels"].items() <= pod_labels.items(), "StatefulSet: selector matches the pod labels")
    governing = by_kind.get("Service", {}).get(spec.get("serviceName"))
    r.check(governing is not None and governing["spec"].get("clusterIP") == "None",
            f"StatefulSet: serviceName {spec.get('serviceName')} is a headless Service")
    container = pod["spec"]["containers"][0]
    ports = {p["name"]: p["containerPort"] for p in container.get("ports", [])}
    r.check({"grpc", "metrics"} <= ports.keys(), f"container ports grpc and metrics: {ports}")
    # The gRPC port speaks TLS, which Kubernetes' gRPC probes cannot: the
    # probes are the plain-HTTP endpoints of the metrics listener.
    for probe, path in (("startupProbe", "/healthz"), ("livenessProbe", "/healthz"), ("readinessProbe", "/readyz")):
        p = container.get(probe, {}).get("httpGet", {})
        r.check(p.get("path") == path and p.get("port") in ("metrics", ports.get("metrics")),
                f"{probe}: HTTP GET {path} on the metrics port")
    requests = container.get("resources", {}).get("requests", {})
    r.check({"cpu", "memory"} <= requests.keys(), f"resource requests {requests}")
    security = {**pod["spec"].get("securityContext", {}), **container.get("securityContext", {})}
    r.check(security.get("runAsNonRoot") is True and security.get("allowPrivilegeEscalation") is False,
            "non-root, no privilege escalation")

    args = container.get("args", [])
    config_path = args[args.index("--config") + 1] if "--config" in args else None
    mounts = {m["name"]: m["mountPath"] for m in container.get("volumeMounts", [])}
    volumes = {v["name"]: v for v in pod["spec"].get("volumes", [])}
    config_volume = next((n for n, v in volumes.items() if v.get("configMap", {}).get("name") in generators), None)
    r.check(config_path is not None and config_volume is not None
            and config_path == f"{mounts.get(config_volume)}/humem.toml",
            f"--config {config_path} is the generated ConfigMap's humem.toml")
    config = load_toml(os.path.join(base, "humem.toml"))
    claims = [c["metadata"]["name"] for c in spec.get("volumeClaimTemplates", [])]
    data_dir = config.get("store", {}).get("data_dir")
    r.check(any(mounts.get(c) == data_dir for c in claims),
            f"a volumeClaimTemplate is mounted at store.data_dir {data_dir}")
    # The secure setup: TLS from a mounted Secret, tokens on the volume.
    tls = config.get("server", {}).get("tls", {})
    secret_mounts = {mounts.get(n) for n, v in volumes.items() if "secret" in v}
    for key in ("cert", "key"):
        path = tls.get(key)
        r.check(path is not None and os.path.dirname(path) in secret_mounts,
                f"humem.toml server.tls.{key} {path} is in a mounted Secret")
    r.check(not any(d.get("kind") == "Secret" for d in docs), "no Secret is shipped (certificates are never baked in)")
    tokens = config.get("auth", {}).get("tokens_file", "")
    r.check(bool(tokens) and tokens.startswith(f"{data_dir}/"), f"auth.tokens_file {tokens} is on the persistent volume")
    for key, port_name in (("server", "grpc"), ("metrics", "metrics")):
        host, port = host_port(config.get(key, {}).get("listen", "127.0.0.1:0"))
        r.check(ipaddress.ip_address(host).is_unspecified and port == ports.get(port_name),
                f"humem.toml [{key}] listen {host}:{port} binds all interfaces on container port {port_name}")

    service = by_kind.get("Service", {}).get("humem")
    if r.check(service is not None, "Service humem"):
        r.check(service["spec"]["selector"].items() <= pod_labels.items(), "Service humem selects the pod")
        names = {p["name"]: p for p in service["spec"]["ports"]}
        r.check({"grpc", "metrics"} <= names.keys() and all(p["targetPort"] in ports for p in names.values()),
                "Service humem: grpc and metrics ports onto named container ports")
        monitor = load_yaml_docs(os.path.join(base, "monitoring/servicemonitor.yaml"))[0]
        selector = monitor["spec"]["selector"]["matchLabels"]
        selected = [n for n, s in by_kind.get("Service", {}).items() if selector.items() <= s["metadata"].get("labels", {}).items()]
        r.check(selected == ["humem"], f"ServiceMonitor selects the Service humem only (job=\"humem\"), got {selected}")
        r.check(all(e.get("port") in names for e in monitor["spec"]["endpoints"]), "ServiceMonitor endpoints name Service ports")

    gpu = os.path.join(base, "gpu")
    overlay = load_yaml_docs(os.path.join(gpu, "kustomization.yaml"))[0]
    r.check(all(os.path.exists(os.path.join(gpu, res)) for res in overlay.get("resources", [])), "gpu overlay: resources exist")
    for patch in overlay.get("patches", []):
        path = os.path.join(gpu, patch["path"])
        if not r.check(os.path.isfile(path), f"gpu overlay: {patch['path']} exists"):
            continue
        doc = load_yaml_docs(path)[0]
        c = doc["spec"]["template"]["spec"]["containers"][0]
        r.check(doc["metadata"]["name"] == "humem" and c["name"] == container["name"], "gpu patch targets the humem container")
        r.check(c.get("resources", {}).get("limits", {}).get("nvidia.com/gpu") == 1, "gpu patch: limits nvidia.com/gpu: 1")
        r.check({"name": "HUMEM_PERCEPTION__PROVIDER", "value": "cuda"} in c.get("env", []), "gpu patch: provider cuda")

    generated = subprocess.run([os.path.join(base, "monitoring/prometheusrule.sh")], capture_output=True, text=True, check=True).stdout
    rule = yaml.safe_load(generated)
    rules = load_yaml_docs(os.path.join(repo, "deploy/prometheus/rules/humem.rules.yml"))[0]
    r.check(rule["kind"] == "PrometheusRule" and rule["spec"] == rules, "prometheusrule.sh reproduces the rules file")


def check_compose_and_grafana(repo: str, r: Report) -> None:
    docker = os.path.join(repo, "docker")
    compose = load_yaml_docs(os.path.join(docker, "compose.yaml"))[0]
    services = compose.get("services", {})
    r.check({"humem", "prometheus", "grafana"} <= services.keys(), f"compose services {sorted(services)}")
    mounts = {}
    for name, service in services.items():
        build = service.get("build")
        if build:
            context = os.path.normpath(os.path.join(docker, build["context"]))
            r.check(os.path.isfile(os.path.join(context, build["dockerfile"])), f"compose {name}: build {build['dockerfile']} exists")
        for volume in service.get("volumes", []):
            source, target = volume.split(":")[:2]
            if source.startswith("."):
                path = os.path.normpath(os.path.join(docker, source))
                r.check(os.path.exists(path), f"compose {name}: mount {source} exists")
                mounts[(name, os.path.relpath(path, repo))] = target
            elif source not in compose.get("volumes", {}):
                r.fail(f"compose {name}: volume {source} is not declared")
    image_config = load_toml(os.path.join(docker, "humem.toml"))
    metrics_port = host_port(image_config["metrics"]["listen"])[1]
    prom_dir = mounts.get(("prometheus", "deploy/prometheus"))
    r.check(prom_dir is not None and f"--config.file={prom_dir}/prometheus.yml" in services["prometheus"].get("command", []),
            "compose prometheus runs deploy/prometheus/prometheus.yml")
    prometheus = load_yaml_docs(os.path.join(repo, "deploy/prometheus/prometheus.yml"))[0]
    jobs = [j["job_name"] for j in prometheus.get("scrape_configs", [])]
    r.check("humem" in jobs, f"prometheus.yml scrapes job \"humem\", which the rules and the dashboard select ({jobs})")
    targets = [t for group in load_yaml_docs(os.path.join(repo, "deploy/prometheus/targets/humem.yml"))[0] for t in group["targets"]]
    r.check(f"humem:{metrics_port}" in targets, f"targets/humem.yml lists the compose service humem:{metrics_port}")
    prov = mounts.get(("grafana", "deploy/grafana/provisioning"))
    r.check(prov == "/etc/grafana/provisioning", "compose grafana mounts the provisioning directory")
    datasources = load_yaml_docs(os.path.join(repo, "deploy/grafana/provisioning/datasources/prometheus.yml"))[0]
    ds = datasources.get("datasources", [])
    r.check(datasources.get("apiVersion") == 1 and len(ds) == 1 and ds[0]["type"] == "prometheus"
            and ds[0]["url"] == "http://prometheus:9090", "Grafana datasource: the compose prometheus service")
    providers = load_yaml_docs(os.path.join(repo, "deploy/grafana/provisioning/dashboards/humem.yml"))[0]
    paths = [p["options"]["path"] for p in providers.get("providers", [])]
    r.check(paths == [mounts.get(("grafana", "deploy/grafana/dashboards"))],
            f"Grafana dashboard provider reads where compose mounts deploy/grafana/dashboards: {paths}")


def check_systemd(repo: str, r: Report) -> None:
    base = os.path.join(repo, "deploy/systemd")
    unit = configparser.ConfigParser(strict=False, interpolation=None, empty_lines_in_values=False)
    unit.optionxform = str
    # Repeated keys (SystemCallFilter=, DeviceAllow=) are allowed in units: keep the last.
    with open(os.path.join(base, "humem.service"), encoding="utf-8") as f:
        unit.read_string(f.read())
    service = unit["Service"]
    exec_start = service["ExecStart"].split()
    config_path = exec_start[exec_start.index("--config") + 1]
    r.check(exec_start[1] == "serve" and config_path == "/etc/humem/humem.toml", f"ExecStart runs `humem serve --config {config_path}`")
    config = load_toml(os.path.join(base, "humem.toml"))
    data_dir = config["store"]["data_dir"]
    r.check(data_dir in service["ReadWritePaths"].split(), f"ReadWritePaths= holds store.data_dir {data_dir}")
    r.check(data_dir in unit["Unit"].get("RequiresMountsFor", "").split(), "RequiresMountsFor= the data dir")
    for key, value in (("ProtectSystem", "strict"), ("NoNewPrivileges", "yes"), ("Restart", "on-failure")):
        r.check(service.get(key) == value, f"{key}={value}")
    for section in ("server", "metrics"):
        host = host_port(config[section]["listen"])[0]
        r.check(ipaddress.ip_address(host).is_loopback, f"sidecar [{section}] listen on loopback ({host})")
    r.check(config["perception"]["provider"] in ("cuda", "tensorrt"), "sidecar asks for a GPU provider")
    with open(os.path.join(base, "humem.sysusers.conf"), encoding="utf-8") as f:
        users = [line.split()[1] for line in f if line.startswith("u ")]
    r.check(users == [service["User"]], f"sysusers creates User={service['User']}")
    with open(os.path.join(base, "humem.tmpfiles.conf"), encoding="utf-8") as f:
        dirs = [line.split() for line in f if line.startswith("d ")]
    r.check(any(d[1] == data_dir and d[3] == service["User"] for d in dirs), f"tmpfiles creates {data_dir} for {service['User']}")


def main(repo: str) -> None:
    r = Report("manifests")
    check_kubernetes(repo, r)
    check_compose_and_grafana(repo, r)
    check_systemd(repo, r)
    r.finish()


if __name__ == "__main__":
    main(sys.argv[1])
