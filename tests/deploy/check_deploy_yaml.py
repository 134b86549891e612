#!/usr/bin/python3
"""Checks rim's deployment assets under deploy/ for the mistakes that only show up at deploy time.

- Every YAML file under deploy/ parses.
- Kubernetes manifests (deploy/k8s/): known kinds with their apiVersions; selectors that match pod
  labels; Service, probe and ServiceMonitor ports that exist on the containers they point at; the
  rim StatefulSet's headless Service, shared ReadWriteMany volume at /data with shared sessions
  on, GPU limit, gRPC health probes and a grace period that leaves time to save sessions after
  the preStop pause; HAProxy's config (deploy/haproxy/haproxy.cfg, the ConfigMap kustomize
  generates from it): HTTP/2 front and servers, `balance hdr(x-robot-id)` on a consistent ring,
  health checks, one server per StatefulSet pod, named by the proxy Deployment's environment.
- Compose (deploy/compose.yaml), Prometheus and Grafana provisioning agree with each other: mounted
  files exist, the scrape target is the rim service's metrics port, the dashboard's datasource uid
  is the provisioned one.
- The Grafana dashboard parses, has a `session` variable, and every PromQL expression of the
  dashboard and of the alert rules names only metric families documented in docs/metrics.md (or
  `up`); every documented family is shown somewhere. With promtool present, the dashboard's
  expressions must also be valid PromQL.

Usage: check_deploy_yaml.py [REPO_ROOT]   (default: two levels above this script)
Exits 1 listing every problem found.
"""

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

import yaml

ROOT = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else
                       os.path.join(os.path.dirname(__file__), "..", ".."))
DEPLOY = os.path.join(ROOT, "deploy")
K8S = os.path.join(DEPLOY, "k8s")

errors = []


def check(condition, message):
    if not condition:
        errors.append(message)
    return condition


def rel(path):
    return os.path.relpath(path, ROOT)


# --------------------------------------------------------------------------------------------
# YAML files


def load_yaml_files():
    """Every *.yml / *.yaml under deploy/, as {path: [documents]}."""
    docs = {}
    for dirpath, _, files in os.walk(DEPLOY):
        for name in sorted(files):
            if not name.endswith((".yml", ".yaml")):
                continue
            path = os.path.join(dirpath, name)
            try:
                with open(path) as f:
                    docs[path] = [d for d in yaml.safe_load_all(f) if d is not None]
            except yaml.YAMLError as e:
                errors.append(f"{rel(path)}: does not parse: {e}")
    return docs


# --------------------------------------------------------------------------------------------
# Metric families and PromQL


def documented_families():
    """{family: type} from the table of docs/metrics.md."""
    path = os.path.join(ROOT, "docs", "metrics.md")
    families = {}
    with open(path) as f:
        for line in f:
            m = re.match(r"\|\s*`(rim_[a-z0-9_]+)`\s*\|\s*(counter|gauge|histogram)\s*\|", line)
            if m:
                families[m.group(1)] = m.group(2)
    check(families, "docs/metrics.md: no metric table rows found")
    for name, kind in families.items():
        if kind == "counter":
            check(name.endswith("_total"), f"docs/metrics.md: counter {name} must end in _total")
        else:
            check(not name.endswith("_total"), f"docs/metrics.md: {kind} {name} must not end in _total")
    return families


def series_names(families):
    """Series names Prometheus stores for the families: histograms as _bucket, _sum, _count."""
    names = {"up"}
    for name, kind in families.items():
        if kind == "histogram":
            names.update({name + "_bucket", name + "_sum", name + "_count"})
        else:
            names.add(name)
    return names


PROMQL_KEYWORDS = {"and", "or", "unless", "bool", "offset", "inf", "nan", "Inf", "NaN"}


def promql_metric_names(expr):
    """Metric names an expression selects: identifiers that are not functions, aggregations,
    keywords, label names, label values, durations or Grafana variables."""
    e = re.sub(r'"(?:[^"\\]|\\.)*"', '""', expr)
    e = re.sub(r"'(?:[^'\\]|\\.)*'", "''", e)
    e = re.sub(r"\{[^}]*\}", "", e)  # label matchers
    e = re.sub(r"\[[^\]]*\]", "", e)  # range and subquery windows
    e = re.sub(r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\)", " ", e)
    e = re.sub(r"\b(group_left|group_right)\b", " ", e)
    e = re.sub(r"\$\{?[A-Za-z_][A-Za-z0-9_]*\}?", " ", e)  # Grafana variables outside selectors
    names = []
    for m in re.finditer(r"[A-Za-z_:][A-Za-z0-9_:]*", e):
        if m.start() > 0 and (e[m.start() - 1].isdigit() or e[m.start() - 1] == "."):
            continue  # exponent or duration unit, as in 1e3 or 5m
        if e[m.end():].lstrip().startswith("("):
            continue  # function or aggregation
        if m.group(0) in PROMQL_KEYWORDS:
            continue
        names.append(m.group(0))
    return names


def check_expr(where, expr, allowed):
    names = promql_metric_names(expr)
    check(names, f"{where}: no metric in expression {expr!r}")
    for name in names:
        check(name in allowed, f"{where}: {name!r} is not a metric family of docs/metrics.md "
              f"(expression {expr!r})")
    return names


def grafana_to_promql(expr):
    """Grafana's variables replaced by values Prometheus accepts, for syntax checking."""
    expr = expr.replace("$__rate_interval", "5m").replace("$__interval", "1m")
    expr = expr.replace("$__range", "1h")
    return re.sub(r"\$\{?[A-Za-z_][A-Za-z0-9_]*\}?", ".*", expr)


def check_promql_syntax(exprs):
    promtool = shutil.which("promtool")
    if not promtool:
        print("check_deploy_yaml: promtool not found, dashboard PromQL syntax not checked")
        return
    rules = {"groups": [{"name": "dashboard", "rules": [
        {"record": f"rim_dashboard_expr_{i}", "expr": grafana_to_promql(e)}
        for i, (_, e) in enumerate(exprs)]}]}
    with tempfile.NamedTemporaryFile("w", suffix=".yml", delete=False) as f:
        yaml.safe_dump(rules, f)
        path = f.name
    try:
        out = subprocess.run([promtool, "check", "rules", path], capture_output=True, text=True)
        check(out.returncode == 0, "dashboard: PromQL that Prometheus rejects:\n" +
              out.stdout + out.stderr)
    finally:
        os.unlink(path)


# --------------------------------------------------------------------------------------------
# Grafana


def panels_of(dashboard):
    for panel in dashboard.get("panels", []):
        yield panel
        for inner in panel.get("panels", []):
            yield inner


def check_dashboard(path, datasource_uid, allowed, families):
    try:
        with open(path) as f:
            dashboard = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        errors.append(f"{rel(path)}: does not parse: {e}")
        return
    where = rel(path)
    check(dashboard.get("uid") and dashboard.get("title"), f"{where}: needs uid and title")

    variables = {v.get("name"): v for v in dashboard.get("templating", {}).get("list", [])}
    session = variables.get("session")
    if check(session is not None, f"{where}: no `session` template variable"):
        check(session.get("type") == "query", f"{where}: `session` must be a query variable")
        check(session.get("datasource", {}).get("uid") == datasource_uid,
              f"{where}: `session` variable must use datasource uid {datasource_uid!r}")
    exprs = []
    for name, v in variables.items():
        if v.get("type") != "query":
            continue
        query = v.get("query")
        query = query.get("query", "") if isinstance(query, dict) else (query or "")
        m = re.fullmatch(r"\s*label_values\((.*),\s*([A-Za-z_][A-Za-z0-9_]*)\s*\)\s*", query)
        if check(m, f"{where}: variable {name}: expected label_values(SELECTOR, LABEL), got {query!r}"):
            check_expr(f"{where}: variable {name}", m.group(1), allowed)

    ids = set()
    boxes = []
    for panel in panels_of(dashboard):
        title = panel.get("title", "?")
        pw = f"{where}: panel {title!r}"
        check(panel.get("id") not in ids, f"{pw}: duplicate panel id {panel.get('id')}")
        ids.add(panel.get("id"))
        pos = panel.get("gridPos", {})
        if check(all(k in pos for k in "xywh"), f"{pw}: gridPos needs x, y, w, h"):
            check(pos["x"] >= 0 and pos["x"] + pos["w"] <= 24, f"{pw}: wider than the 24-column grid")
            for other_title, o in boxes:
                overlap = (pos["x"] < o["x"] + o["w"] and o["x"] < pos["x"] + pos["w"] and
                           pos["y"] < o["y"] + o["h"] and o["y"] < pos["y"] + pos["h"])
                check(not overlap, f"{pw}: overlaps panel {other_title!r}")
            boxes.append((title, pos))
        if panel.get("type") == "row":
            continue
        targets = panel.get("targets", [])
        check(targets, f"{pw}: no queries")
        ds = panel.get("datasource", {})
        check(isinstance(ds, dict) and ds.get("uid") == datasource_uid,
              f"{pw}: datasource must be uid {datasource_uid!r}")
        for t in targets:
            tds = t.get("datasource", ds)
            check(isinstance(tds, dict) and tds.get("uid") == datasource_uid,
                  f"{pw}: query {t.get('refId')} datasource must be uid {datasource_uid!r}")
            expr = t.get("expr", "")
            if check(expr, f"{pw}: query {t.get('refId')} has no expr"):
                check_expr(pw, expr, allowed)
                exprs.append((pw, expr))

    check(any("$session" in e for _, e in exprs), f"{where}: no query uses $session")
    shown = {n for _, e in exprs for n in promql_metric_names(e)}
    for family, kind in families.items():
        series = ({family + s for s in ("_bucket", "_sum", "_count")} if kind == "histogram"
                  else {family})
        check(series & shown, f"{where}: documented family {family} is on no panel")
    check_promql_syntax(exprs)


def grafana_provisioning(docs):
    prov = os.path.join(DEPLOY, "grafana", "provisioning")
    uid = url = dash_path = None
    for path, ds in docs.items():
        if not path.startswith(prov):
            continue
        for d in ds:
            for source in d.get("datasources", []) or []:
                if source.get("type") == "prometheus":
                    uid, url = source.get("uid"), source.get("url")
            for provider in d.get("providers", []) or []:
                dash_path = provider.get("options", {}).get("path")
    check(uid, "grafana provisioning: no Prometheus datasource with a uid")
    check(dash_path, "grafana provisioning: no dashboard provider with options.path")
    return uid, url, dash_path


# --------------------------------------------------------------------------------------------
# Prometheus


def check_rules(docs, allowed):
    path = os.path.join(DEPLOY, "prometheus", "rim-alerts.yml")
    alerts = {}
    for d in docs.get(path, []):
        for group in d.get("groups", []):
            for rule in group.get("rules", []):
                if "alert" in rule:
                    alerts[rule["alert"]] = rule
                    w = f"{rel(path)}: {rule['alert']}"
                    check_expr(w, str(rule.get("expr", "")), allowed)
                    check(rule.get("labels", {}).get("severity"), f"{w}: needs a severity label")
                    check(rule.get("annotations", {}).get("summary"), f"{w}: needs a summary")
    needed = {
        "RimServerDown": "up",
        "RimSessionLagging": "rim_training_lag_frames",
        "RimHostMemoryNearBudget": "rim_host_memory_budget_bytes",
        "RimScansRejected": "rim_scans_rejected_total",
        "RimCheckpointSlow": "rim_checkpoint_seconds_sum",
    }
    for alert, metric in needed.items():
        if check(alert in alerts, f"{rel(path)}: alert {alert} missing"):
            check(metric in promql_metric_names(str(alerts[alert]["expr"])),
                  f"{rel(path)}: {alert} must use {metric}")
    lag = alerts.get("RimSessionLagging", {})
    check(lag.get("for") == "2m", f"{rel(path)}: RimSessionLagging must hold for 2m")
    down = str(alerts.get("RimServerDown", {}).get("expr", ""))
    m = re.search(r'job\s*=\s*"([^"]+)"', down)
    return m.group(1) if m else None


def check_prometheus_config(docs, rim_job):
    path = os.path.join(DEPLOY, "prometheus", "prometheus.yml")
    config = (docs.get(path) or [{}])[0]
    for rule_file in config.get("rule_files", []):
        check(os.path.exists(os.path.join(os.path.dirname(path), rule_file)),
              f"{rel(path)}: rule file {rule_file} not next to it")
    jobs = {j.get("job_name"): j for j in config.get("scrape_configs", [])}
    check(rim_job in jobs, f"{rel(path)}: no scrape job {rim_job!r}, the job RimServerDown watches")
    targets = [t for sc in jobs.get(rim_job, {}).get("static_configs", [])
               for t in sc.get("targets", [])]
    return targets


# --------------------------------------------------------------------------------------------
# Compose


def dockerfile_metrics_port():
    with open(os.path.join(ROOT, "Dockerfile")) as f:
        m = re.search(r'"--metrics",\s*"[^"]*:(\d+)"', f.read())
    check(m, "Dockerfile: ENTRYPOINT has no --metrics ADDR:PORT")
    return int(m.group(1)) if m else None


def check_compose(docs, scrape_targets, datasource_url, dashboard_dir):
    path = os.path.join(DEPLOY, "compose.yaml")
    if not check(path in docs, "deploy/compose.yaml missing"):
        return
    compose = docs[path][0]
    services = compose.get("services", {})
    for name in ("rim", "prometheus", "grafana"):
        check(name in services, f"{rel(path)}: service {name} missing")
    rim = services.get("rim", {})
    build = rim.get("build", {})
    context = os.path.normpath(os.path.join(DEPLOY, build.get("context", ".")))
    check(os.path.isfile(os.path.join(context, build.get("dockerfile", "Dockerfile"))),
          f"{rel(path)}: rim build context has no {build.get('dockerfile', 'Dockerfile')}")
    check(any(str(v).endswith(":/data") for v in rim.get("volumes", [])),
          f"{rel(path)}: rim needs a volume on /data")
    published = {str(p).split(":")[-1] for p in rim.get("ports", [])}
    check("50051" in published, f"{rel(path)}: rim must publish gRPC port 50051")
    metrics_port = dockerfile_metrics_port()
    check(f"rim:{metrics_port}" in scrape_targets,
          f"prometheus.yml: scrape target must be rim:{metrics_port} (service rim, metrics port)")
    check(rim.get("stop_grace_period"), f"{rel(path)}: rim needs stop_grace_period to save sessions")

    mounts = {}
    for name, service in services.items():
        for volume in service.get("volumes", []):
            parts = str(volume).split(":")
            if parts[0].startswith((".", "/")):
                source = os.path.normpath(os.path.join(DEPLOY, parts[0]))
                check(os.path.exists(source), f"{rel(path)}: {name} mounts missing {parts[0]}")
                mounts[(name, parts[1])] = source
    prom_config = mounts.get(("prometheus", "/etc/prometheus/prometheus.yml"))
    check(prom_config == os.path.join(DEPLOY, "prometheus", "prometheus.yml"),
          f"{rel(path)}: prometheus must mount prometheus/prometheus.yml")
    check(mounts.get(("prometheus", "/etc/prometheus/rim-alerts.yml")) ==
          os.path.join(DEPLOY, "prometheus", "rim-alerts.yml"),
          f"{rel(path)}: prometheus must mount prometheus/rim-alerts.yml next to its config")
    for kind in ("datasources", "dashboards"):
        check(mounts.get(("grafana", f"/etc/grafana/provisioning/{kind}")) ==
              os.path.join(DEPLOY, "grafana", "provisioning", kind),
              f"{rel(path)}: grafana must mount grafana/provisioning/{kind}")
    dashboard = os.path.join(DEPLOY, "grafana", "rim-dashboard.json")
    check(any(src == dashboard and os.path.dirname(target) == dashboard_dir
              for (svc, target), src in mounts.items() if svc == "grafana"),
          f"{rel(path)}: grafana must mount rim-dashboard.json into {dashboard_dir}")
    m = re.match(r"https?://([^:/]+):(\d+)", datasource_url or "")
    if check(m, f"grafana datasource url {datasource_url!r} is not http://HOST:PORT"):
        check(m.group(1) in services, f"grafana datasource host {m.group(1)} is no compose service")


# --------------------------------------------------------------------------------------------
# Kubernetes

API_VERSIONS = {
    "Namespace": "v1", "ConfigMap": "v1", "Service": "v1", "StatefulSet": "apps/v1",
    "Deployment": "apps/v1", "ServiceMonitor": "monitoring.coreos.com/v1",
    "PersistentVolumeClaim": "v1",
}
HAPROXY = os.path.join(DEPLOY, "haproxy")


def matches(selector, labels):
    return bool(selector) and all(labels.get(k) == v for k, v in selector.items())


def container_port(pod_spec, port):
    """The container port a probe or Service targetPort means (by name or number), or None."""
    for c in pod_spec.get("containers", []):
        for p in c.get("ports", []):
            if port in (p.get("name"), p.get("containerPort")):
                return p.get("containerPort")
    return None


def probe_port(probe):
    for kind in ("grpc", "tcpSocket", "httpGet"):
        if kind in probe:
            return kind, probe[kind].get("port")
    return None, None


def check_workload(w, objects):
    name = f"{w['kind']} {w['metadata']['name']}"
    spec = w.get("spec", {})
    template = spec.get("template", {})
    labels = template.get("metadata", {}).get("labels", {})
    check(matches(spec.get("selector", {}).get("matchLabels", {}), labels),
          f"{name}: selector.matchLabels do not match the pod template's labels")
    pod = template.get("spec", {})
    volumes = {v["name"]: v for v in pod.get("volumes", [])}
    claims = {c["metadata"]["name"] for c in spec.get("volumeClaimTemplates", [])}
    for c in pod.get("containers", []):
        cn = f"{name} container {c.get('name')}"
        check(c.get("image"), f"{cn}: no image")
        for probe_kind in ("startupProbe", "readinessProbe", "livenessProbe"):
            if probe_kind in c:
                kind, port = probe_port(c[probe_kind])
                check(container_port(pod, port) is not None,
                      f"{cn}: {probe_kind} {kind} port {port} is not a container port")
        for mount in c.get("volumeMounts", []):
            check(mount["name"] in volumes or mount["name"] in claims,
                  f"{cn}: volumeMount {mount['name']} is neither a volume nor a claim template")
    for v in volumes.values():
        if "configMap" in v:
            check(("ConfigMap", v["configMap"]["name"]) in objects,
                  f"{name}: volume {v['name']} uses missing ConfigMap {v['configMap']['name']}")
    return labels, pod


def check_rim_statefulset(sts, objects):
    name = f"StatefulSet {sts['metadata']['name']}"
    spec = sts["spec"]
    pod = spec["template"]["spec"]
    labels = spec["template"]["metadata"].get("labels", {})
    svc = objects.get(("Service", spec.get("serviceName")))
    if check(svc is not None, f"{name}: serviceName {spec.get('serviceName')} is no Service"):
        check(svc["spec"].get("clusterIP") == "None", f"{name}: Service {svc['metadata']['name']} "
              "must be headless (clusterIP: None)")
        check(matches(svc["spec"].get("selector", {}), labels),
              f"{name}: headless Service selector does not match its pods")
    # One data root for every replica: a ReadWriteMany claim (sessions move between replicas).
    check(not spec.get("volumeClaimTemplates"),
          f"{name}: replicas share one volume; volumeClaimTemplates give each its own")
    shared = {}
    for v in pod.get("volumes", []):
        claim = v.get("persistentVolumeClaim", {}).get("claimName")
        pvc = objects.get(("PersistentVolumeClaim", claim))
        if claim and check(pvc is not None, f"{name}: volume {v['name']} uses missing "
                           f"PersistentVolumeClaim {claim}"):
            shared[v["name"]] = pvc
            check("ReadWriteMany" in pvc.get("spec", {}).get("accessModes", []),
                  f"{name}: claim {claim} must be ReadWriteMany (every replica mounts it)")
            check(pvc.get("spec", {}).get("resources", {}).get("requests", {}).get("storage"),
                  f"{name}: claim {claim} requests no storage")
    server = pod["containers"][0]
    check(any(m["mountPath"] == "/data" and m["name"] in shared
              for m in server.get("volumeMounts", [])),
          f"{name}: /data must be mounted from the shared PersistentVolumeClaim")
    limits = server.get("resources", {}).get("limits", {})
    check(str(limits.get("nvidia.com/gpu")) == "1", f"{name}: needs limit nvidia.com/gpu: 1")
    grpc_port = container_port(pod, "grpc")
    check(grpc_port == 50051, f"{name}: container port named grpc must be 50051")
    check(container_port(pod, "metrics") is not None, f"{name}: needs a container port named metrics")
    for probe_kind in ("readinessProbe", "livenessProbe"):
        kind, port = probe_port(server.get(probe_kind, {}))
        check(kind == "grpc" and container_port(pod, port) == 50051,
              f"{name}: {probe_kind} must be a gRPC health probe on 50051")
    command = server.get("lifecycle", {}).get("preStop", {}).get("exec", {}).get("command", [])
    sleep = None
    if command and os.path.basename(command[0]) == "sleep" and len(command) == 2:
        sleep = int(command[1])
    elif command:
        m = re.search(r"\bsleep\s+(\d+)", " ".join(command))
        sleep = int(m.group(1)) if m else None
    grace = pod.get("terminationGracePeriodSeconds", 30)
    if check(sleep is not None, f"{name}: needs a preStop hook that sleeps"):
        # After the pause, rim_server gives in-flight RPCs 10 s, drains its queues and saves every
        # session: a grace period that ends soon after the pause kills it mid-save.
        check(grace >= sleep + 60, f"{name}: terminationGracePeriodSeconds {grace} leaves under "
              f"60 s after the {sleep} s preStop pause to save sessions")
    config_arg = server.get("args", [])
    if "--config" in config_arg:
        config_path = config_arg[config_arg.index("--config") + 1]
        volumes = {v["name"]: v for v in pod.get("volumes", [])}
        found = False
        for m in server.get("volumeMounts", []):
            v = volumes.get(m["name"], {})
            if "configMap" in v and os.path.dirname(config_path) == m["mountPath"]:
                cm = objects.get(("ConfigMap", v["configMap"]["name"]), {})
                found = os.path.basename(config_path) in cm.get("data", {})
        check(found, f"{name}: --config {config_path} is not a key of a mounted ConfigMap")
        conf = ""
        for (kind, _), o in objects.items():
            if kind == "ConfigMap":
                conf += o.get("data", {}).get(os.path.basename(config_path), "")
        check("--shared-sessions" in config_arg or
              re.search(r"^\s*shared[_-]sessions\s*=\s*true\s*$", conf, re.M),
              f"{name}: replicas on one volume need shared_sessions = true (or --shared-sessions)")
    return grpc_port


def check_services(objects, pods):
    for (kind, name), svc in objects.items():
        if kind != "Service":
            continue
        selector = svc["spec"].get("selector", {})
        targets = [(w, pod) for w, (labels, pod) in pods.items() if matches(selector, labels)]
        if not check(targets, f"Service {name}: selector {selector} matches no pod template"):
            continue
        for port in svc["spec"].get("ports", []):
            target = port.get("targetPort", port.get("port"))
            for w, pod in targets:
                check(container_port(pod, target) is not None,
                      f"Service {name}: port {port.get('name')} targets {target}, "
                      f"not a container port of {w}")


def check_service_monitors(objects):
    monitors = [o for (k, _), o in objects.items() if k == "ServiceMonitor"]
    check(monitors, "deploy/k8s: no ServiceMonitor")
    for mon in monitors:
        name = mon["metadata"]["name"]
        selector = mon["spec"].get("selector", {}).get("matchLabels", {})
        services = [o for (k, _), o in objects.items()
                    if k == "Service" and matches(selector, o["metadata"].get("labels", {}))]
        if not check(services, f"ServiceMonitor {name}: selects no Service"):
            continue
        for ep in mon["spec"].get("endpoints", []):
            for svc in services:
                check(ep.get("port") in {p.get("name") for p in svc["spec"].get("ports", [])},
                      f"ServiceMonitor {name}: port {ep.get('port')} is not a port name of "
                      f"Service {svc['metadata']['name']}")
        yield [s["metadata"]["name"] for s in services]


def find_key(node, key):
    """Every value stored under `key` anywhere in a parsed YAML tree."""
    if isinstance(node, dict):
        for k, v in node.items():
            if k == key:
                yield v
            yield from find_key(v, key)
    elif isinstance(node, list):
        for v in node:
            yield from find_key(v, key)


def generated_config_maps():
    """The ConfigMaps that deploy/haproxy/kustomization.yaml generates, as kustomize would."""
    out = {}
    path = os.path.join(HAPROXY, "kustomization.yaml")
    if not check(os.path.exists(path), "deploy/haproxy/kustomization.yaml missing"):
        return out
    with open(path) as f:
        k = yaml.safe_load(f) or {}
    for gen in k.get("configMapGenerator", []):
        data = {}
        for name in gen.get("files", []):
            with open(os.path.join(HAPROXY, name)) as f:
                data[os.path.basename(name)] = f.read()
        check(gen.get("options", {}).get("disableNameSuffixHash"),
              f"deploy/haproxy: ConfigMap {gen.get('name')} needs disableNameSuffixHash (the "
              "Deployment names it)")
        out[("ConfigMap", gen.get("name"))] = {"kind": "ConfigMap", "apiVersion": "v1",
                                                "metadata": {"name": gen.get("name")},
                                                "data": data}
    return out


def check_haproxy(objects, pods, sts, grpc_port):
    configs = [(name, o) for (k, name), o in objects.items()
               if k == "ConfigMap" and "haproxy.cfg" in o.get("data", {})]
    if not check(configs, "deploy/k8s: no ConfigMap with haproxy.cfg"):
        return
    cm_name, cm = configs[0]
    w = "deploy/haproxy/haproxy.cfg"
    text = cm["data"]["haproxy.cfg"]
    lines = [ln.split("#")[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    sections, current = {}, None
    for ln in lines:
        head = ln.split()[0]
        if head in ("global", "defaults", "frontend", "backend", "listen", "resolvers"):
            current = " ".join(ln.split()[:2])
            sections[current] = []
        elif current:
            sections[current].append(ln)
    fronts = {k: v for k, v in sections.items() if k.startswith("frontend")}
    backs = {k: v for k, v in sections.items() if k.startswith("backend")}
    grpc_front = [v for v in fronts.values() if any("proto h2" in ln for ln in v if
                                                     ln.startswith("bind"))]
    check(grpc_front, f"{w}: no frontend binds with `proto h2` (gRPC is HTTP/2)")
    if not check(len(backs) == 1, f"{w}: expected one backend, got {sorted(backs)}"):
        return
    back = list(backs.values())[0]
    check("balance hdr(x-robot-id)" in back, f"{w}: backend must `balance hdr(x-robot-id)`")
    check("hash-type consistent" in back, f"{w}: backend needs `hash-type consistent`")
    defaults = " ".join(ln for ln in back if ln.startswith("default-server"))
    servers = [ln.split() for ln in back if ln.startswith("server ")]
    for srv in servers:
        opts = " ".join(srv[3:]) + " " + defaults
        check(" proto h2" in " " + opts, f"{w}: server {srv[1]} must speak h2 (proto h2)")
        check(re.search(r"(^|\s)check(\s|$)", opts), f"{w}: server {srv[1]} has no health check")
        check("id" in srv, f"{w}: server {srv[1]} needs a fixed id (its place on the ring)")

    # The Deployment that runs it: mounts the ConfigMap, exposes the front port, and names one
    # replica per server line.
    deployments = [(wn, pod) for wn, (_, pod) in pods.items() if wn.startswith("Deployment ") and
                   any(v.get("configMap", {}).get("name") == cm_name for v in pod.get("volumes", []))]
    if not check(deployments, f"{w}: no Deployment mounts ConfigMap {cm_name}"):
        return
    wn, pod = deployments[0]
    env = {e["name"]: str(e.get("value", "")) for c in pod.get("containers", [])
           for e in c.get("env", [])}
    bind = env.get("RIM_PROXY_BIND", "")
    check(bind and container_port(pod, int(bind.rsplit(":", 1)[1])) is not None,
          f"{wn}: RIM_PROXY_BIND {bind!r} is not a container port")
    if sts is None:
        return
    sts_name = sts["metadata"]["name"]
    ns = sts["metadata"].get("namespace", "default")
    svc = sts["spec"].get("serviceName")
    replicas = int(sts["spec"].get("replicas", 1))
    check(len(servers) == replicas, f"{w}: {len(servers)} servers for a StatefulSet of "
          f"{replicas} replicas")
    for i, srv in enumerate(servers):
        var = re.fullmatch(r'"?\$\{(\w+)\}"?', srv[2])
        if not check(var, f"{w}: server {srv[1]} address must come from the environment"):
            continue
        want = f"{sts_name}-{i}.{svc}.{ns}.svc.cluster.local:{grpc_port}"
        check(env.get(var.group(1)) == want, f"{wn}: {var.group(1)} is {env.get(var.group(1))!r}, "
              f"expected the StatefulSet's pod {want}")
    haproxy = shutil.which("haproxy") or "/usr/sbin/haproxy"
    if os.access(haproxy, os.X_OK):
        with tempfile.NamedTemporaryFile("w", suffix=".cfg") as f:
            f.write(text)
            f.flush()
            run_env = dict(os.environ, **env)
            run_env.update(RIM_PROXY_BIND="127.0.0.1:50051", RIM_PROXY_STATS_BIND="127.0.0.1:8404")
            out = subprocess.run([haproxy, "-c", "-f", f.name], env=run_env,
                                 capture_output=True, text=True)
            check(out.returncode == 0, f"{w}: haproxy -c failed: {out.stdout}{out.stderr}")
    else:
        print("check_deploy_yaml: haproxy not found, `haproxy -c` not run")


def check_kubernetes(docs, rim_job):
    objects = {}
    for path, ds in docs.items():
        if not path.startswith(K8S + os.sep) or os.path.basename(path) == "kustomization.yaml":
            continue
        for d in ds:
            kind, meta = d.get("kind"), d.get("metadata", {})
            where = f"{rel(path)}: {kind} {meta.get('name')}"
            if not check(kind in API_VERSIONS, f"{where}: unexpected kind"):
                continue
            check(d.get("apiVersion") == API_VERSIONS[kind],
                  f"{where}: apiVersion must be {API_VERSIONS[kind]}, is {d.get('apiVersion')}")
            check(meta.get("name"), f"{where}: no metadata.name")
            check(kind == "Namespace" or meta.get("namespace"), f"{where}: no metadata.namespace")
            check((kind, meta.get("name")) not in objects, f"{where}: defined twice")
            objects[(kind, meta.get("name"))] = d

    objects.update(generated_config_maps())
    kustomization = os.path.join(K8S, "kustomization.yaml")
    if check(kustomization in docs, "deploy/k8s/kustomization.yaml missing"):
        resources = docs[kustomization][0].get("resources", [])
        check("../haproxy" in resources, "kustomization.yaml must include ../haproxy (the "
              "ConfigMap generated from haproxy.cfg)")
        listed = {r for r in resources if not r.startswith("../")}
        present = {os.path.basename(p) for p in docs if p.startswith(K8S + os.sep)} - {
            "kustomization.yaml"}
        check(listed == present, f"kustomization.yaml resources {sorted(listed)} differ from the "
              f"manifests {sorted(present)}")

        kubectl = shutil.which("kubectl")
        if kubectl:  # kustomize runs offline; no cluster needed
            out = subprocess.run([kubectl, "kustomize", K8S], capture_output=True, text=True)
            check(out.returncode == 0, f"kubectl kustomize deploy/k8s failed: {out.stderr.strip()}")
            if out.returncode == 0:
                built = {(d.get("kind"), d.get("metadata", {}).get("name")): d
                         for d in yaml.safe_load_all(out.stdout) if d}
                for key, cm in generated_config_maps().items():
                    check(built.get(key, {}).get("data") == cm["data"],
                          f"kubectl kustomize: {key[1]} differs from deploy/haproxy's files")
        else:
            print("check_deploy_yaml: kubectl not found, `kubectl kustomize` not run")

    for kind in ("StatefulSet", "Service", "Deployment", "ConfigMap", "ServiceMonitor"):
        check(any(k == kind for k, _ in objects), f"deploy/k8s: no {kind}")

    pods = {}
    for (kind, name), o in objects.items():
        if kind in ("StatefulSet", "Deployment"):
            pods[f"{kind} {name}"] = check_workload(o, objects)
    check_services(objects, pods)
    for monitored in check_service_monitors(objects):
        # The Prometheus Operator names the job after the Service.
        check(rim_job in monitored, f"ServiceMonitor: job would be {monitored}, the alert rules "
              f"watch job={rim_job!r}")
    sts_list = [o for (k, _), o in objects.items() if k == "StatefulSet"]
    sts = sts_list[0] if sts_list else None
    grpc_port = check_rim_statefulset(sts, objects) if sts else None
    check_haproxy(objects, pods, sts, grpc_port)


def main():
    docs = load_yaml_files()
    families = documented_families()
    allowed = series_names(families)
    uid, url, dash_dir = grafana_provisioning(docs)
    check_dashboard(os.path.join(DEPLOY, "grafana", "rim-dashboard.json"), uid, allowed, families)
    rim_job = check_rules(docs, allowed)
    targets = check_prometheus_config(docs, rim_job)
    check_compose(docs, targets, url, dash_dir)
    check_kubernetes(docs, rim_job)
    if errors:
        print(f"check_deploy_yaml: {len(errors)} problem(s):")
        for e in errors:
            print("  - " + e)
        return 1
    print(f"check_deploy_yaml: OK ({len(docs)} YAML files, {len(families)} metric families)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
