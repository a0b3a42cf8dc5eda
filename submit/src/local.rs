//! Rendering on this machine: an embedded coordinator on 127.0.0.1 (an
//! ephemeral port, data in a temporary directory) and an in-process worker
//! with every core, driven by the same client code as a farm (`remote.rs`),
//! so the output is byte-identical to the farm's.

use anyhow::{Context, Result};
use std::sync::Arc;
use tokio::sync::{oneshot, watch};
use tokio::task::JoinHandle;
use trevi_coordinator::{Farm, FarmConfig};
use trevi_worker::WorkerConfig;

/// A coordinator and a worker running inside this process.
pub struct Embedded {
    pub url: String,
    stop_server: oneshot::Sender<()>,
    stop_worker: watch::Sender<bool>,
    server: JoinHandle<()>,
    worker: JoinHandle<()>,
    _data: tempfile::TempDir,
}

impl Embedded {
    /// `threads` render threads (0: every core); `tile` the default tile edge.
    pub async fn start(threads: usize, tile: u32) -> Result<Embedded> {
        let data = tempfile::Builder::new()
            .prefix("trevi-submit-")
            .tempdir()
            .context("cannot create a temporary directory")?;
        let mut cfg = FarmConfig::new(data.path());
        cfg.default_tile = tile;
        // The data directory dies with this process: nothing to resume.
        cfg.durable = false;
        let farm = Arc::new(Farm::new(cfg).context("cannot start the embedded coordinator")?);
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .context("cannot listen on 127.0.0.1")?;
        let url = format!("http://{}", listener.local_addr()?);
        let (stop_server, stopped) = oneshot::channel::<()>();
        let server = tokio::spawn(async move {
            let shutdown = async {
                let _ = stopped.await;
            };
            if let Err(e) = trevi_coordinator::grpc::serve(farm, listener, shutdown).await {
                eprintln!("trevi-submit: embedded coordinator failed: {e}");
            }
        });
        let (stop_worker, stop) = watch::channel(false);
        let mut wcfg = WorkerConfig::new(url.clone());
        wcfg.threads = threads;
        wcfg.name = "embedded".into();
        let worker = tokio::spawn(async move {
            if let Err(e) = trevi_worker::run(wcfg, stop).await {
                eprintln!("trevi-submit: embedded worker failed: {e}");
            }
        });
        Ok(Embedded {
            url,
            stop_server,
            stop_worker,
            server,
            worker,
            _data: data,
        })
    }

    /// Stops both at once: the jobs are over, and a graceful stop would wait
    /// for the worker's pending lease request.
    pub async fn stop(self) {
        let _ = self.stop_worker.send(true);
        let _ = self.stop_server.send(());
        self.worker.abort();
        self.server.abort();
        let _ = self.worker.await;
        let _ = self.server.await;
    }
}
