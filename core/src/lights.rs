//! The lights of a scene, one kind a file:
//!
//! - `point.rs`: point and spot lights (`<light>`): the spec's E, spot
//!   falloff, the soft-shadow jitter of a light with a radius, power;
//! - `area.rs`: emitting surfaces (`emission` on a `<surface>`, `<light
//!   type="rect">`): sampling by area, the density of a point, power.
//!
//! How the integrators shade with them is integration, not light: Whitted
//! mode's direct light is `integrator/whitted.rs` (point and spot) and
//! `integrator/area.rs` (area lights), path mode's next-event estimation
//! `integrator/path.rs`.

pub mod area;
pub mod point;

pub use point::{incident, jittered_position, power, smoothstep, Incident};
