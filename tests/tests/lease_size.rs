//! Leases of several tiles (coordinator/src/scheduler/lease_size.rs), end to
//! end with a real coordinator: a worker that announces `multi_tile` is given
//! spans of adjacent tiles once the job's cost is measured, renders each as
//! one rectangle, and the stitched frame is byte-identical to the embedded
//! render and to the same job leased in single tiles (to a worker that does
//! not announce it, which never gets more); a real `trevi-worker` gives the
//! same bytes.

mod common;

use common::farm::{upload, workers};
use common::*;
use trevi_core::Rect;
use trevi_proto::pb;

/// 10×3 tiles of 16 (the test coordinator's tile), cheap to render.
const SCENE: &str = r#"<scene version="1">
  <settings background="0.1 0.1 0.2" ambient="0.1 0.1 0.1"/>
  <sphere id="ball" center="0 1 0" radius="1">
    <surface diffuse="0.8 0.3 0.2" specular="1 1 1" shininess="40" reflectivity="0.3"/>
  </sphere>
  <plane id="ground" point="0 0 0" normal="0 1 0"> <surface diffuse="0.5 0.5 0.5"/> </plane>
  <light type="point" position="2 5 3" color="1 1 1" intensity="1" radius="0.3"/>
  <camera id="main" position="0 2 6" lookat="0 1 0" up="0 1 0" fov="50">
    <render width="160" height="40" supersample="2" shadow-samples="2" output="span.png"/>
  </camera>
</scene>
"#;

/// Renders every lease of the farm's one job as a worker registered with
/// `multi_tile` would: the lease's rectangle in one piece. Returns the
/// tiles each lease covered and the job's id.
async fn render_all(c: &Coordinator, multi_tile: bool) -> (Vec<u32>, u64) {
    let bundle = trevi_core::Bundle {
        scene: "span.xml".into(),
        files: [("span.xml".to_string(), SCENE.as_bytes().to_vec())].into(),
    };
    let scene = trevi_core::Scene::from_bundle(&bundle).unwrap();
    let hash = upload(&mut farm::bundles(c, None).await, vec![bundle.encode()])
        .await
        .unwrap();
    let job = farm::submit_job(c, &hash).await.unwrap();
    let mut w = workers(c, None).await;
    let reg = w
        .register(pb::RegisterRequest {
            name: "spans".into(),
            threads: 1,
            multi_tile,
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let mut spans = Vec::new();
    loop {
        let Some(lease) = w
            .lease_tile(pb::LeaseRequest {
                worker_id: reg.worker_id,
                session: reg.session.clone(),
                max_wait_ms: 200,
            })
            .await
            .unwrap()
            .into_inner()
            .lease
        else {
            break;
        };
        let rect: Rect = lease.rect.unwrap().into();
        spans.push(lease.tiles.max(1));
        let r = trevi_core::render_tile(&scene, 0, rect);
        let header = pb::TileHeader {
            worker_id: reg.worker_id,
            lease_id: lease.lease_id,
            job_id: lease.job_id,
            rect: lease.rect,
            rays: r.rays,
            session: reg.session.clone(),
            frame: None,
            render_micros: None,
            cpu_micros: None,
        };
        let bytes = trevi_proto::pixels_to_bytes(&r.pixels);
        let chunks = bytes
            .chunks(trevi_proto::CHUNK_SIZE)
            .map(<[u8]>::to_vec)
            .collect();
        let ack = w
            .submit_tile(tokio_stream::iter(fake_worker::tile_upload(header, chunks)))
            .await
            .unwrap()
            .into_inner();
        assert!(
            ack.accepted,
            "lease {} of {rect:?} not accepted",
            lease.lease_id
        );
    }
    (spans, job.id)
}

#[test]
fn spans_of_tiles_give_the_bytes_of_single_tiles_and_only_to_workers_that_ask() {
    let dir = Dir::new();
    let scene = dir.write("span.xml", SCENE);
    let reference = embedded(&dir, &scene, "embedded.png");
    let rt = runtime();

    // A worker that announces multi_tile: after the first (measuring)
    // lease, the rest of each band comes in one span (1 s of one thread is
    // far more than a band of this frame costs).
    let c = coordinator_with(&dir, "127.0.0.1:0", "coord", &[], &[]);
    let (spans, id) = rt.block_on(render_all(&c, true));
    assert_eq!(spans.iter().sum::<u32>(), 30, "{spans:?}");
    assert!(
        spans.iter().any(|&n| n > 1),
        "no lease of several tiles: {spans:?}"
    );
    let status = farm::job(&rt, &c, id);
    assert_eq!(status.state, pb::JobState::Done as i32, "{status:?}");
    assert_eq!(status.tiles_done, 30);
    let got = rt.block_on(download(&c, id, None));
    assert!(got == reference, "the frame rendered in spans differs");
    drop(c);

    // One that does not: single tiles only, the same bytes.
    let dir2 = Dir::new();
    let c = coordinator_with(&dir2, "127.0.0.1:0", "coord", &[], &[]);
    let (spans, id) = rt.block_on(render_all(&c, false));
    assert_eq!(spans, vec![1; 30]);
    assert!(rt.block_on(download(&c, id, None)) == reference);
}

#[test]
fn a_real_worker_renders_spans_byte_identically() {
    let dir = Dir::new();
    let scene = dir.write("span.xml", SCENE);
    let reference = embedded(&dir, &scene, "embedded.png");
    let rt = runtime();
    let c = coordinator_with(&dir, "127.0.0.1:0", "coord", &[], &[]);
    let _w = worker_with(&dir, &c.url, "worker", &[], &[]);
    // trevi-submit's own default tile is 64: ask for the 16 of the rest.
    let status = farm::submit_and_wait(&dir, &rt, &c, &scene, &["--tile", "16"], 120);
    assert_eq!(status.tiles_done, 30);
    assert!(
        rt.block_on(download(&c, status.id, None)) == reference,
        "the farm's frame differs from the embedded render\n{}",
        dir.logs()
    );
}
