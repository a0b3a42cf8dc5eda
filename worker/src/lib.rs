//! The Trevi worker. Placeholder until the farm lands.
