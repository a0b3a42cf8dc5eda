//! Tile uploads over gRPC take turns (`Limits::max_tile_uploads`): those
//! beyond the limit wait unread, on the same connection as the one being
//! received, without stopping it; and one that stalls is dropped after
//! `Limits::upload_idle` and gives its turn to the next.

mod common;

use std::sync::Arc;
use std::time::Duration;
use trevi_coordinator::{Farm, FarmConfig, JobState, Limits, SubmitOptions};
use trevi_proto::pb::{self, tile_upload::Part, workers_client::WorkersClient};

type Client = WorkersClient<tonic::transport::Channel>;

/// A farm with `limits` and one job of `w` × `h` in tiles of `tile`, served
/// on loopback, and one client connection to it.
async fn serve(
    limits: Limits,
    (w, h, tile): (u32, u32, u32),
) -> (tempfile::TempDir, Arc<Farm>, u64, Client) {
    let dir = tempfile::tempdir().unwrap();
    let f = Farm::new(FarmConfig {
        limits,
        ..FarmConfig::new(dir.path())
    })
    .unwrap();
    let job = f
        .submit(
            common::spec(w, h, tile, "out.exr"),
            SubmitOptions::default(),
        )
        .unwrap()
        .id;
    let f = Arc::new(f);
    let client = common::serve(f.clone()).await;
    (dir, f, job, client)
}

/// A worker of one tile a lease, registered, and the lease it gets.
async fn worker_with_lease(c: &mut Client, name: String) -> (pb::RegisterResponse, pb::Lease) {
    let reg = c
        .register(pb::RegisterRequest {
            name,
            threads: 1,
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    let lease = c
        .lease_tile(pb::LeaseRequest {
            worker_id: reg.worker_id,
            session: reg.session.clone(),
            max_wait_ms: 1000,
        })
        .await
        .unwrap()
        .into_inner()
        .lease
        .expect("a tile is queued for every worker");
    (reg, lease)
}

fn header(reg: &pb::RegisterResponse, lease: &pb::Lease) -> pb::TileUpload {
    pb::TileUpload {
        part: Some(Part::Header(pb::TileHeader {
            worker_id: reg.worker_id,
            lease_id: lease.lease_id,
            job_id: lease.job_id,
            rect: lease.rect,
            rays: 1,
            session: reg.session.clone(),
            frame: None,
            render_micros: Some(1000),
            cpu_micros: None,
        })),
    }
}

/// The lease's pixels (all 0.5) as the wire's little-endian f32 RGB, in
/// messages of 64 KiB.
fn pixel_parts(lease: &pb::Lease) -> Vec<pb::TileUpload> {
    let r = lease.rect.unwrap();
    let bytes: Vec<u8> = std::iter::repeat_n(0.5f32.to_le_bytes(), (r.w * r.h * 3) as usize)
        .flatten()
        .collect();
    bytes
        .chunks(64 << 10)
        .map(|c| pb::TileUpload {
            part: Some(Part::Pixels(c.to_vec())),
        })
        .collect()
}

#[tokio::test]
async fn uploads_beyond_the_limit_wait_their_turn_without_stopping_the_connection() {
    // Eight tiles of 256 × 256 (768 KiB of floats each), one received at a
    // time, all eight sent at once over one connection: the seven waiting
    // hold 7 × 256 KiB unread, more than HTTP/2's default connection
    // window of 1 MiB, which would leave the one being received no window.
    let limits = Limits {
        max_tile_uploads: 1,
        ..Limits::default()
    };
    let (_dir, f, job, mut client) = serve(limits, (1024, 512, 256)).await;
    let mut uploads = tokio::task::JoinSet::new();
    for i in 0..8 {
        let (reg, lease) = worker_with_lease(&mut client, format!("w{i}")).await;
        let mut c = client.clone();
        let msgs: Vec<pb::TileUpload> = std::iter::once(header(&reg, &lease))
            .chain(pixel_parts(&lease))
            .collect();
        uploads.spawn(async move { c.submit_tile(tokio_stream::iter(msgs)).await });
    }
    let all = tokio::time::timeout(Duration::from_secs(60), async {
        let mut accepted = 0;
        while let Some(r) = uploads.join_next().await {
            accepted += r.unwrap().unwrap().into_inner().accepted as u32;
        }
        accepted
    })
    .await
    .expect("every upload is received in its turn, none stuck behind a waiting one");
    assert_eq!(all, 8);
    let info = f.info(job).unwrap();
    assert_eq!((info.state, info.tiles_done), (JobState::Done, 8));
}

#[tokio::test]
async fn a_stalled_upload_is_dropped_and_gives_its_turn_to_the_next() {
    let limits = Limits {
        max_tile_uploads: 1,
        // Long enough that B's upload, sent at once, is never idle that
        // long on a busy machine; A's stall is.
        upload_idle: Duration::from_secs(2),
        ..Limits::default()
    };
    let (_dir, f, job, mut client) = serve(limits, (64, 32, 32)).await;
    let (reg_a, lease_a) = worker_with_lease(&mut client, "a".into()).await;
    let (reg_b, lease_b) = worker_with_lease(&mut client, "b".into()).await;

    // A sends its header and then nothing, its stream still open.
    let (tx, rx) = tokio::sync::mpsc::channel(1);
    tx.send(header(&reg_a, &lease_a)).await.unwrap();
    let mut ca = client.clone();
    let stalled = tokio::spawn(async move {
        ca.submit_tile(tokio_stream::wrappers::ReceiverStream::new(rx))
            .await
    });
    // A has taken the only turn before B asks for it.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let msgs: Vec<pb::TileUpload> = std::iter::once(header(&reg_b, &lease_b))
        .chain(pixel_parts(&lease_b))
        .collect();
    let b = tokio::time::timeout(
        Duration::from_secs(30),
        client.submit_tile(tokio_stream::iter(msgs)),
    )
    .await
    .expect("B is received once A is dropped")
    .unwrap();
    assert!(b.into_inner().accepted);
    let e = stalled.await.unwrap().unwrap_err();
    assert_eq!(e.code(), tonic::Code::DeadlineExceeded, "{e:?}");
    assert!(e.message().contains("--upload-idle-ms"), "{}", e.message());
    drop(tx);
    assert_eq!(f.info(job).unwrap().tiles_done, 1);
}
