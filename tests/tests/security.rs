//! Tokens, limits and hostile input against a real coordinator: every
//! refusal has its gRPC code and a clear message, and the coordinator keeps
//! serving honest clients afterwards.

mod common;

use common::fake_worker::{grey, tile_upload};
use common::*;
use std::path::Path;
use std::process::Command;
use tonic::Code;
use trevi_proto::pb;

const SUBMIT: &str = "submit-secret-1234";
const WORK: &str = "worker-secret-5678";

fn code<T: std::fmt::Debug>(r: Result<T, tonic::Status>) -> Code {
    match r {
        Ok(v) => panic!("expected an error, got {v:?}"),
        Err(s) => s.code(),
    }
}

#[test]
fn each_token_and_role_combination() {
    token_roles(&Dir::new(), None);
}

#[test]
fn each_token_and_role_combination_over_tls() {
    let dir = Dir::new();
    let Some(certs) = make_certs(&dir, "certs") else {
        return;
    };
    token_roles(&dir, Some(&certs));
}

/// Every token and role, on a plain coordinator or (with `certs`, made by
/// `deploy/make-certs.sh`) a TLS one, through gRPC clients and the real
/// programs.
fn token_roles(dir: &Dir, certs: Option<&Path>) {
    let scene = dir.write("s.xml", &tiny_scene(1));
    let expected = embedded(dir, &scene, "embedded.png");
    let token_file = dir.write("worker.token", &format!("{WORK}\n"));
    let certs = certs.map(|d| {
        let s = |f: &str| d.join(f).to_str().unwrap().to_string();
        (s("coordinator.pem"), s("coordinator.key"), s("ca.pem"))
    });
    let mut args = vec!["--worker-token-file", token_file.to_str().unwrap()];
    // What the worker and trevi-submit need to trust the coordinator.
    let mut client_tls: Vec<&str> = Vec::new();
    if let Some((cert, key, ca)) = &certs {
        args.extend(["--tls-cert", cert.as_str(), "--tls-key", key.as_str()]);
        client_tls.extend(["--tls-ca", ca.as_str()]);
    }
    let mut c = coordinator_with(
        dir,
        "127.0.0.1:0",
        "coordinator",
        &args,
        &[("TREVI_SUBMIT_TOKEN", SUBMIT)],
    );
    if let Some((_, _, ca)) = &certs {
        assert!(c.url.starts_with("https://localhost:"), "{}", c.url);
        c.tls.ca_file = Some(ca.into());
    }
    let rt = runtime();
    rt.block_on(async {
        let c = &c;
        let list = |t: Option<&'static str>| async move {
            jobs(c, t)
                .await
                .list_jobs(pb::ListJobsRequest::default())
                .await
                .map(|r| r.into_inner().jobs.len())
        };
        let register = |t: Option<&'static str>| async move {
            workers(c, t)
                .await
                .register(pb::RegisterRequest {
                    name: "t".into(),
                    threads: 1,
                    ..Default::default()
                })
                .await
                .map(|r| r.into_inner().worker_id)
        };
        // Jobs: the submit token only.
        assert_eq!(list(Some(SUBMIT)).await.unwrap(), 0);
        assert_eq!(code(list(None).await), Code::Unauthenticated);
        assert_eq!(code(list(Some("guess")).await), Code::Unauthenticated);
        let e = list(Some(WORK)).await.unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        assert!(e.message().contains("submit token"), "{}", e.message());
        // Workers: the worker token only.
        assert!(register(Some(WORK)).await.is_ok());
        assert_eq!(code(register(None).await), Code::Unauthenticated);
        assert_eq!(code(register(Some("guess")).await), Code::Unauthenticated);
        assert_eq!(code(register(Some(SUBMIT)).await), Code::PermissionDenied);
        // Bundles: submitters upload, workers only download.
        let bytes = bundle_of(&tiny_scene(2)).encode();
        let mut wb = bundles(c, Some(WORK)).await;
        assert_eq!(
            code(upload(&mut wb, vec![bytes.clone()]).await),
            Code::PermissionDenied
        );
        let mut nb = bundles(c, None).await;
        assert_eq!(
            code(upload(&mut nb, vec![bytes.clone()]).await),
            Code::Unauthenticated
        );
        let mut sb = bundles(c, Some(SUBMIT)).await;
        let hash = upload(&mut sb, vec![bytes.clone()]).await.unwrap();
        let mut got = Vec::new();
        let mut s = wb
            .download_bundle(pb::BundleRef {
                hash: hash.clone(),
                size: 0,
            })
            .await
            .unwrap()
            .into_inner();
        while let Some(chunk) = s.message().await.unwrap() {
            got.extend_from_slice(&chunk.data);
        }
        assert_eq!(got, bytes);
        assert_eq!(
            code(
                nb.download_bundle(pb::BundleRef { hash, size: 0 })
                    .await
                    .map(|_| ())
            ),
            Code::Unauthenticated
        );
        // Health stays open.
        use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
        let r = HealthClient::new(channel(c).await)
            .check(HealthCheckRequest {
                service: "trevi.v1.Jobs".into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.status, 1);
    });
    // The real programs with their tokens render the same bytes.
    let _w = worker_with(
        dir,
        &c.url,
        "worker",
        &client_tls,
        &[("TREVI_WORKER_TOKEN", WORK)],
    );
    let out = dir.path().join("farm.png");
    let mut args = vec![
        scene.to_str().unwrap(),
        "--coordinator",
        &c.url,
        "-o",
        out.to_str().unwrap(),
        "--tile",
        "16",
    ];
    args.extend(&client_tls);
    let o = submit_env(dir, &args, &[("TREVI_SUBMIT_TOKEN", SUBMIT)]);
    assert!(o.status.success(), "{}", dir.logs());
    assert!(std::fs::read(&out).unwrap() == expected);
    // Without a token, or with the worker's, trevi-submit is told why.
    let o = submit(dir, &args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("token"), "{err}");
    let o = submit_env(dir, &args, &[("TREVI_SUBMIT_TOKEN", WORK)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("PermissionDenied"),
        "{err}"
    );
    // A worker with the submit token gets no work (and says why).
    let mut bad_args = vec!["--token", SUBMIT];
    bad_args.extend(&client_tls);
    let _bad = worker_with(dir, &c.url, "badworker", &bad_args, &[]);
    wait_for(dir, "the refused worker to log", 30, || {
        dir.read_log("badworker").contains("worker token")
    });
}

/// A scene made to blow up an XML parser that expands entities.
const LAUGHS: &str = r#"<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
 <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
 <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
 <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
 <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
 <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
 <!ENTITY xxe SYSTEM "file:///etc/passwd">
]>
<scene version="1">
  <camera id="&lol9;&xxe;" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="8" height="8" output="o.png"/>
  </camera>
</scene>
"#;

#[test]
fn hostile_input_gets_its_error_and_the_coordinator_keeps_serving() {
    let dir = Dir::new();
    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &[
            "--max-bundle-mib",
            "1",
            "--max-bundle-files",
            "3",
            "--max-image-samples",
            "100000",
            "--max-jobs-per-submitter",
            "3",
        ],
        &[],
    );
    let rt = runtime();
    rt.block_on(async {
        let mut b = bundles(&c, None).await;
        let mut j = jobs(&c, None).await;
        let w = workers(&c, None).await;

        // A bundle over the size limit, sent in legal chunks.
        let big = vec![vec![7u8; 600 << 10], vec![7u8; 600 << 10]];
        let e = upload(&mut b, big).await.unwrap_err();
        assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
        assert!(e.message().contains("limit"), "{}", e.message());
        // One message over the message size limit.
        let e = upload(&mut b, vec![vec![1u8; 6 << 20]]).await.unwrap_err();
        assert!(
            matches!(e.code(), Code::ResourceExhausted | Code::OutOfRange),
            "{e:?}"
        );
        // Too many files.
        let mut many = bundle_of(&tiny_scene(1));
        for i in 0..4 {
            many.files.insert(format!("f{i}.obj"), b"v 0 0 0".to_vec());
        }
        let e = upload(&mut b, vec![many.encode()]).await.unwrap_err();
        assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
        // A path outside the bundle; a truncated bundle; garbage.
        let mut sneaky = bundle_of(&tiny_scene(1));
        sneaky.files.insert("../x.obj".into(), b"v 0 0 0".to_vec());
        assert_eq!(
            code(upload(&mut b, vec![sneaky.encode()]).await),
            Code::InvalidArgument
        );
        let good = bundle_of(&tiny_scene(1)).encode();
        assert_eq!(
            code(upload(&mut b, vec![good[..good.len() - 5].to_vec()]).await),
            Code::InvalidArgument
        );
        assert_eq!(
            code(upload(&mut b, vec![b"not a bundle".to_vec()]).await),
            Code::InvalidArgument
        );
        // XML entity tricks: refused, not expanded, no file read.
        let hash = upload(&mut b, vec![bundle_of(LAUGHS).encode()])
            .await
            .unwrap();
        let e = j
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: hash,
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
        assert!(!e.message().contains("root:"), "{}", e.message());
        // A frame over the image limit.
        let huge =
            tiny_scene(1).replace(r#"width="24" height="20""#, r#"width="400" height="300""#);
        let hash = upload(&mut b, vec![bundle_of(&huge).encode()])
            .await
            .unwrap();
        let e = j
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: hash,
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
        assert!(e.message().contains("samples"), "{}", e.message());
        // Unknown bundle and job.
        let e = j
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: "ab".repeat(32),
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(e.code(), Code::NotFound);
        assert_eq!(
            code(
                j.get_job(pb::JobId {
                    id: 999,
                    frame: None
                })
                .await
            ),
            Code::NotFound
        );

        // A bundle damaged on the coordinator's disk is never served.
        let hash = upload(&mut b, vec![good.clone()]).await.unwrap();
        let path = c.data.join("bundles").join(&hash);
        let mut damaged = std::fs::read(&path).unwrap();
        let last = damaged.len() - 2;
        damaged[last] ^= 1;
        std::fs::write(&path, &damaged).unwrap();
        let r = async {
            let mut s = b
                .download_bundle(pb::BundleRef {
                    hash: hash.clone(),
                    size: 0,
                })
                .await?
                .into_inner();
            s.message().await
        }
        .await;
        assert_eq!(code(r), Code::InvalidArgument);
        assert_eq!(
            code(
                j.submit_job(pb::SubmitJobRequest {
                    bundle_hash: hash,
                    ..Default::default()
                })
                .await
            ),
            Code::InvalidArgument
        );

        // Tile results: a real job and a lease.
        let scene = tiny_scene(3);
        let hash = upload(&mut b, vec![bundle_of(&scene).encode()])
            .await
            .unwrap();
        let job = j
            .submit_job(pb::SubmitJobRequest {
                bundle_hash: hash.clone(),
                tile_size: 16,
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner()
            .id;
        let mut liar = FakeWorker::register(&w, "liar").await;
        let other = FakeWorker::register(&w, "other").await.id;
        let me = liar.id;
        let lease = liar.lease().await;
        let rect: trevi_core::Rect = lease.rect.unwrap().into();
        let sender = liar.client.clone();
        let session = liar.session.clone();
        let send = |worker_id: u64, lease_id: u64, rect: pb::Rect, pixels: Vec<Vec<u8>>| {
            let header = pb::TileHeader {
                worker_id,
                lease_id,
                job_id: job,
                rect: Some(rect),
                rays: 1,
                session: session.clone(),
                frame: None,
                render_micros: None,
                cpu_micros: None,
            };
            let mut w = sender.clone();
            async move {
                w.submit_tile(tokio_stream::iter(tile_upload(header, pixels)))
                    .await
            }
        };
        let full = grey(rect.pixel_count());
        // A lease the worker does not hold (made up, or someone else's).
        let e = send(
            me,
            lease.lease_id + 1000,
            lease.rect.unwrap(),
            vec![full.clone()],
        )
        .await
        .unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        // Another registration's id (with this one's session secret).
        let e = send(
            other,
            lease.lease_id,
            lease.rect.unwrap(),
            vec![full.clone()],
        )
        .await
        .unwrap_err();
        assert_eq!(e.code(), Code::PermissionDenied, "{e:?}");
        // A rectangle that is no tile, and a huge one.
        let odd = pb::Rect {
            x: 3,
            y: 0,
            w: 16,
            h: 16,
        };
        assert_eq!(
            code(send(me, lease.lease_id, odd, vec![full.clone()]).await),
            Code::InvalidArgument
        );
        let huge = pb::Rect {
            x: 0,
            y: 0,
            w: u32::MAX,
            h: u32::MAX,
        };
        assert_eq!(
            code(send(me, lease.lease_id, huge, vec![]).await),
            Code::InvalidArgument
        );
        // Truncated (header only; half the pixels) and oversized streams.
        assert_eq!(
            code(send(me, lease.lease_id, lease.rect.unwrap(), vec![]).await),
            Code::InvalidArgument
        );
        let again = liar.lease().await;
        assert_eq!(again.rect, lease.rect, "the refused tile is back first");
        let oversized = vec![full.clone(), grey(10)];
        assert_eq!(
            code(send(me, again.lease_id, again.rect.unwrap(), oversized).await),
            Code::InvalidArgument
        );
        assert_eq!(
            jobs(&c, None)
                .await
                .get_job(pb::JobId {
                    id: job,
                    frame: None
                })
                .await
                .unwrap()
                .into_inner()
                .tiles_done,
            0
        );
    });

    // Jobs per submitter: job 1 is unfinished; two more fit, the next not.
    let scene = dir.write("s.xml", &tiny_scene(4));
    let detach = |dir: &Dir| {
        submit(
            dir,
            &[
                scene.to_str().unwrap(),
                "--coordinator",
                &c.url,
                "--detach",
                "--tile",
                "16",
            ],
        )
    };
    assert!(detach(&dir).status.success(), "{}", dir.logs());
    assert!(detach(&dir).status.success(), "{}", dir.logs());
    let o = detach(&dir);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("unfinished jobs") && err.contains("ResourceExhausted"),
        "{err}"
    );

    // Still serving: an honest worker finishes everything, and a new render
    // is byte-identical to the embedded one.
    let expected = embedded(&dir, &scene, "embedded.png");
    let _w = worker_with(&dir, &c.url, "honest", &[], &[]);
    let rt = runtime();
    wait_for(&dir, "the queued jobs", 60, || {
        rt.block_on(async {
            let list = jobs(&c, None)
                .await
                .list_jobs(pb::ListJobsRequest::default())
                .await
                .unwrap()
                .into_inner()
                .jobs;
            list.iter().all(|s| s.state == pb::JobState::Done as i32)
        })
    });
    let out = dir.path().join("after.png");
    let o = submit(
        &dir,
        &[
            scene.to_str().unwrap(),
            "--coordinator",
            &c.url,
            "-o",
            out.to_str().unwrap(),
            "--tile",
            "16",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    assert!(std::fs::read(&out).unwrap() == expected);
}

/// Runs a program that should fail at once; returns its stderr.
fn fails(dir: &Dir, name: &str, args: &[&str]) -> String {
    let mut cmd = if name == "trevi-submit" {
        submit_cmd(args)
    } else {
        let mut c = Command::new(bin(name));
        c.args(args)
            .env_remove("TREVI_TLS_CERT")
            .env_remove("TREVI_TLS_KEY")
            .env_remove("TREVI_TLS_CA")
            .env_remove("TREVI_SUBMIT_TOKEN")
            .env_remove("TREVI_WORKER_TOKEN");
        c
    };
    let o = cmd
        .env("RUST_BACKTRACE", "0")
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(
        !o.status.success(),
        "{name} {args:?} succeeded\n{err}\n{}",
        dir.logs()
    );
    assert!(
        o.status.code().is_some() && !err.contains("panicked"),
        "{name} {args:?} did not exit with an error\n{err}"
    );
    err
}

#[test]
fn tls_mistakes_get_clear_errors() {
    let dir = Dir::new();
    let (Some(certs), Some(other)) = (make_certs(&dir, "certs"), make_certs(&dir, "other")) else {
        return;
    };
    let f = |d: &Path, name: &str| d.join(name).to_str().unwrap().to_string();
    let (cert, key, ca) = (
        f(&certs, "coordinator.pem"),
        f(&certs, "coordinator.key"),
        f(&certs, "ca.pem"),
    );
    let (other_key, other_ca) = (f(&other, "coordinator.key"), f(&other, "ca.pem"));
    let data = f(dir.path(), "data-bad");

    // The coordinator refuses to start on a bad key, naming the file.
    let base = ["--listen", "127.0.0.1:0", "--data-dir", &data];
    let run = |extra: &[&str]| {
        let args: Vec<&str> = base.iter().chain(extra).copied().collect();
        fails(&dir, "trevi-coordinator", &args)
    };
    let err = run(&["--tls-cert", &cert, "--tls-key", "missing.key"]);
    assert!(err.contains("cannot read the TLS key missing.key"), "{err}");
    let err = run(&["--tls-cert", &cert]);
    assert!(err.contains("--tls-key is missing"), "{err}");
    let err = run(&["--tls-cert", &cert, "--tls-key", &cert]);
    assert!(err.contains("holds no PEM private key"), "{err}");
    let err = run(&["--tls-cert", &cert, "--tls-key", &other_key]);
    assert!(err.contains("cannot be used together"), "{err}");

    let c = coordinator_with(
        &dir,
        "127.0.0.1:0",
        "coordinator",
        &["--tls-cert", &cert, "--tls-key", &key],
        &[],
    );
    let port = c.addr.rsplit(':').next().unwrap().to_string();
    let plain = format!("http://127.0.0.1:{port}");
    let scene = dir.write("s.xml", &tiny_scene(3));
    let out = f(dir.path(), "out.png");
    let render = |url: &str, extra: &[&str]| {
        let mut args = vec![scene.to_str().unwrap(), "--coordinator", url, "-o", &out];
        args.extend(extra);
        fails(&dir, "trevi-submit", &args)
    };

    // Plain http:// against TLS: told to use https://.
    let err = render(&plain, &[]);
    assert!(
        err.contains("seems to serve TLS: use an https:// URL"),
        "{err}"
    );
    let err = fails(&dir, "trevi-submit", &["list", "--coordinator", &plain]);
    assert!(err.contains("seems to serve TLS"), "{err}");
    // The wrong CA, or none (the system roots do not know this farm's CA).
    for extra in [&["--tls-ca", other_ca.as_str()][..], &[]] {
        let err = render(&c.url, extra);
        assert!(
            err.contains("cannot reach the coordinator")
                && err.contains("invalid peer certificate")
                && err.contains("--tls-ca"),
            "{extra:?}: {err}"
        );
    }
    // A name the certificate was not made for, and --tls-domain.
    let by_ip = format!("https://127.0.0.1:{port}");
    let err = render(&by_ip, &["--tls-ca", &ca, "--tls-domain", "wrong.example"]);
    assert!(
        err.contains("not valid for name \"wrong.example\""),
        "{err}"
    );
    let o = submit(
        &dir,
        &[
            "list",
            "--coordinator",
            &by_ip,
            "--tls-ca",
            &ca,
            "--tls-domain",
            "coordinator",
        ],
    );
    assert!(o.status.success(), "{}", dir.logs());
    // TLS options with an http:// URL, and a CA file that is not one.
    let err = render(&plain, &["--tls-ca", &ca]);
    assert!(err.contains("--tls-ca is only for TLS"), "{err}");
    let err = render(&c.url, &["--tls-ca", &key]);
    assert!(err.contains("holds no PEM certificate"), "{err}");
    let err = render(&c.url, &["--tls-ca", "missing-ca.pem"]);
    assert!(
        err.contains("cannot read the CA certificate missing-ca.pem"),
        "{err}"
    );

    // https:// against a plain coordinator.
    let dir2 = Dir::new();
    let p = coordinator_with(&dir2, "127.0.0.1:0", "plain", &[], &[]);
    let https_plain = p.url.replace("http://", "https://");
    let err = render(&https_plain, &["--tls-ca", &ca]);
    assert!(err.contains("seems to serve plain gRPC"), "{err}");

    // A worker trusting the wrong CA stops with the reason (retrying cannot
    // help); one speaking plain http:// says what is wrong while it retries.
    let mut w = worker_with(&dir, &c.url, "wrongca", &["--tls-ca", &other_ca], &[]);
    let status = wait_child(&dir, &mut w.0, 30);
    assert!(!status.success(), "{}", dir.logs());
    let log = dir.read_log("wrongca");
    assert!(
        log.contains("invalid peer certificate") && !log.contains("panicked"),
        "{log}"
    );
    let _w = worker_with(&dir, &plain, "plainworker", &[], &[]);
    wait_for(&dir, "the plain worker to log", 30, || {
        dir.read_log("plainworker")
            .contains("seems to serve TLS: use an https:// URL")
    });

    // After all that, the TLS coordinator still serves.
    let o = submit(&dir, &["list", "--coordinator", &c.url, "--tls-ca", &ca]);
    assert!(o.status.success(), "{}", dir.logs());
}

/// Runs `deploy/trevi-health ADDR [SERVICE]` with `envs`: (exit ok, stderr).
fn health(addr: &str, service: Option<&str>, envs: &[(&str, &str)]) -> (bool, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/trevi-health");
    let mut cmd = Command::new("sh");
    cmd.arg(&script)
        .arg(addr)
        .args(service)
        .env_remove("TREVI_TLS_CA")
        .env_remove("TREVI_TLS_DOMAIN")
        .env("TREVI_HEALTH_TIMEOUT", "10");
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let o = cmd.output().expect("run sh");
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

/// The probe the compose file and the Kubernetes workers use answers yes
/// only for a serving coordinator it can trust, plain or TLS.
#[test]
fn the_health_probe_checks_plain_and_tls_coordinators() {
    if !have_command("curl", "--version", "deploy/trevi-health") {
        return;
    }
    let dir = Dir::new();
    let plain = coordinator_with(&dir, "127.0.0.1:0", "plain", &[], &[]);
    assert!(health(&plain.addr, None, &[]).0);
    assert!(health(&plain.url, Some("trevi.v1.Jobs"), &[]).0);
    let (ok, err) = health(&plain.addr, Some("no.such.Service"), &[]);
    assert!(!ok && err.contains("is not serving"), "{err}");

    let Some(certs) = make_certs(&dir, "certs") else {
        return;
    };
    let f = |name: &str| certs.join(name).to_str().unwrap().to_string();
    let tls_dir = Dir::new();
    let tls = coordinator_with(
        &tls_dir,
        "127.0.0.1:0",
        "tls",
        &[
            "--tls-cert",
            &f("coordinator.pem"),
            "--tls-key",
            &f("coordinator.key"),
        ],
        &[],
    );
    let ca = f("ca.pem");
    let port = tls.addr.rsplit(':').next().unwrap();
    // Trusting the farm's CA: serving, for the URL's host or a named one.
    assert!(health(&tls.url, None, &[("TREVI_TLS_CA", &ca)]).0);
    let by_ip = format!("https://127.0.0.1:{port}");
    let named = [
        ("TREVI_TLS_CA", ca.as_str()),
        ("TREVI_TLS_DOMAIN", "coordinator"),
    ];
    assert!(health(&by_ip, Some("trevi.v1.Workers"), &named).0);
    // Not trusting it, the wrong name, or plain gRPC to a TLS port: no.
    let (ok, err) = health(&tls.url, None, &[]);
    assert!(!ok && err.contains("certificate"), "{err}");
    let wrong = [
        ("TREVI_TLS_CA", ca.as_str()),
        ("TREVI_TLS_DOMAIN", "wrong.example"),
    ];
    let (ok, err) = health(&by_ip, None, &wrong);
    assert!(!ok && err.contains("is not serving"), "{err}");
    let (ok, err) = health(&tls.addr, None, &[]);
    assert!(!ok && err.contains("is not serving"), "{err}");
}
