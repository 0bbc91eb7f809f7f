#!/usr/bin/env python3
"""Parses the operator files written in YAML/TOML/INI and checks that they
agree with each other and with the service's configuration:

- Kubernetes (deploy/kubernetes): every document has apiVersion/kind/name;
  the kustomizations name files and bases that exist, files inside their own
  directory and no base that contains them (which kustomize refuses: "cycle
  detected", or files outside the root without LoadRestrictionsNone);
  deploy/kubernetes deploys the base (base/) as it is; the base's
  StatefulSet has one replica, a
  headless governing Service, a volume claim mounted at the configuration's
  store.data_dir, the configuration mounted where `--config` points,
  HTTP probes on the metrics port (the gRPC port speaks TLS), TLS from a
  mounted Secret and tokens on the volume, resource requests, a non-root
  security context;
  humem.toml binds 0.0.0.0 on the container ports; the Service and the
  ServiceMonitor select what they should; the GPU overlay asks for a GPU and
  the CUDA provider; the PrometheusRule generator reproduces the rules file.
- Kubernetes cluster mode (deploy/kubernetes/cluster): the overlay takes
  the base (which itself stays one replica), replaces its ConfigMaps and
  keeps its image; its patch scales the StatefulSet past one replica and mounts the
  NATS CA, password and the shared token file from Secrets; its humem.toml
  knows only keys the service knows ([cluster] against
  crates/cluster/src/config.rs, the rest against the base's), turns cluster
  mode on with TLS and credentials, and names every pod of nats.yaml's
  StatefulSet through its headless Service; the NATS servers run JetStream
  on a volume, 3 of them, with routes to each other, max_payload of at
  least 8 MB, TLS from a mounted Secret, the password HuMem sends, probes on
  the monitoring port, non-root.
- Prometheus, Grafana provisioning and docker/compose.yaml: the job name,
  mounts, service names and ports line up with deploy/ and docker/humem.toml.
- docker/compose.cluster.yaml: three NATS servers with JetStream, routes to
  each other and docker/nats-cluster.conf (max_payload); HuMem replicas
  built from docker/Dockerfile in cluster mode, each with its own store
  volume and name, one shared token volume, NATS URLs naming the NATS
  services, on distinct loopback ports.
- systemd (deploy/systemd): the unit, the sidecar configuration, the
  sysusers and tmpfiles snippets name the same user, config and data dir, and
  the sidecar binds loopback only.

Needs PyYAML (the only non-stdlib module of the checks).

  check_manifests.py REPO
"""

import configparser
import ipaddress
import json
import os
import re
import subprocess
import sys
import tomllib
import urllib.parse

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


def rust_struct_fields(path: str, struct: str) -> list[str]:
    """The `pub name:` fields of `pub struct NAME { ... }` in a Rust file."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    m = re.search(r"pub struct " + struct + r" \{(.*?)\n\}", text, re.S)
    return re.findall(r"^\s*pub (\w+):", m.group(1), re.M) if m else []


def size_bytes(value: str) -> int:
    """A NATS size (8MB, 512KB, 1048576) in bytes."""
    m = re.fullmatch(r"(\d+)\s*([KMG]?)B?", value.strip(), re.I)
    if not m:
        return 0
    return int(m.group(1)) * 1024 ** " KMG".index(m.group(2).upper() or " ")


def merge_named(base: list[dict], patch: list[dict], key: str) -> list[dict]:
    """A strategic merge of two lists of objects keyed by `key` (patch wins)."""
    merged = {item[key]: item for item in base}
    for item in patch:
        merged[item[key]] = {**merged.get(item[key], {}), **item}
    return list(merged.values())


def secret_volume_paths(volumes: list[dict], mounts: list[dict]) -> dict[str, set[str]]:
    """Mount path -> Secrets it shows, for Secret and projected Secret volumes."""
    out = {}
    by_name = {v["name"]: v for v in volumes}
    for m in mounts:
        v = by_name.get(m["name"], {})
        secrets = set()
        if "secret" in v:
            secrets.add(v["secret"]["secretName"])
        for source in v.get("projected", {}).get("sources", []):
            if "secret" in source:
                secrets.add(source["secret"]["name"])
        if secrets:
            out[m["mountPath"]] = secrets
    return out


def check_kustomization_resources(directory: str, kustomization: dict, label: str, r: Report) -> list[dict]:
    """Each resource of a kustomization is a file inside its directory or a
    directory with a kustomization.yaml (a base) that does not contain it:
    kustomize refuses a base above the overlay ("cycle detected") and, without
    --load-restrictor LoadRestrictionsNone, files outside the overlay's root.
    Returns the documents of the resources, a base's resources included (not
    its generators or patches)."""
    docs = []
    for resource in kustomization.get("resources", []):
        path = os.path.normpath(os.path.join(directory, resource))
        if os.path.isdir(path):
            if not r.check(os.path.isfile(os.path.join(path, "kustomization.yaml")), f"{label}: {resource} is a base (has a kustomization.yaml)"):
                continue
            if r.check(os.path.commonpath([path, directory]) != path, f"{label}: base {resource} does not contain the kustomization (no cycle)"):
                docs += check_kustomization_resources(path, load_yaml_docs(os.path.join(path, "kustomization.yaml"))[0], f"{label}: {resource}", r)
        elif r.check(os.path.isfile(path), f"{label}: resource {resource} exists"):
            r.check(os.path.commonpath([path, directory]) == directory, f"{label}: resource {resource} is inside the kustomization's directory")
            docs += load_yaml_docs(path)
    return docs


def check_kubernetes(repo: str, r: Report) -> None:
    kubernetes = os.path.join(repo, "deploy/kubernetes")
    base = os.path.join(kubernetes, "base")
    # `kubectl apply -k deploy/kubernetes`: the base, unchanged.
    top = load_yaml_docs(os.path.join(kubernetes, "kustomization.yaml"))[0]
    check_kustomization_resources(kubernetes, top, "deploy/kubernetes kustomization", r)
    r.check([os.path.normpath(os.path.join(kubernetes, res)) for res in top.get("resources", [])] == [base]
            and top.keys() <= {"apiVersion", "kind", "resources"},
            "deploy/kubernetes kustomization: the base (base/) and nothing else")
    kustomization = load_yaml_docs(os.path.join(base, "kustomization.yaml"))[0]
    docs = check_kustomization_resources(base, kustomization, "base kustomization", r)
    generators = {g["name"]: g for g in kustomization.get("configMapGenerator", [])}
    for g in generators.values():
        for file in g.get("files", []):
            r.check(os.path.isfile(os.path.join(base, file.split("=")[-1])), f"configMapGenerator {g['name']}: {file} exists")
    for doc in docs + load_yaml_docs(os.path.join(kubernetes, "monitoring/servicemonitor.yaml")):
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
        monitor = load_yaml_docs(os.path.join(kubernetes, "monitoring/servicemonitor.yaml"))[0]
        selector = monitor["spec"]["selector"]["matchLabels"]
        selected = [n for n, s in by_kind.get("Service", {}).items() if selector.items() <= s["metadata"].get("labels", {}).items()]
        r.check(selected == ["humem"], f"ServiceMonitor selects the Service humem only (job=\"humem\"), got {selected}")
        r.check(all(e.get("port") in names for e in monitor["spec"]["endpoints"]), "ServiceMonitor endpoints name Service ports")

    gpu = os.path.join(kubernetes, "gpu")
    overlay = load_yaml_docs(os.path.join(gpu, "kustomization.yaml"))[0]
    check_kustomization_resources(gpu, overlay, "gpu overlay", r)
    r.check(base in {os.path.normpath(os.path.join(gpu, res)) for res in overlay.get("resources", [])}, "gpu overlay: takes the base (../base)")
    for patch in overlay.get("patches", []):
        path = os.path.join(gpu, patch["path"])
        if not r.check(os.path.isfile(path), f"gpu overlay: {patch['path']} exists"):
            continue
        doc = load_yaml_docs(path)[0]
        c = doc["spec"]["template"]["spec"]["containers"][0]
        r.check(doc["metadata"]["name"] == "humem" and c["name"] == container["name"], "gpu patch targets the humem container")
        r.check(c.get("resources", {}).get("limits", {}).get("nvidia.com/gpu") == 1, "gpu patch: limits nvidia.com/gpu: 1")
        r.check({"name": "HUMEM_PERCEPTION__PROVIDER", "value": "cuda"} in c.get("env", []), "gpu patch: provider cuda")

    generated = subprocess.run([os.path.join(kubernetes, "monitoring/prometheusrule.sh")], capture_output=True, text=True, check=True).stdout
    rule = yaml.safe_load(generated)
    rules = load_yaml_docs(os.path.join(repo, "deploy/prometheus/rules/humem.rules.yml"))[0]
    r.check(rule["kind"] == "PrometheusRule" and rule["spec"] == rules, "prometheusrule.sh reproduces the rules file")


def check_cluster_overlay(repo: str, r: Report) -> None:
    """deploy/kubernetes/cluster: the base, scaled out, in cluster mode on nats.yaml."""
    kubernetes = os.path.join(repo, "deploy/kubernetes")
    base = os.path.join(kubernetes, "base")
    overlay_dir = os.path.join(kubernetes, "cluster")
    base_kustomization = load_yaml_docs(os.path.join(base, "kustomization.yaml"))[0]
    overlay = load_yaml_docs(os.path.join(overlay_dir, "kustomization.yaml"))[0]
    docs = check_kustomization_resources(overlay_dir, overlay, "cluster overlay", r)
    named = {os.path.normpath(os.path.join(overlay_dir, res)) for res in overlay.get("resources", [])}
    r.check(base in named, "cluster overlay: takes the base (../base), so every resource of the base")
    # The base's ConfigMaps replaced by the overlay's (its humem.toml), the base's images kept.
    base_generators = {g["name"] for g in base_kustomization.get("configMapGenerator", [])}
    generators = {g["name"]: g for g in overlay.get("configMapGenerator", [])}
    r.check(all(generators.get(name, {}).get("behavior") == "replace" for name in base_generators),
            f"cluster overlay: replaces the base's ConfigMaps {sorted(base_generators)} (behavior: replace)")
    for g in generators.values():
        for file in g.get("files", []):
            r.check(os.path.isfile(os.path.join(overlay_dir, file.split("=")[-1])), f"cluster overlay: configMapGenerator {g['name']}: {file} exists")
    base_images = {i["name"] for i in base_kustomization.get("images", [])}
    overridden = sorted(i["name"] for i in overlay.get("images", []) if i["name"] in base_images)
    r.check(bool(base_images) and not overridden, f"cluster overlay: the base's images {sorted(base_images)} (overridden: {overridden or 'none'})")
    for doc in docs:
        r.check(bool(doc.get("apiVersion") and doc.get("kind") and doc.get("metadata", {}).get("name")),
                f"cluster overlay: {doc.get('kind')}/{doc.get('metadata', {}).get('name')}: apiVersion, kind, metadata.name")
    r.check(not any(d.get("kind") == "Secret" for d in docs), "cluster overlay: no Secret is shipped")
    by_kind = {}
    for doc in docs:
        by_kind.setdefault(doc["kind"], {})[doc["metadata"]["name"]] = doc
    sts = by_kind.get("StatefulSet", {}).get("humem")
    nats = by_kind.get("StatefulSet", {}).get("nats")
    if not r.check(sts is not None and nats is not None, "cluster overlay: StatefulSets humem and nats"):
        return

    # The patch of the humem StatefulSet, merged the way kustomize does for these fields.
    patches = []
    for patch in overlay.get("patches", []):
        if patch.get("target", {}).get("kind") != "StatefulSet" or patch.get("target", {}).get("name") != "humem":
            continue
        if "path" in patch:
            if r.check(os.path.isfile(os.path.join(overlay_dir, patch["path"])), f"cluster overlay: {patch['path']} exists"):
                patches += load_yaml_docs(os.path.join(overlay_dir, patch["path"]))
        else:
            patches += [d for d in yaml.safe_load_all(patch.get("patch", "")) if d]
    if not r.check(len(patches) == 1, f"cluster overlay: one patch of StatefulSet humem, got {len(patches)}"):
        return
    patch = patches[0]
    r.check(patch.get("kind") == "StatefulSet" and patch.get("metadata", {}).get("name") == "humem",
            "cluster overlay: the patch is of StatefulSet humem")
    spec, patch_spec = sts["spec"], patch.get("spec", {})
    replicas = patch_spec.get("replicas", spec.get("replicas"))
    r.check(isinstance(replicas, int) and replicas > 1, f"cluster overlay: humem scaled out ({replicas} replicas)")
    r.check(patch_spec.get("podManagementPolicy") == "Parallel", "cluster overlay: replicas start in parallel")
    container = spec["template"]["spec"]["containers"][0]
    patch_pod = patch_spec.get("template", {}).get("spec", {})
    patch_containers = patch_pod.get("containers", [])
    r.check(all(c.get("name") == container["name"] for c in patch_containers), "cluster overlay: the patch names the humem container")
    mounts = merge_named(container.get("volumeMounts", []), sum((c.get("volumeMounts", []) for c in patch_containers), []), "mountPath")
    volumes = merge_named(spec["template"]["spec"].get("volumes", []), patch_pod.get("volumes", []), "name")
    mounted = {m["name"] for m in mounts}
    r.check(all(v["name"] in mounted for v in patch_pod.get("volumes", [])), "cluster overlay: every volume it adds is mounted")
    claims = [c["metadata"]["name"] for c in spec.get("volumeClaimTemplates", [])]
    r.check(all(m["name"] in {v["name"] for v in volumes} | set(claims) for m in mounts),
            "cluster overlay: every mount has a volume or a volume claim")
    secrets = secret_volume_paths(volumes, mounts)

    config = load_toml(os.path.join(overlay_dir, "humem.toml"))
    base_config = load_toml(os.path.join(base, "humem.toml"))
    # Unknown keys are refused at start: [cluster] against the service's own
    # settings, the rest against the base's file, which the real binary reads
    # in scripts/check-deploy.sh.
    cluster_rs = os.path.join(repo, "crates/cluster/src/config.rs")
    known = {"": rust_struct_fields(cluster_rs, "ClusterConfig"), "auth": rust_struct_fields(cluster_rs, "NatsAuth"),
             "tls": rust_struct_fields(cluster_rs, "NatsTls")}
    cluster = config.get("cluster", {})
    unknown = [k for k in cluster if k not in known[""]]
    unknown += [f"{section}.{k}" for section in ("auth", "tls") for k in cluster.get(section, {}) if k not in known[section]]
    r.check(bool(known[""]) and not unknown, f"cluster overlay humem.toml: [cluster] keys are ClusterConfig's (unknown: {unknown or 'none'})")
    for section, values in config.items():
        if section == "cluster":
            continue
        for key, value in values.items():
            if isinstance(value, dict):
                r.check(isinstance(base_config.get(section, {}).get(key), dict) or value == {},
                        f"cluster overlay humem.toml: [{section}.{key}] is a section of the base's humem.toml")
            else:
                r.check(key in base_config.get(section, {}), f"cluster overlay humem.toml: {section}.{key} is a key of the base's humem.toml")
    r.check(cluster.get("enabled") is True, "cluster overlay humem.toml: cluster.enabled = true")
    auth, tls = cluster.get("auth", {}), cluster.get("tls", {})
    r.check(bool(tls.get("ca") or tls.get("cert")), "cluster overlay humem.toml: [cluster.tls] set (NATS beyond loopback)")
    r.check(sum(bool(auth.get(k)) for k in ("token_file", "user", "credentials_file")) == 1,
            "cluster overlay humem.toml: [cluster.auth] has one credential")
    for key, path in [("tls." + k, tls[k]) for k in ("ca", "cert", "key") if k in tls] + \
                     [("auth." + k, auth[k]) for k in ("token_file", "password_file", "credentials_file") if k in auth]:
        r.check(os.path.dirname(path) in secrets, f"cluster overlay humem.toml: cluster.{key} {path} is in a mounted Secret")
    tokens = config.get("auth", {}).get("tokens_file", "")
    r.check(os.path.dirname(tokens) in secrets, f"cluster overlay humem.toml: auth.tokens_file {tokens} is in a mounted Secret (one for every replica)")
    data_dir = config.get("store", {}).get("data_dir")
    r.check(any(m["name"] in claims and m["mountPath"] == data_dir for m in mounts),
            f"cluster overlay: each replica keeps its store on its own volume claim ({data_dir})")

    # NATS: nats.yaml's StatefulSet, its headless Service and nats.conf.
    nspec = nats["spec"]
    nreplicas = nspec.get("replicas")
    r.check(nreplicas == 3, f"nats: 3 replicas ({nreplicas})")
    r.check(1 <= cluster.get("stream_replicas", 3) <= (nreplicas or 0), "cluster.stream_replicas fits the NATS servers")
    service = by_kind.get("Service", {}).get(nspec.get("serviceName"))
    r.check(service is not None and service["spec"].get("clusterIP") == "None"
            and service["spec"]["selector"].items() <= nspec["template"]["metadata"]["labels"].items(),
            f"nats: serviceName {nspec.get('serviceName')} is a headless Service selecting its pods")
    r.check(service is not None and service["spec"].get("publishNotReadyAddresses") is True,
            "nats: the headless Service publishes not-ready pods (a new cluster's servers find each other)")
    npod = nspec["template"]["spec"]
    nc = npod["containers"][0]
    r.check(re.fullmatch(r"nats:2\.9\.\d+(-\w+)?", nc.get("image", "")) is not None, f"nats: image {nc.get('image')} is NATS 2.9, pinned")
    nports = {p["name"]: p["containerPort"] for p in nc.get("ports", [])}
    command = nc.get("command", []) + nc.get("args", [])
    conf_path = command[command.index("--config") + 1] if "--config" in command else None
    nmounts = nc.get("volumeMounts", [])
    nvolumes = {v["name"]: v for v in npod.get("volumes", [])}
    conf_mount = next((m for m in nmounts if conf_path and os.path.dirname(conf_path) == m["mountPath"]), None)
    configmap = nvolumes.get(conf_mount["name"], {}).get("configMap", {}).get("name") if conf_mount else None
    conf = by_kind.get("ConfigMap", {}).get(configmap, {}).get("data", {}).get(os.path.basename(conf_path or ""), "")
    if not r.check(bool(conf), f"nats: --config {conf_path} is a mounted ConfigMap's file"):
        return
    setting = lambda name: (re.search(r"^\s*" + name + r"\s*[:=]\s*(\S+)", conf, re.M) or [None, None])[1]
    r.check(re.search(r"^\s*jetstream\s*\{", conf, re.M) is not None, "nats.conf: JetStream on")
    store_dir = setting("store_dir")
    nclaims = [c["metadata"]["name"] for c in nspec.get("volumeClaimTemplates", [])]
    r.check(any(m["name"] in nclaims and store_dir and (store_dir + "/").startswith(m["mountPath"].rstrip("/") + "/") for m in nmounts),
            f"nats: JetStream's store_dir {store_dir} is on a volume claim")
    r.check(size_bytes(setting("max_payload") or "0") >= 8 * 1024 ** 2, f"nats.conf: max_payload {setting('max_payload')} of at least 8 MB")
    r.check(str(nports.get("client")) == str(setting("port")), f"nats.conf: port {setting('port')} is the container port client")
    r.check(str(nports.get("monitor")) == str(setting("http_port")), f"nats.conf: http_port {setting('http_port')} is the container port monitor")
    cluster_block = conf[conf.find("cluster {"):] if "cluster {" in conf else ""
    cluster_port = (re.search(r"^\s*port\s*:\s*(\d+)", cluster_block, re.M) or [None, None])[1]
    r.check(cluster_port is not None and int(cluster_port) == nports.get("cluster"), f"nats.conf: cluster port {cluster_port} is the container port cluster")
    pods = [f"{nats['metadata']['name']}-{i}.{nspec.get('serviceName')}" for i in range(nreplicas or 0)]
    routes = {(u.hostname, u.port) for u in map(urllib.parse.urlsplit, re.findall(r"nats(?:-route)?://\S+", cluster_block))}
    r.check(routes == {(p, int(cluster_port or 0)) for p in pods}, f"nats.conf: routes to every server {pods}")
    tls_files = re.findall(r"^\s*(?:cert_file|key_file|ca_file)\s*:\s*(\S+)", conf, re.M)
    nsecrets = secret_volume_paths(list(nvolumes.values()), nmounts)
    r.check(len(tls_files) >= 6 and all(os.path.dirname(f) in nsecrets for f in tls_files),
            "nats.conf: TLS for clients and routes, from a mounted Secret")
    r.check(re.search(r"verify\s*:\s*true", cluster_block) is not None, "nats.conf: routes check each other's certificates")
    r.check(re.search(r"no_advertise\s*:\s*true", cluster_block) is not None,
            "nats.conf: no_advertise (clients keep to the names the certificate holds)")
    # The servers' CA is what HuMem trusts; the password HuMem sends is the one they read.
    nats_tls_secrets = set().union(*[nsecrets[os.path.dirname(f)] for f in tls_files if os.path.dirname(f) in nsecrets]) if tls_files else set()
    if tls.get("ca"):
        r.check(bool(secrets.get(os.path.dirname(tls["ca"]), set()) & nats_tls_secrets),
                f"cluster.tls.ca comes from the NATS servers' Secret {sorted(nats_tls_secrets)}")
    user = re.search(r"user\s*:\s*(\w+)\s*,\s*password\s*:\s*\$(\w+)", conf)
    env = {e["name"]: e for e in nc.get("env", [])}
    if r.check(user is not None and user.group(1) == auth.get("user"), f"nats.conf: a user {auth.get('user')} with a password from the environment"):
        ref = env.get(user.group(2), {}).get("valueFrom", {}).get("secretKeyRef", {})
        volume = next((v for v in volumes for m in mounts if m["name"] == v["name"]
                       and m["mountPath"] == os.path.dirname(auth.get("password_file", ""))), {})
        items = [(s["secret"]["name"], i["key"], i["path"]) for s in volume.get("projected", {}).get("sources", []) if "secret" in s
                 for i in s["secret"].get("items", [])]
        if "secret" in volume:
            items += [(volume["secret"]["secretName"], i["key"], i["path"]) for i in volume["secret"].get("items", [])] \
                or [(volume["secret"]["secretName"], ref.get("key"), ref.get("key"))]
        r.check((ref.get("name"), ref.get("key"), os.path.basename(auth.get("password_file", ""))) in items,
                f"cluster.auth.password_file is the Secret key the NATS servers read ({ref.get('name')}/{ref.get('key')})")
    # HuMem names every NATS pod through the headless Service, on the client port.
    urls = [urllib.parse.urlsplit(u) for u in cluster.get("nats_urls", [])]
    r.check(sorted((u.hostname, u.port) for u in urls) == sorted((p, nports.get("client")) for p in pods),
            f"cluster overlay humem.toml: nats_urls name every NATS pod {pods} on port {nports.get('client')}")
    r.check(all(u.scheme == "tls" for u in urls), "cluster overlay humem.toml: nats_urls are tls://")
    for probe in ("readinessProbe",):
        p = nc.get(probe, {}).get("httpGet", {})
        r.check(p.get("path", "").startswith("/healthz") and p.get("port") in ("monitor", nports.get("monitor")),
                f"nats: {probe} on /healthz of the monitoring port")
    security = {**npod.get("securityContext", {}), **nc.get("securityContext", {})}
    r.check(security.get("runAsNonRoot") is True and security.get("allowPrivilegeEscalation") is False,
            "nats: non-root, no privilege escalation")
    # Prometheus Operator: the ServiceMonitor still selects HuMem's Service only.
    monitor = load_yaml_docs(os.path.join(kubernetes, "monitoring/servicemonitor.yaml"))[0]
    selector = monitor["spec"]["selector"]["matchLabels"]
    selected = [n for n, sv in by_kind.get("Service", {}).items() if selector.items() <= sv["metadata"].get("labels", {}).items()]
    r.check(selected == ["humem"], f"cluster overlay: the ServiceMonitor selects the Service humem only, got {selected}")


def check_compose_cluster(repo: str, r: Report) -> None:
    """docker/compose.cluster.yaml: NATS servers and HuMem replicas in cluster mode."""
    docker = os.path.join(repo, "docker")
    compose = load_yaml_docs(os.path.join(docker, "compose.cluster.yaml"))[0]
    services = compose.get("services", {})
    declared = compose.get("volumes", {})
    image_config = load_toml(os.path.join(docker, "humem.toml"))
    grpc_port = host_port(image_config["server"]["listen"])[1]
    nats = {n: s for n, s in services.items() if s.get("image", "").startswith("nats:") and "nats-server" in s.get("command", [])}
    humem = {n: s for n, s in services.items() if s.get("build")}
    r.check(len(nats) == 3, f"compose.cluster: 3 NATS servers ({sorted(nats)})")
    r.check(len(humem) >= 2, f"compose.cluster: HuMem replicas ({sorted(humem)})")
    volume_mounts = {}
    for name, service in services.items():
        image = service.get("image", "")
        r.check(":" in image and not image.endswith(":latest"), f"compose.cluster {name}: image {image} pinned by tag")
        for volume in service.get("volumes", []):
            source, target = volume.split(":")[:2]
            if source.startswith("."):
                r.check(os.path.exists(os.path.normpath(os.path.join(docker, source))), f"compose.cluster {name}: mount {source} exists")
            elif r.check(source in declared, f"compose.cluster {name}: volume {source} is declared"):
                volume_mounts.setdefault(name, {})[target] = source
    for name, service in humem.items():
        build = service["build"]
        r.check(os.path.isfile(os.path.join(os.path.normpath(os.path.join(docker, build["context"])), build["dockerfile"])),
                f"compose.cluster {name}: build {build['dockerfile']} exists")
    # NATS: JetStream, one cluster, routes to every server, max_payload from the mounted file.
    names, cluster_names = [], set()
    for name, service in nats.items():
        flags = dict(f.lstrip("-").split("=", 1) if "=" in f else (f.lstrip("-"), "") for f in service["command"][1:])
        names.append(flags.get("server_name") or flags.get("n") or flags.get("name"))
        cluster_names.add(flags.get("cluster_name"))
        r.check("jetstream" in flags or "js" in flags, f"compose.cluster {name}: JetStream on")
        store = flags.get("store_dir") or flags.get("sd")
        r.check(store in volume_mounts.get(name, {}), f"compose.cluster {name}: store_dir {store} on a volume")
        port = urllib.parse.urlsplit(flags.get("cluster", "")).port
        routes = {(u.hostname, u.port) for u in map(urllib.parse.urlsplit, flags.get("routes", "").split(","))}
        r.check(routes == {(n, port) for n in nats}, f"compose.cluster {name}: routes to every NATS server on port {port}")
        conf = flags.get("config") or flags.get("c")
        source = next((v.split(":")[0] for v in service.get("volumes", []) if v.split(":")[1:2] == [conf]), None)
        text = open(os.path.normpath(os.path.join(docker, source)), encoding="utf-8").read() if source else ""
        payload = re.search(r"^\s*max_payload\s*[:=]\s*(\S+)", text, re.M)
        r.check(payload is not None and size_bytes(payload.group(1)) >= 8 * 1024 ** 2,
                f"compose.cluster {name}: --config {conf} sets max_payload of at least 8 MB")
    r.check(len(set(names)) == len(names) == 3 and None not in names, f"compose.cluster: NATS server names unique ({names})")
    r.check(len(cluster_names) == 1 and None not in cluster_names, f"compose.cluster: one NATS cluster name ({cluster_names})")
    # HuMem: cluster mode on the NATS services, each replica its own store and name, one token file.
    data_dir = image_config["store"]["data_dir"]
    replica_names, stores, published, token_volumes = [], [], [], []
    for name, service in humem.items():
        env = {k: str(v) for k, v in (service.get("environment") or {}).items()}
        r.check(env.get("HUMEM_CLUSTER__ENABLED") == "true", f"compose.cluster {name}: HUMEM_CLUSTER__ENABLED=true")
        urls = [urllib.parse.urlsplit(u) for u in json.loads(env.get("HUMEM_CLUSTER__NATS_URLS", "[]"))]
        r.check(sorted((u.hostname, u.port) for u in urls) == sorted((n, 4222) for n in nats),
                f"compose.cluster {name}: HUMEM_CLUSTER__NATS_URLS name every NATS service")
        # NATS without TLS or credentials beyond loopback is refused unless allowed.
        r.check(env.get("HUMEM_SERVER__ALLOW_INSECURE_NETWORK") == "true",
                f"compose.cluster {name}: allows plain NATS on the compose network (HUMEM_SERVER__ALLOW_INSECURE_NETWORK)")
        replica_names.append(env.get("HUMEM_CLUSTER__REPLICA_NAME"))
        stores.append(volume_mounts.get(name, {}).get(data_dir))
        tokens = env.get("HUMEM_AUTH__TOKENS_FILE", image_config.get("auth", {}).get("tokens_file", ""))
        token_volumes.append(volume_mounts.get(name, {}).get(os.path.dirname(tokens)))
        for port in service.get("ports", []):
            host, outside, inside = port.split(":")
            r.check(host == "127.0.0.1", f"compose.cluster {name}: port {port} published on loopback only")
            published.append(outside)
        r.check(any(int(p.split(":")[2]) == grpc_port for p in service.get("ports", [])), f"compose.cluster {name}: publishes gRPC {grpc_port}")
    r.check(None not in replica_names and len(set(replica_names)) == len(replica_names), f"compose.cluster: replica names unique {replica_names}")
    r.check(None not in stores and len(set(stores)) == len(stores), f"compose.cluster: each replica its own store volume at {data_dir} {stores}")
    r.check(None not in token_volumes and len(set(token_volumes)) == 1 and not set(token_volumes) & set(stores),
            f"compose.cluster: one token file for every replica, on a volume of its own {token_volumes}")
    r.check(len(set(published)) == len(published), f"compose.cluster: published ports distinct {published}")


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
    check_cluster_overlay(repo, r)
    check_compose_and_grafana(repo, r)
    check_compose_cluster(repo, r)
    check_systemd(repo, r)
    r.finish()


if __name__ == "__main__":
    main(sys.argv[1])
