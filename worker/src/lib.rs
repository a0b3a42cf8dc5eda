//! The Trevi worker: a stateless tile renderer around `trevi_core::render_tile`
//! (and `trevi_core::passes::TileState` for a progressive job's passes).
//!
//! [`run`](fn@run) loops: connect (with exponential backoff), register, lease a tile,
//! fetch its scene bundle by hash (verifying the SHA-256, keeping the last few
//! built scenes), render the tile on a rayon pool of `threads` threads while
//! heartbeating the lease, and stream the pixels back. It keeps nothing that
//! matters: kill it at any moment and the coordinator re-queues its tile when
//! the lease runs out. It survives a coordinator restart by reconnecting and
//! registering again.
//!
//! A lease may cover several adjacent tiles of one band (the worker
//! registers with `multi_tile`; the coordinator sizes such spans from the
//! render cost it measures): their union is rendered as one rectangle, which
//! gives the same pixels, and uploaded once.
//!
//! The worker registers with its PNG segment encoder's name
//! (`trevi_core::output::PNG_ENCODER`). A lease with `png_segments` is
//! uploaded as encoded 16-row PNG segments and preview sums instead of
//! floats ([`segments`]): the worker checks the pixels (a pixel not finite
//! and non-negative fails the lease, which goes back with an error naming
//! it) and encodes the segments on the render threads.
//!
//! A lease with `samples` is a pass of a progressive job (`pass.rs`,
//! docs/progressive.md): the worker renders its sample range
//! on the rect's accumulation state (a new one when the range starts at 0,
//! otherwise fetched with `FetchState`, at most the state's encoded length
//! and checked: its rect and `next` are the lease's), under the job's own
//! samples per pixel when it has one (the scene kept apart in the cache),
//! and uploads the finished pixels (floats or segments) followed by the new
//! state. A pass stopped midway uploads nothing: the worker loses at most
//! that pass of that lease.
//!
//! A lease is held only by a tile being worked on: a loop takes the render
//! threads before it asks for a lease, so no tile waits behind another while
//! its lease is kept alive. A render stops within a pixel once its lease is
//! dropped (the job was cancelled) or `shutdown` turns true; then the worker
//! gives the lease back unrendered and returns. A render that panics is
//! reported to the coordinator (which counts it against the tile) and the
//! worker goes on.
//!
//! The render threads run at idle priority unless told otherwise
//! ([`priority`]): a worker on a spare desk takes only the CPU time its
//! owner leaves unused.
//!
//! A scene whose estimated size exceeds the worker's memory limit
//! ([`memory`], `--max-memory`) is declined, not built: the coordinator
//! learns the limit at registration and leases such jobs elsewhere. A
//! pass's accumulation state (64 bytes a pixel, twice) counts with it.
//!
//! # Where things are
//!
//! | file | what it holds |
//! |---|---|
//! | `config.rs` | [`WorkerConfig`]: the settings and their defaults |
//! | `run.rs` | [`run`](fn@run): the render threads, connecting (and again, with backoff), registering |
//! | `session.rs` | what one session's loops share, and how a session ends |
//! | `lease.rs` | a loop: lease a tile, then upload it, give it back or decline it |
//! | `render.rs` | rendering a leased tile (or a pass on its state) while heartbeating its lease; stopping it |
//! | `scene_cache.rs` | the built scenes kept between leases (stills' and frames', by their samples too) |
//! | `scene_load.rs` | a lease's scene: from the cache, or downloaded, checked, built, moved to its frame, given a pass's samples |
//! | `cpu.rs` | the render threads' CPU clocks: what a result says it cost (the usage history's figure) |
//! | `upload.rs` | a rendered tile's upload: floats, or PNG segments and preview sums; a pass's state after them |
//! | `pass.rs` | a progressive job's pass (`Lease.samples`): the range checked, the state fetched (bounded) and checked, the range rendered on it |
//! | [`segments`] | checking and encoding a lease's pixels as PNG segments |
//! | [`pause`] | when a worker pauses: the load and active-hours rules |
//! | `machine.rs` | the machine watcher: samples the machine, publishes and reports the pause |
//! | [`priority`] | the render threads' CPU priority |
//! | [`memory`] | `--max-memory`: the biggest scene a worker builds |
//! | `error.rs` | [`WorkerError`], [`SceneLoadError`] |
//! | `test_hooks.rs` | the end-to-end tests' fault and load hooks (feature `test-hooks` only) |
//!
//! `src/main.rs` is `trevi-worker`: its flags, and the stop signals
//! (`trevi_proto::signal`).
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

mod config;
mod cpu;
mod error;
mod lease;
mod machine;
pub mod memory;
mod pass;
pub mod pause;
pub mod priority;
mod render;
mod run;
mod scene_cache;
mod scene_load;
pub mod segments;
mod session;
#[cfg(feature = "test-hooks")]
mod test_hooks;
mod upload;

pub use config::{Preloaded, WorkerConfig, POLL, SCENE_CACHE, TILES_IN_FLIGHT};
pub use error::{SceneLoadError, WorkerError};
pub use memory::MaxMemory;
pub use pause::{Pause, PauseConfig};
pub use priority::Priority;
pub use run::run;
#[cfg(feature = "test-hooks")]
pub use test_hooks::{TestFault, ABORT_ON_TILE, FAIL_JOB, PANIC_ON_TILE};
pub use upload::{segment_messages, state_messages, tile_messages, Rendered};
