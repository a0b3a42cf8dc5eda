//! What the coordinator's integration tests share: a job's spec, and a farm
//! served over gRPC on loopback.
#![allow(dead_code)] // Each test binary uses a part.

use std::sync::Arc;
use tokio::net::TcpListener;
use trevi_coordinator::{Farm, JobSpec};
use trevi_proto::pb::workers_client::WorkersClient;

/// A job of `w` × `h` in tiles of `tile`, written to `name`; its bundle and
/// camera are never opened by these tests.
pub fn spec(w: u32, h: u32, tile: u32, name: &str) -> JobSpec {
    JobSpec {
        frame: None,
        bundle_hash: "0".repeat(64),
        camera: "cam".into(),
        priority: 0,
        width: w,
        height: h,
        tile_size: tile,
        output_name: name.into(),
        scene: String::new(),
        submitter: String::new(),
        samples: None,
        aovs: trevi_core::Aovs::NONE,
    }
}

/// `farm` served over gRPC on a free loopback port, and a workers' client
/// connected to it (one connection, shared by its clones).
pub async fn serve(farm: Arc<Farm>) -> WorkersClient<tonic::transport::Channel> {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        trevi_coordinator::grpc::serve(farm, listener, std::future::pending()).await
    });
    WorkersClient::connect(format!("http://{addr}"))
        .await
        .unwrap()
        .max_decoding_message_size(usize::MAX)
}
