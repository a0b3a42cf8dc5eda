//! `trevi-core`: the Trevi tracer.
//!
//! A scene bundle goes in, linear float pixels of any tile of any camera's
//! frame come out. There is no network code here: the worker and the
//! coordinator wrap this crate.
//!
//! The modules follow the data flow:
//!
//! ```text
//! scene file ─► scene::aisxml (parse, resolve, validate) ─► scene::SceneDesc
//!   (files through scene::source, meshes from mesh::obj / mesh::ply;
//!   bundle::ParsedBundle keeps the bytes read and the description)
//! SceneDesc ─► world::Scene (build: bvh over meshes, bvh over instances)
//! camera::Camera (primary rays) ─► integrator (Whitted + Monte-Carlo effects,
//!   lights, sampling) ─► tile::render_tile (linear RGB of a rectangle)
//!   ─► output::FrameWriter (PNG / EXR, band by band, atomic rename)
//! ```
//!
//! Determinism: a pixel's value depends only on the scene and its coordinates
//! (see `sampling`), so any tiling, thread count or machine gives the same
//! bytes.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]
// `!(x > 0.0)` is deliberate throughout the geometry code: it is true for
// NaN as well, which is exactly what the hit tests must reject.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod alloc_meter;
pub mod aov;
pub mod bundle;
pub mod bvh;
pub mod camera;
pub mod error;
pub mod geometry;
pub mod integrator;
pub mod lights;
pub mod math;
pub mod mesh;
pub mod output;
pub mod passes;
pub mod sampling;
pub mod scene;
#[cfg(test)]
mod testing;
pub mod texture;
pub mod tile;
pub mod world;

pub use aov::{Aov, AovTile, Aovs};
pub use bundle::{Bundle, BundleError, ParsedBundle};
pub use error::{Location, OutputError, SceneError, SceneErrorKind};
pub use output::FrameWriter;
pub use scene::source::{DirSource, FileSource};
pub use scene::SceneDesc;
pub use tile::{render_tile, Rect, TileResult};
pub use world::Scene;
