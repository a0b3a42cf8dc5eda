//! `Session::fetch_state` over a real gRPC connection, against a stand-in
//! coordinator whose `FetchState` answers as each test says.

use super::*;
use std::sync::{Arc, Mutex};
use tokio::sync::watch;
use tonic::{Request, Response, Status};
use trevi_proto::pb::workers_server::{Workers, WorkersServer};
use trevi_proto::pb::{bundles_client::BundlesClient, workers_client::WorkersClient};
use trevi_proto::Bearer;

/// What the stand-in's FetchState answers: these chunks, or this error.
#[derive(Clone)]
struct Coordinator {
    answer: Result<Vec<Vec<u8>>, Status>,
    asked: Arc<Mutex<Vec<pb::StateRequest>>>,
}

fn no<T>() -> Result<Response<T>, Status> {
    Err(Status::unimplemented("not in this test"))
}

#[tonic::async_trait]
impl Workers for Coordinator {
    async fn register(
        &self,
        _: Request<pb::RegisterRequest>,
    ) -> Result<Response<pb::RegisterResponse>, Status> {
        no()
    }
    async fn lease_tile(
        &self,
        _: Request<pb::LeaseRequest>,
    ) -> Result<Response<pb::LeaseResponse>, Status> {
        no()
    }
    async fn heartbeat(
        &self,
        _: Request<pb::HeartbeatRequest>,
    ) -> Result<Response<pb::HeartbeatResponse>, Status> {
        no()
    }
    async fn submit_tile(
        &self,
        _: Request<tonic::Streaming<pb::TileUpload>>,
    ) -> Result<Response<pb::TileAck>, Status> {
        no()
    }
    async fn return_tile(
        &self,
        _: Request<pb::TileReturn>,
    ) -> Result<Response<pb::TileReturnAck>, Status> {
        no()
    }
    type FetchStateStream = tokio_stream::Iter<std::vec::IntoIter<Result<pb::StateChunk, Status>>>;
    async fn fetch_state(
        &self,
        r: Request<pb::StateRequest>,
    ) -> Result<Response<Self::FetchStateStream>, Status> {
        self.asked.lock().unwrap().push(r.into_inner());
        let chunks = self.answer.clone()?;
        let chunks: Vec<_> = chunks
            .into_iter()
            .map(|data| Ok(pb::StateChunk { data }))
            .collect();
        Ok(Response::new(tokio_stream::iter(chunks)))
    }
}

/// A session of the worker connected (lazily) to `addr`.
fn session(addr: std::net::SocketAddr) -> Session {
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect_lazy();
    let bearer = Bearer::new(None).unwrap();
    Session {
        workers: WorkersClient::with_interceptor(channel.clone(), bearer.clone()),
        bundles: BundlesClient::with_interceptor(channel, bearer),
        pool: Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap(),
        ),
        threads: 1,
        clocks: crate::cpu::RenderClocks::default(),
        render: Arc::new(tokio::sync::Semaphore::new(1)),
        paused: watch::channel(None).1,
        max_memory: crate::MaxMemory::NONE,
        scenes: Arc::new(tokio::sync::Mutex::new(
            crate::scene_cache::SceneCache::new(std::num::NonZeroUsize::MIN),
        )),
        #[cfg(feature = "test-hooks")]
        fault: None,
    }
}

/// Serves `c` on a loopback port; the session that talks to it.
async fn serve(c: Coordinator) -> Session {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(WorkersServer::new(c))
            .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)),
    );
    session(addr)
}

fn me() -> Me {
    Me {
        id: 3,
        session: b"secret".to_vec(),
    }
}

#[tokio::test]
async fn a_fetched_state_arrives_in_chunks_and_is_bounded() {
    let rect = Rect::new(0, 0, 3, 2);
    let state = TileState::new(rect).encode();
    let asked = Arc::new(Mutex::new(Vec::new()));
    let chunks: Vec<Vec<u8>> = state.chunks(100).map(<[u8]>::to_vec).collect();
    let mut s = serve(Coordinator {
        answer: Ok(chunks),
        asked: asked.clone(),
    })
    .await;
    assert_eq!(s.fetch_state(&me(), 12, rect).await.unwrap(), state);
    assert_eq!(
        asked.lock().unwrap()[0],
        pb::StateRequest {
            worker_id: 3,
            session: b"secret".to_vec(),
            lease_id: 12,
        }
    );
    // The same bytes for a smaller rect: past its bound.
    let e = s
        .fetch_state(&me(), 12, Rect::new(0, 0, 2, 2))
        .await
        .unwrap_err();
    assert!(matches!(e, PassError::TooLong { lease: 12, .. }), "{e}");
}

/// The coordinator's refusal fails the lease; a connection that cannot be
/// made is the connection's (the session reconnects).
#[tokio::test]
async fn a_refusal_fails_the_lease_and_a_lost_connection_reconnects() {
    let rect = Rect::new(0, 0, 3, 2);
    let mut s = serve(Coordinator {
        answer: Err(Status::not_found("no state for lease 12")),
        asked: Default::default(),
    })
    .await;
    let e = s.fetch_state(&me(), 12, rect).await.unwrap_err();
    let PassError::Fetch { lease: 12, status } = &e else {
        panic!("{e}")
    };
    assert!(!connection_lost(status), "{e}");
    assert!(e.to_string().contains("no state for lease 12"), "{e}");
    // Nothing listens there any more.
    let gone = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = gone.local_addr().unwrap();
    drop(gone);
    let e = session(addr)
        .fetch_state(&me(), 12, rect)
        .await
        .unwrap_err();
    let PassError::Fetch { status, .. } = &e else {
        panic!("{e}")
    };
    assert!(connection_lost(status), "{e}");
}
