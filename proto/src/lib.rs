//! The Trevi gRPC contract (`trevi.v1`). Placeholder until the farm lands.
