//! A worker made by hand from the raw gRPC client, for tests that lie to
//! the coordinator (wrong pixels, someone else's lease or id, forged
//! sessions) or must hold a lease at a precise moment.

use trevi_proto::pb::{self, workers_client::WorkersClient};
use trevi_proto::AuthChannel;

/// One registration: its id and session secret, and the client it came on.
pub struct FakeWorker {
    pub client: WorkersClient<AuthChannel>,
    pub id: u64,
    pub session: Vec<u8>,
}

impl FakeWorker {
    /// Registers as `name` with one thread on `client`'s coordinator.
    pub async fn register(client: &WorkersClient<AuthChannel>, name: &str) -> FakeWorker {
        let mut client = client.clone();
        let reg = client
            .register(pb::RegisterRequest {
                name: name.into(),
                threads: 1,
                ..Default::default()
            })
            .await
            .unwrap_or_else(|s| panic!("register {name}: {s:?}"))
            .into_inner();
        FakeWorker {
            client,
            id: reg.worker_id,
            session: reg.session,
        }
    }

    /// A lease request in this worker's name (the coordinator's default
    /// wait).
    pub fn lease_request(&self) -> pb::LeaseRequest {
        pb::LeaseRequest {
            worker_id: self.id,
            session: self.session.clone(),
            ..Default::default()
        }
    }

    /// One lease request: a tile, or `None` when there was none to give.
    pub async fn try_lease(&mut self) -> Option<pb::Lease> {
        let req = self.lease_request();
        self.client
            .lease_tile(req)
            .await
            .unwrap_or_else(|s| panic!("lease: {s:?}"))
            .into_inner()
            .lease
    }

    /// Asks until a tile is leased.
    pub async fn lease(&mut self) -> pb::Lease {
        loop {
            if let Some(l) = self.try_lease().await {
                return l;
            }
        }
    }

    /// The header an honest result for `lease` carries (one ray); tests
    /// change the fields they forge.
    pub fn header(&self, lease: &pb::Lease) -> pb::TileHeader {
        pb::TileHeader {
            worker_id: self.id,
            lease_id: lease.lease_id,
            job_id: lease.job_id,
            rect: lease.rect,
            rays: 1,
            session: self.session.clone(),
            frame: lease.frame,
            render_micros: None,
            cpu_micros: None,
        }
    }

    /// Sends a tile result: `header`, then each of `chunks` as one pixels
    /// message.
    pub async fn send(
        &mut self,
        header: pb::TileHeader,
        chunks: Vec<Vec<u8>>,
    ) -> Result<pb::TileAck, tonic::Status> {
        self.client
            .submit_tile(tokio_stream::iter(tile_upload(header, chunks)))
            .await
            .map(|r| r.into_inner())
    }
}

/// The messages of a tile result: `header`, then one message per chunk of
/// pixel bytes.
pub fn tile_upload(header: pb::TileHeader, chunks: Vec<Vec<u8>>) -> Vec<pb::TileUpload> {
    use pb::tile_upload::Part;
    std::iter::once(Part::Header(header))
        .chain(chunks.into_iter().map(Part::Pixels))
        .map(|p| pb::TileUpload { part: Some(p) })
        .collect()
}

/// `n` pixels of one grey, as wire bytes.
pub fn grey(n: usize) -> Vec<u8> {
    trevi_proto::pixels_to_bytes(&vec![[0.5f32; 3]; n])
}
