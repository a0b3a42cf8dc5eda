//! Rendering on this machine: an embedded coordinator on 127.0.0.1 (an
//! ephemeral port, data in a temporary directory, or for a render kept for
//! `extend` in the local directory, see `kept.rs`) and an in-process worker
//! with every core, driven by the same client as a farm (`client.rs`), so
//! the output is byte-identical to the farm's, stills and sequences alike.
//! The scene the submitter parsed is handed to both: the coordinator keeps
//! its cameras, so it does not parse the bundle again, and for stills it
//! is built here once and the worker starts with it in its scene cache. A
//! sequence's frames need a scene of their own to move from frame to
//! frame: the worker builds that one from the bundle.

use crate::data_dir::DataDir;
use anyhow::{Context, Result};
use std::sync::Arc;
use tokio::sync::{oneshot, watch};
use tokio::task::JoinHandle;
use trevi_coordinator::{Farm, FarmConfig};
use trevi_core::{Scene, SceneDesc};
use trevi_worker::{Preloaded, WorkerConfig};

/// The scene of a local render, with its bundle's hash: the description
/// the submitter parsed, built (BVHs included) when stills are rendered.
pub struct Prepared {
    hash: String,
    /// The scene file's name in the bundle.
    name: String,
    scene: Ready,
}

/// How far [`Prepared`] took the scene.
enum Ready {
    Described(Box<SceneDesc>),
    Built(Arc<Scene>),
}

impl Prepared {
    /// `desc`, the parsed scene of the bundle whose hash is `hash`; with
    /// `build`, built off the async threads.
    pub async fn new(hash: String, name: String, desc: SceneDesc, build: bool) -> Result<Prepared> {
        let scene = if build {
            let scene = tokio::task::spawn_blocking(move || Scene::build(desc))
                .await
                .context("building the scene")?;
            Ready::Built(Arc::new(scene))
        } else {
            Ready::Described(Box::new(desc))
        };
        Ok(Prepared { hash, name, scene })
    }

    fn desc(&self) -> &SceneDesc {
        match &self.scene {
            Ready::Described(desc) => desc,
            Ready::Built(scene) => &scene.desc,
        }
    }
}

/// A coordinator and a worker running inside this process.
pub struct Embedded {
    pub url: String,
    farm: Arc<Farm>,
    stop_server: oneshot::Sender<()>,
    stop_worker: watch::Sender<bool>,
    server: JoinHandle<()>,
    worker: JoinHandle<()>,
}

/// A signal that ends a local render early: SIGINT (Ctrl-C) or SIGTERM.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interrupted {
    pub name: &'static str,
    /// The exit status that tells a shell which signal it was: 128 + the
    /// signal's number.
    pub code: i32,
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "interrupted by {}: the render stopped; its temporary files and any \
             half-written output were removed",
            self.name
        )
    }
}

impl std::error::Error for Interrupted {}

/// SIGINT and SIGTERM, caught from now on (instead of ending the process
/// where it stands) so that a local render can clean up after itself
/// ([`trevi_proto::signal::Signals`], naming what arrived as the error
/// `trevi-submit` exits with).
pub struct Signals(trevi_proto::signal::Signals);

impl Signals {
    /// Must run inside the runtime.
    pub fn catch() -> Result<Signals> {
        let signals =
            trevi_proto::signal::Signals::catch().context("cannot catch SIGINT and SIGTERM")?;
        Ok(Signals(signals))
    }

    /// The next SIGINT or SIGTERM (including one that arrived since
    /// [`Signals::catch`]).
    pub async fn next(&mut self) -> Interrupted {
        let s = self.0.next().await;
        Interrupted {
            name: s.name,
            code: s.code,
        }
    }
}

impl Embedded {
    /// `threads` render threads (0: every core); `tile` the default tile
    /// edge; `data` its data directory; `scene` the scene about to be
    /// submitted (see [`Prepared`]; none for `extend`, whose worker reads
    /// the bundle the coordinator kept).
    ///
    /// A temporary directory dies with this process: nothing to resume, no
    /// database. A kept one has its database, whose jobs come back; one
    /// left unfinished (by a process that was killed) is cancelled, so that
    /// this process's worker does not render it.
    pub async fn start(
        threads: usize,
        tile: u32,
        data: &DataDir,
        scene: Option<Prepared>,
    ) -> Result<Embedded> {
        let mut cfg = FarmConfig::new(data.path());
        cfg.default_tile = tile;
        cfg.durable = data.is_kept();
        let farm = Arc::new(Farm::new(cfg).with_context(|| {
            format!(
                "cannot start the embedded coordinator in {}",
                data.path().display()
            )
        })?);
        let left = cancel_unfinished(&farm);
        if !left.is_empty() {
            eprintln!(
                "trevi-submit: cancelled job(s) {left:?} of {}, left unfinished by a trevi-submit \
                 that did not end normally",
                data.path().display()
            );
        }
        if let Some(scene) = &scene {
            farm.summaries()
                .prime(&scene.hash, &scene.name, scene.desc());
        }
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .context("cannot listen on 127.0.0.1")?;
        let url = format!("http://{}", listener.local_addr()?);
        let (stop_server, stopped) = oneshot::channel::<()>();
        let served = farm.clone();
        let server = tokio::spawn(async move {
            let farm = served;
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
        // The user asked for this render on this machine: it gets the
        // machine's normal share, not a spare machine's leftovers.
        wcfg.priority = trevi_worker::Priority::Normal;
        if let Some(Prepared {
            hash,
            scene: Ready::Built(built),
            ..
        }) = scene
        {
            wcfg.preloaded = vec![Preloaded { hash, scene: built }];
        }
        let worker = tokio::spawn(async move {
            if let Err(e) = trevi_worker::run(wcfg, stop).await {
                eprintln!("trevi-submit: embedded worker failed: {e}");
            }
        });
        Ok(Embedded {
            url,
            farm,
            stop_server,
            stop_worker,
            server,
            worker,
        })
    }

    /// Whether the coordinator has job (or sequence) `id`.
    pub fn knows(&self, id: u64) -> bool {
        self.farm.info(id).is_ok()
    }

    /// Cancels every job that has not ended (a render interrupted: in a
    /// kept directory it must not come back unfinished); returns their ids.
    pub fn cancel_unfinished(&self) -> Vec<u64> {
        cancel_unfinished(&self.farm)
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

/// Cancels `farm`'s jobs that have not ended (stills, sequences and
/// progressive jobs: their frames and passes go with them); their ids.
fn cancel_unfinished(farm: &Farm) -> Vec<u64> {
    let (jobs, _) = farm.list_from(0, usize::MAX);
    let mut cancelled = Vec::new();
    for j in jobs.into_iter().filter(|j| !j.state.is_final()) {
        match farm.cancel(j.id) {
            Ok(_) => cancelled.push(j.id),
            Err(e) => eprintln!("trevi-submit: cannot cancel job {}: {e}", j.id),
        }
    }
    cancelled
}
