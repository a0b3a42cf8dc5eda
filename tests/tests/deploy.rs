//! The deployment files parse and carry what the farm needs: the Kubernetes
//! manifests in `deploy/k8s/` (coordinator with a persistent volume, a
//! Service and gRPC probes; workers with gRPC probes, resource requests and a
//! grace period long enough to hand back a lease) and `deploy/docker-compose.yml`
//! (coordinator published on 127.0.0.1 only, workers that scale). The compose
//! farm itself is exercised for real by `deploy/compose-test.sh`.

use serde::Deserialize;
use serde_yaml::Value;
use std::path::{Path, PathBuf};

fn deploy_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

/// Every document of every `.yaml` file in `deploy/k8s/`, with its file name.
fn k8s_docs() -> Vec<(String, Value)> {
    let dir = deploy_dir().join("k8s");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("yaml" | "yml")))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no manifests in {}", dir.display());
    let mut docs = Vec::new();
    for f in files {
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(&f).unwrap();
        for de in serde_yaml::Deserializer::from_str(&text) {
            let v = Value::deserialize(de).unwrap_or_else(|e| panic!("{name}: {e}"));
            if !v.is_null() {
                docs.push((name.clone(), v));
            }
        }
    }
    docs
}

/// `v` at a dotted path (`spec.template.spec`); numeric parts index lists.
fn at<'a>(v: &'a Value, path: &str) -> Option<&'a Value> {
    path.split('.')
        .try_fold(v, |v, key| match key.parse::<usize>() {
            Ok(i) => v.as_sequence()?.get(i),
            Err(_) => v.get(key),
        })
}

fn str_at<'a>(v: &'a Value, path: &str) -> &'a str {
    at(v, path).and_then(Value::as_str).unwrap_or_else(|| {
        panic!(
            "no string at {path} in {}",
            serde_yaml::to_string(v).unwrap()
        )
    })
}

fn seq_at<'a>(v: &'a Value, path: &str) -> &'a Vec<Value> {
    at(v, path)
        .and_then(Value::as_sequence)
        .unwrap_or_else(|| panic!("no list at {path}"))
}

fn find<'a>(docs: &'a [(String, Value)], kinds: &[&str], component: &str) -> &'a Value {
    let hits: Vec<&Value> = docs
        .iter()
        .map(|(_, d)| d)
        .filter(|d| {
            kinds.contains(&str_at(d, "kind"))
                && at(d, "metadata.labels")
                    .and_then(|l| l.get("app.kubernetes.io/component"))
                    .and_then(Value::as_str)
                    == Some(component)
        })
        .collect();
    assert_eq!(
        hits.len(),
        1,
        "expected one {kinds:?} labelled component={component}"
    );
    hits[0]
}

fn container<'a>(workload: &'a Value, name: &str) -> &'a Value {
    seq_at(workload, "spec.template.spec.containers")
        .iter()
        .find(|c| c.get("name").and_then(Value::as_str) == Some(name))
        .unwrap_or_else(|| panic!("no container {name}"))
}

fn env<'a>(c: &'a Value, name: &str) -> Option<&'a Value> {
    c.get("env")?
        .as_sequence()?
        .iter()
        .find(|e| e.get("name").and_then(Value::as_str) == Some(name))
}

/// A probe that asks grpc.health.v1: Kubernetes' own `grpc` probe on `port`,
/// or an exec of the image's `trevi-health` probe.
fn assert_grpc_probe(c: &Value, which: &str, port: Option<u64>) {
    let p = c
        .get(which)
        .unwrap_or_else(|| panic!("container {} has no {which}", str_at(c, "name")));
    if let Some(g) = p.get("grpc") {
        let got = g.get("port").and_then(Value::as_u64);
        assert_eq!(got, port, "{which}: gRPC probe on the wrong port");
    } else {
        let cmd = seq_at(p, "exec.command")
            .iter()
            .map(|s| s.as_str().unwrap())
            .collect::<Vec<_>>()
            .join(" ");
        assert!(
            cmd.contains("trevi-health"),
            "{which} is neither a grpc probe nor trevi-health: {cmd}"
        );
    }
}

fn labels_match(selector: &Value, labels: &Value) -> bool {
    selector
        .as_mapping()
        .unwrap()
        .iter()
        .all(|(k, v)| labels.get(k.as_str().unwrap()) == Some(v))
}

#[test]
fn every_manifest_parses_and_names_itself() {
    let docs = k8s_docs();
    for (file, d) in &docs {
        let keys: &[&str] = if file == "kustomization.yaml" {
            &["apiVersion", "kind"]
        } else {
            &["apiVersion", "kind", "metadata.name"]
        };
        for &key in keys {
            assert!(
                at(d, key).and_then(Value::as_str).is_some(),
                "{file}: a document has no {key}"
            );
        }
    }
    // kustomization.yaml lists every other manifest.
    let (_, kust) = docs
        .iter()
        .find(|(_, d)| at(d, "kind").and_then(Value::as_str) == Some("Kustomization"))
        .expect("deploy/k8s/kustomization.yaml");
    let listed: Vec<&str> = seq_at(kust, "resources")
        .iter()
        .map(|r| r.as_str().unwrap())
        .collect();
    for (file, _) in &docs {
        if file != "kustomization.yaml" {
            assert!(
                listed.contains(&file.as_str()),
                "{file} is not in kustomization.yaml"
            );
        }
    }
}

#[test]
fn coordinator_has_a_volume_a_service_and_grpc_probes() {
    let docs = k8s_docs();
    let sts = find(&docs, &["StatefulSet", "Deployment"], "coordinator");
    assert_eq!(at(sts, "spec.replicas").and_then(Value::as_u64), Some(1));
    let pod_labels = at(sts, "spec.template.metadata.labels").unwrap();
    assert!(labels_match(
        at(sts, "spec.selector.matchLabels").unwrap(),
        pod_labels
    ));
    let c = container(sts, "coordinator");

    // The data directory is a persistent volume.
    let args: Vec<&str> = seq_at(c, "args")
        .iter()
        .map(|a| a.as_str().unwrap())
        .collect();
    let data_dir = args[args.iter().position(|a| *a == "--data-dir").unwrap() + 1];
    let mount = seq_at(c, "volumeMounts")
        .iter()
        .find(|m| str_at(m, "mountPath") == data_dir)
        .expect("the data directory is mounted");
    let vol = str_at(mount, "name");
    let claimed_by_template = at(sts, "spec.volumeClaimTemplates").is_some_and(|t| {
        t.as_sequence().unwrap().iter().any(|t| {
            str_at(t, "metadata.name") == vol && at(t, "spec.resources.requests.storage").is_some()
        })
    });
    let claimed_by_pvc = at(sts, "spec.template.spec.volumes").is_some_and(|vs| {
        vs.as_sequence().unwrap().iter().any(|v| {
            str_at(v, "name") == vol
                && at(v, "persistentVolumeClaim.claimName")
                    .and_then(Value::as_str)
                    .is_some_and(|claim| {
                        docs.iter().any(|(_, d)| {
                            str_at(d, "kind") == "PersistentVolumeClaim"
                                && str_at(d, "metadata.name") == claim
                        })
                    })
        })
    });
    assert!(
        claimed_by_template || claimed_by_pvc,
        "the volume {vol} at {data_dir} is not a PersistentVolumeClaim"
    );

    // gRPC probes on the port it listens on.
    let listen = args[args.iter().position(|a| *a == "--listen").unwrap() + 1];
    let port: u64 = listen.rsplit(':').next().unwrap().parse().unwrap();
    assert!(seq_at(c, "ports")
        .iter()
        .any(|p| at(p, "containerPort").and_then(Value::as_u64) == Some(port)));
    assert_grpc_probe(c, "readinessProbe", Some(port));
    assert_grpc_probe(c, "livenessProbe", Some(port));
    assert!(at(c, "resources.requests.cpu").is_some());
    assert!(at(c, "resources.requests.memory").is_some());

    // A Service selects its pods on that port.
    let svc = find(&docs, &["Service"], "coordinator");
    assert!(labels_match(at(svc, "spec.selector").unwrap(), pod_labels));
    let sp = &seq_at(svc, "spec.ports")[0];
    assert_eq!(at(sp, "port").and_then(Value::as_u64), Some(port));
    if str_at(sts, "kind") == "StatefulSet" {
        assert_eq!(
            str_at(sts, "spec.serviceName"),
            str_at(svc, "metadata.name")
        );
    }
}

#[test]
fn workers_find_the_coordinator_probe_it_and_have_time_to_return_leases() {
    let docs = k8s_docs();
    let dep = find(&docs, &["Deployment"], "worker");
    assert!(labels_match(
        at(dep, "spec.selector.matchLabels").unwrap(),
        at(dep, "spec.template.metadata.labels").unwrap()
    ));
    let c = container(dep, "worker");
    assert_eq!(
        seq_at(c, "command")[0].as_str(),
        Some("trevi-worker"),
        "the worker container runs trevi-worker"
    );

    // TREVI_COORDINATOR names the coordinator's Service and port.
    let svc = find(&docs, &["Service"], "coordinator");
    let url = str_at(
        env(c, "TREVI_COORDINATOR").expect("TREVI_COORDINATOR"),
        "value",
    );
    let port = at(&seq_at(svc, "spec.ports")[0], "port")
        .and_then(Value::as_u64)
        .unwrap();
    assert_eq!(
        url,
        format!("http://{}:{port}", str_at(svc, "metadata.name")),
        "TREVI_COORDINATOR"
    );

    assert_grpc_probe(c, "readinessProbe", None);
    assert_grpc_probe(c, "livenessProbe", None);
    for r in ["cpu", "memory"] {
        assert!(
            at(c, &format!("resources.requests.{r}")).is_some(),
            "the worker requests no {r}"
        );
    }
    // On SIGTERM a worker finishes the tile in hand and sends it: give it
    // well over Kubernetes' default 30 s.
    let grace = at(dep, "spec.template.spec.terminationGracePeriodSeconds")
        .and_then(Value::as_u64)
        .expect("terminationGracePeriodSeconds");
    assert!(grace >= 60, "terminationGracePeriodSeconds {grace} < 60");
}

/// Every document of every `.yaml` file in `deploy/k8s/autoscale/`.
fn autoscale_docs() -> Vec<(String, Value)> {
    let dir = deploy_dir().join("k8s/autoscale");
    let mut docs = Vec::new();
    for e in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let f = e.unwrap().path();
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(&f).unwrap();
        for de in serde_yaml::Deserializer::from_str(&text) {
            let v = Value::deserialize(de).unwrap_or_else(|e| panic!("{name}: {e}"));
            if !v.is_null() {
                docs.push((name.clone(), v));
            }
        }
    }
    docs
}

#[test]
fn workers_scale_with_the_queue_depth_the_coordinator_exports() {
    let base = k8s_docs();
    let docs = autoscale_docs();
    // The overlay is the farm plus its ScaledObject.
    let (_, kust) = docs
        .iter()
        .find(|(f, _)| f == "kustomization.yaml")
        .expect("deploy/k8s/autoscale/kustomization.yaml");
    let resources: Vec<&str> = seq_at(kust, "resources")
        .iter()
        .map(|r| r.as_str().unwrap())
        .collect();
    assert!(resources.contains(&".."), "{resources:?}");
    for (f, _) in docs.iter().filter(|(f, _)| f != "kustomization.yaml") {
        assert!(resources.contains(&f.as_str()), "{f} is not in the overlay");
    }
    let so = docs
        .iter()
        .map(|(_, d)| d)
        .find(|d| str_at(d, "kind") == "ScaledObject")
        .expect("a KEDA ScaledObject");
    assert_eq!(str_at(so, "apiVersion"), "keda.sh/v1alpha1");

    // It scales the worker Deployment.
    let dep = find(&base, &["Deployment"], "worker");
    assert_eq!(str_at(so, "spec.scaleTargetRef.kind"), "Deployment");
    assert_eq!(
        str_at(so, "spec.scaleTargetRef.name"),
        str_at(dep, "metadata.name")
    );
    let min = at(so, "spec.minReplicaCount").and_then(Value::as_u64);
    let max = at(so, "spec.maxReplicaCount").and_then(Value::as_u64);
    assert!(
        matches!((min, max), (Some(a), Some(b)) if a < b),
        "min {min:?} max {max:?}"
    );

    // On trevi_queue_depth_tiles, read from the coordinator Service's HTTP
    // port, a metric the coordinator really exports.
    let t = seq_at(so, "spec.triggers")
        .iter()
        .find(|t| str_at(t, "type") == "metrics-api")
        .expect("a metrics-api trigger");
    assert_eq!(str_at(t, "metadata.format"), "prometheus");
    let metric = str_at(t, "metadata.valueLocation");
    assert_eq!(metric, "trevi_queue_depth_tiles");
    let exported = include_str!("../../coordinator/src/metrics.rs");
    assert!(
        exported.contains(&format!("\"{metric} {{}}\""))
            || exported.contains(&format!("\"{metric}\"")),
        "coordinator/src/metrics.rs does not write {metric}"
    );
    let svc = find(&base, &["Service"], "coordinator");
    let http = seq_at(svc, "spec.ports")
        .iter()
        .find(|p| str_at(p, "name") == "http")
        .and_then(|p| at(p, "port"))
        .and_then(Value::as_u64)
        .expect("the coordinator Service's http port");
    assert_eq!(
        str_at(t, "metadata.url"),
        format!("http://{}:{http}/metrics", str_at(svc, "metadata.name"))
    );
    let target: f64 = str_at(t, "metadata.targetValue").parse().unwrap();
    assert!(target > 0.0, "targetValue {target}");
}

#[test]
fn compose_publishes_on_loopback_only_and_workers_scale() {
    let path = deploy_dir().join("docker-compose.yml");
    let text = std::fs::read_to_string(&path).unwrap();
    let doc: Value = serde_yaml::from_str(&text).unwrap();
    let coord = at(&doc, "services.coordinator").expect("a coordinator service");
    let worker = at(&doc, "services.worker").expect("a worker service");

    // Published ports: 127.0.0.1 only, also in the default of any variable.
    for p in seq_at(coord, "ports") {
        let p = p.as_str().expect("ports in short syntax");
        let host = match p.strip_prefix("${") {
            Some(var) => var.split_once(":-").expect("a default").1,
            None => p,
        };
        assert!(
            host.starts_with("127.0.0.1:"),
            "port {p} is not on 127.0.0.1"
        );
    }
    assert!(worker.get("ports").is_none(), "workers publish no port");
    // Scaling needs no fixed name.
    assert!(worker.get("container_name").is_none());

    // The data directory is a named volume.
    let cmd: Vec<&str> = seq_at(coord, "command")
        .iter()
        .map(|a| a.as_str().unwrap())
        .collect();
    let data_dir = cmd[cmd.iter().position(|a| *a == "--data-dir").unwrap() + 1];
    let vol = seq_at(coord, "volumes")
        .iter()
        .map(|v| v.as_str().unwrap())
        .find(|v| v.ends_with(&format!(":{data_dir}")))
        .expect("a volume on the data directory");
    let vol_name = vol.split(':').next().unwrap();
    assert!(at(&doc, &format!("volumes.{vol_name}")).is_some());

    // Workers find the coordinator by TREVI_COORDINATOR and wait for it.
    assert_eq!(
        str_at(worker, "environment.TREVI_COORDINATOR"),
        "http://coordinator:50051"
    );
    assert_eq!(
        str_at(worker, "depends_on.coordinator.condition"),
        "service_healthy"
    );
    // Health checks through the gRPC health probe.
    for s in [coord, worker] {
        let test = seq_at(s, "healthcheck.test");
        assert!(test.iter().any(|t| t.as_str() == Some("trevi-health")));
    }
    assert!(deploy_dir().join("trevi-health").exists());
}
