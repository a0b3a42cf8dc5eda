//! The Trevi coordinator. Placeholder until the farm lands.
