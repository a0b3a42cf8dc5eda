//! A usage answer as the wire carries it ([`usage_to_pb`]) and as JSON: one
//! shape for `GET /api/usage` and `trevi-submit usage --format json`.
//!
//! ```json
//! {"by": "worker", "since_ms": 1700000000000, "bucket_s": 3600, "truncated": false,
//!  "cost_per_core_hour": 0.05,
//!  "rows": [{"key": "render-01", "core_seconds": 12.5, "cpu_micros": 12500000,
//!            "tiles": 64, "rays": 1234567, "wall_seconds": null,
//!            "unmeasured_tiles": 0, "first_ms": ..., "last_ms": ..., "cost": 0.00017}],
//!  "buckets": [{"start_ms": 1700000000000, "core_seconds": 12.5}]}
//! ```
//!
//! `cost` (and `cost_per_core_hour`) only when a cost was given.

use super::{UsageBy, UsageReport};
use serde_json::{json, Value};
use trevi_proto::pb;

/// A usage report as the wire carries it (`Jobs.Usage`'s answer).
pub fn usage_to_pb(r: &UsageReport) -> pb::UsageResponse {
    pb::UsageResponse {
        rows: r
            .rows
            .iter()
            .map(|row| pb::UsageRow {
                key: row.key.clone(),
                cpu_micros: row.agg.cpu_micros,
                tiles: row.agg.tiles,
                rays: row.agg.rays,
                wall_ms: row.wall_ms,
                unmeasured_tiles: row.agg.unmeasured,
                first_ms: row.first_ms,
                last_ms: row.last_ms,
            })
            .collect(),
        truncated: r.truncated,
        buckets: r
            .buckets
            .iter()
            .map(|&(start_ms, cpu_micros)| pb::UsageBucket {
                start_ms,
                cpu_micros,
            })
            .collect(),
        bucket_seconds: r.bucket_ms / 1000,
        since_ms: r.since_ms,
    }
}

/// Core-seconds of `micros` microseconds of CPU time.
pub fn core_seconds(micros: u64) -> f64 {
    micros as f64 / 1e6
}

/// What `micros` of CPU time cost at `per_core_hour`.
pub fn cost(micros: u64, per_core_hour: f64) -> f64 {
    core_seconds(micros) / 3600.0 * per_core_hour
}

/// `r` (grouped `by`) as JSON, with a cost column at `per_core_hour`.
pub fn usage_json(r: &pb::UsageResponse, by: UsageBy, per_core_hour: Option<f64>) -> Value {
    let rows: Vec<Value> = r
        .rows
        .iter()
        .map(|row| {
            let mut v = json!({
                "key": row.key,
                "core_seconds": core_seconds(row.cpu_micros),
                "cpu_micros": row.cpu_micros,
                "tiles": row.tiles,
                "rays": row.rays,
                "wall_seconds": row.wall_ms.map(|w| w as f64 / 1e3),
                "unmeasured_tiles": row.unmeasured_tiles,
                "first_ms": row.first_ms,
                "last_ms": row.last_ms,
            });
            if let Some(c) = per_core_hour {
                v["cost"] = json!(cost(row.cpu_micros, c));
            }
            v
        })
        .collect();
    let buckets: Vec<Value> = r
        .buckets
        .iter()
        .map(|b| json!({"start_ms": b.start_ms, "core_seconds": core_seconds(b.cpu_micros)}))
        .collect();
    let mut v = json!({
        "by": by.name(),
        "since_ms": r.since_ms,
        "bucket_s": r.bucket_seconds,
        "truncated": r.truncated,
        "rows": rows,
        "buckets": buckets,
    });
    if let Some(c) = per_core_hour {
        v["cost_per_core_hour"] = json!(c);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_carry_core_seconds_and_a_cost_only_when_asked() {
        let r = pb::UsageResponse {
            rows: vec![pb::UsageRow {
                key: "w\"1".into(),
                cpu_micros: 7_200_000_000,
                tiles: 3,
                rays: 9,
                wall_ms: None,
                unmeasured_tiles: 0,
                first_ms: 1,
                last_ms: 2,
            }],
            ..Default::default()
        };
        let v = usage_json(&r, UsageBy::Worker, Some(0.5));
        assert_eq!(v["rows"][0]["core_seconds"], json!(7200.0));
        assert_eq!(v["rows"][0]["cost"], json!(1.0));
        assert_eq!(v["rows"][0]["key"], json!("w\"1"));
        assert!(v["rows"][0]["wall_seconds"].is_null());
        let v = usage_json(&r, UsageBy::Worker, None);
        assert!(v["rows"][0].get("cost").is_none() && v.get("cost_per_core_hour").is_none());
    }
}
