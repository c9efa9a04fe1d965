#!/usr/bin/python3
"""Checks Kubernetes manifests against the Kubernetes API types (Debian's python3-kubernetes
models: every field name and its type, recursively, and the required fields), then Exoview's own
rules: every container has requests and limits, a non-root read-only root file system and no
privilege escalation; every long-running Exoview container has readiness and liveness probes;
every Service selects a workload of the set; the HPA targets a Deployment of the set.

  deploy/k8s/check_manifests.py FILE.yaml...     exit 0 = all valid, 1 = errors (listed)
  deploy/k8s/check_manifests.py --self-test      the checker must reject broken manifests

The models of python3-kubernetes 22.6 are Kubernetes 1.22: autoscaling/v2 (GA in 1.23, the
only HPA version of current clusters) is checked against the autoscaling/v2beta2 model, whose
fields are the same. Exit 77 (ctest: skipped) when python3-kubernetes or PyYAML is missing.
"""
import datetime
import re
import sys

try:
    import yaml
    import kubernetes.client.models as models
    from kubernetes.client import ApiClient
except ImportError as e:  # pragma: no cover
    print(f"SKIP: {e} (apt-get install python3-kubernetes python3-yaml)")
    sys.exit(77)

KINDS = {
    ("v1", "Secret"): "V1Secret",
    ("v1", "ConfigMap"): "V1ConfigMap",
    ("v1", "Service"): "V1Service",
    ("v1", "Pod"): "V1Pod",
    ("v1", "PersistentVolumeClaim"): "V1PersistentVolumeClaim",
    ("apps/v1", "Deployment"): "V1Deployment",
    ("apps/v1", "StatefulSet"): "V1StatefulSet",
    ("autoscaling/v2", "HorizontalPodAutoscaler"): "V2beta2HorizontalPodAutoscaler",
    ("autoscaling/v2beta2", "HorizontalPodAutoscaler"): "V2beta2HorizontalPodAutoscaler",
}
PRIMITIVES = {"str": str, "int": int, "bool": bool, "float": (int, float), "object": object}


def check_type(value, type_name, path, errors):
    """Field names and value types of `value` against the model type `type_name`."""
    if value is None:
        return
    m = re.fullmatch(r"list\[(.+)\]", type_name)
    if m:
        if not isinstance(value, list):
            errors.append(f"{path}: expected a list, got {type(value).__name__}")
            return
        for i, v in enumerate(value):
            check_type(v, m.group(1), f"{path}[{i}]", errors)
        return
    m = re.fullmatch(r"dict\(str, (.+)\)", type_name)
    if m:
        if not isinstance(value, dict):
            errors.append(f"{path}: expected a map, got {type(value).__name__}")
            return
        for k, v in value.items():
            check_type(v, m.group(1), f"{path}.{k}", errors)
        return
    if type_name in PRIMITIVES:
        t = PRIMITIVES[type_name]
        if type_name == "int" and isinstance(value, bool) or not isinstance(value, t):
            errors.append(f"{path}: expected {type_name}, got {type(value).__name__} {value!r}")
        return
    if type_name in ("datetime", "date"):
        if not isinstance(value, (str, datetime.date)):
            errors.append(f"{path}: expected a time")
        return
    klass = getattr(models, type_name, None)
    if klass is None:
        errors.append(f"{path}: unknown model type {type_name}")
        return
    if type_name == "IntOrString" or klass.openapi_types == {}:
        return
    if not isinstance(value, dict):
        errors.append(f"{path}: expected an object ({type_name}), got {type(value).__name__}")
        return
    by_json = {j: a for a, j in klass.attribute_map.items()}
    for key, v in value.items():
        if key not in by_json:
            errors.append(f"{path}.{key}: unknown field of {type_name}")
            continue
        check_type(v, klass.openapi_types[by_json[key]], f"{path}.{key}", errors)


def containers_of(doc):
    spec = doc.get("spec", {})
    if doc["kind"] in ("Deployment", "StatefulSet"):
        spec = spec.get("template", {}).get("spec", {})
    elif doc["kind"] != "Pod":
        return []
    return spec.get("containers", []) + spec.get("initContainers", [])


def pod_labels(doc):
    if doc["kind"] == "Pod":
        return doc.get("metadata", {}).get("labels", {})
    if doc["kind"] in ("Deployment", "StatefulSet"):
        return doc["spec"]["template"]["metadata"].get("labels", {})
    return None


def check_docs(docs):
    """[(file, doc)] -> list of error strings."""
    errors = []
    api = ApiClient()
    for path, doc in docs:
        where = f"{path}: {doc.get('kind')} {doc.get('metadata', {}).get('name')}"
        key = (doc.get("apiVersion"), doc.get("kind"))
        if key not in KINDS:
            errors.append(f"{where}: apiVersion/kind {key} is not one this set uses")
            continue
        n = len(errors)
        check_type(doc, KINDS[key], where, errors)
        if len(errors) == n:
            try:  # the model constructors check required fields and enums
                api._ApiClient__deserialize(doc, KINDS[key])
            except (ValueError, TypeError) as e:
                errors.append(f"{where}: {e}")
        for c in containers_of(doc):
            cw = f"{where} container {c.get('name')}"
            res = c.get("resources", {})
            for part in ("requests", "limits"):
                for r in ("cpu", "memory"):
                    if r not in res.get(part, {}):
                        errors.append(f"{cw}: resources.{part}.{r} missing")
            sc = c.get("securityContext", {})
            if sc.get("readOnlyRootFilesystem") is not True:
                errors.append(f"{cw}: securityContext.readOnlyRootFilesystem must be true")
            if sc.get("allowPrivilegeEscalation") is not False:
                errors.append(f"{cw}: securityContext.allowPrivilegeEscalation must be false")
            pod_spec = doc["spec"] if doc["kind"] == "Pod" else doc["spec"]["template"]["spec"]
            if not (sc.get("runAsNonRoot") or pod_spec.get("securityContext", {}).get("runAsNonRoot")):
                errors.append(f"{cw}: runAsNonRoot must be true (pod or container)")
            long_running = doc["kind"] != "Pod" or pod_spec.get("restartPolicy", "Always") == "Always"
            if long_running and "exoview" in str(c.get("image", "")) + str(c.get("name", "")):
                for probe in ("readinessProbe", "livenessProbe"):
                    if probe not in c:
                        errors.append(f"{cw}: {probe} missing")
    # Services select something; the HPA targets a Deployment of the set.
    workloads = [(d.get("metadata", {}).get("name"), d["kind"], pod_labels(d)) for _, d in docs]
    for path, d in docs:
        if d.get("kind") == "Service":
            sel = d.get("spec", {}).get("selector") or {}
            if not any(l and all(l.get(k) == v for k, v in sel.items()) for _, _, l in workloads):
                errors.append(f"{path}: Service {d['metadata']['name']} selects no workload {sel}")
        if d.get("kind") == "HorizontalPodAutoscaler":
            ref = d["spec"]["scaleTargetRef"]
            if (ref["name"], ref["kind"]) not in [(n, k) for n, k, _ in workloads]:
                errors.append(f"{path}: HPA target {ref['kind']}/{ref['name']} is not in the set")
    return errors


def load(paths):
    docs = []
    for p in paths:
        with open(p) as f:
            try:
                for d in yaml.safe_load_all(f):
                    if d:
                        docs.append((p, d))
            except yaml.YAMLError as e:
                print(f"ERROR {p}: not valid YAML: {e}")
                sys.exit(1)
    return docs


def self_test(paths):
    """Each mutation of a valid set must be reported: the check cannot pass vacuously."""
    import copy
    base = load(paths)
    assert not check_docs(base), "the base set must be valid for the self-test"

    def first(kind):
        return next(i for i, (_, d) in enumerate(base) if d["kind"] == kind)

    def mutated(kind, change):
        docs = copy.deepcopy(base)
        change(docs[first(kind)][1])
        return docs

    cases = {
        "misspelled field": mutated("StatefulSet", lambda d: d["spec"].__setitem__("replica", 2)),
        "wrong type": mutated("Deployment", lambda d: d["spec"].__setitem__("replicas", "two")),
        "unknown nested field": mutated("Deployment", lambda d: d["spec"]["template"]["spec"]
                                        ["containers"][0].__setitem__("imagePullPolicyy", "x")),
        "missing required field": mutated("Service", lambda d: d["spec"]["ports"][0].pop("port")),
        "no limits": mutated("Deployment", lambda d: d["spec"]["template"]["spec"]["containers"]
                             [0]["resources"].pop("limits")),
        "no readiness probe": mutated("StatefulSet", lambda d: [c.pop("readinessProbe", None) for c in
                                      d["spec"]["template"]["spec"]["containers"]]),
        "writable root": mutated("Deployment", lambda d: d["spec"]["template"]["spec"]["containers"]
                                 [0]["securityContext"].__setitem__("readOnlyRootFilesystem", False)),
        "service selects nothing": mutated("Service", lambda d: d["spec"].__setitem__(
            "selector", {"app.kubernetes.io/name": "nothing"})),
        "hpa without target": mutated("HorizontalPodAutoscaler", lambda d: d["spec"]
                                      ["scaleTargetRef"].__setitem__("name", "nothing")),
    }
    failed = 0
    for name, docs in cases.items():
        errs = check_docs(docs)
        print(f"self-test {name}: {'rejected' if errs else 'ACCEPTED (checker is broken)'}"
              + (f" ({errs[0]})" if errs else ""))
        failed += not errs
    return failed


def main():
    args = sys.argv[1:]
    if args and args[0] == "--self-test":
        sys.exit(1 if self_test(args[1:]) else 0)
    docs = load(args)
    errors = check_docs(docs)
    for e in errors:
        print("ERROR", e)
    kinds = {}
    for _, d in docs:
        kinds[d["kind"]] = kinds.get(d["kind"], 0) + 1
    print(f"{len(docs)} manifests in {len(args)} files ({', '.join(f'{v} {k}' for k, v in sorted(kinds.items()))}): "
          f"{'all valid' if not errors else f'{len(errors)} errors'}")
    sys.exit(1 if errors else 0)


if __name__ == "__main__":
    main()
