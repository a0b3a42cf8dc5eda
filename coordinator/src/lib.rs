//! The Trevi coordinator: job queue, tile leases, validation and stitching.
//!
//! - [`scheduler`]: pure bookkeeping of jobs, tiles and leases (time passed in).
//! - [`farm`]: the coordinator without the network: bundles on disk, result
//!   validation, and stitching each job's tiles into its output file through
//!   a [`sink::TileSink`], normally `trevi_core::FrameWriter` (rows leave as
//!   soon as a band is complete, and the file is moved into place when the
//!   last tile is in).
//! - [`limits`]: every bound the coordinator works within, in one value.
//! - [`store`]: the durable state (SQLite and the tile files);
//!   [`bundles`]: the uploaded scene bundles on disk.
//! - [`grpc`]: the `trevi.v1` services over [`farm::Farm`], plus
//!   `grpc.health.v1` and server reflection.
//! - [`http`]: the web monitor (`--http`), its JSON API, `/metrics`
//!   ([`metrics`]) and `/healthz`; [`preview`] keeps each running frame's
//!   small live preview, [`workers`] what is known of each worker.
//! - [`events`]: job events (submitted, started, done, ...) POSTed to
//!   webhooks, signed, and streamed to the monitor.
//! - [`usage`]: the usage history (CPU time, tiles, rays and wall time per
//!   job, submitter and worker, hour by hour), kept beyond the jobs.
//! - [`summaries`]: the cameras of each stored bundle's scene, parsed once.
//! - [`listen`]: accepting connections through errors (out of file
//!   descriptors) and raising the open-files limit at start-up.
//! - [`dir_lock`]: one coordinator per data directory.
//! - [`tls`]: loading and checking the certificate and key of `--tls-cert`
//!   and `--tls-key`.
//! - [`timed_lock`]: the mutex of the farm's state and of the store, which
//!   counts how long it is held (the serial part of the coordinator's work).
//!
//! Memory: tiles are leased in band order and at most a window of bands ahead
//! of the first incomplete band, so the rows held by a job's writer are
//! bounded by the window (see [`limits::Limits::window_bytes`]),
//! not by the image height.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod admission;
pub mod auth;
pub mod bundles;
pub mod dir_lock;
pub mod error;
pub mod events;
pub mod farm;
pub mod grpc;
pub mod http;
pub mod limits;
pub mod listen;
pub mod metrics;
pub mod preview;
pub mod scheduler;
pub mod sink;
pub mod store;
pub mod summaries;
pub mod timed_lock;
pub mod tls;
pub mod usage;
pub mod workers;

pub use error::FarmError;
pub use farm::{
    Farm, FarmConfig, LeaseResult, Registration, SubmitOptions, TileOutcome, WorkerOptions,
};
pub use limits::Limits;
pub use scheduler::{JobId, JobInfo, JobSpec, JobState};
pub use sink::{SinkError, TileSink};
