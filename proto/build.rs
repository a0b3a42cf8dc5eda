//! Generates the `trevi.v1` code from `proto/trevi/v1/*.proto` with protox, a
//! pure-Rust protobuf compiler, so building needs no installed `protoc`.

use prost::Message;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protos = ["proto/trevi/v1/farm.proto"];
    for p in &protos {
        println!("cargo:rerun-if-changed={p}");
    }
    let fds = protox::compile(protos, ["proto"])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    // The descriptor set serves gRPC server reflection.
    std::fs::write(out.join("trevi_descriptor.bin"), fds.encode_to_vec())?;
    tonic_prost_build::configure().compile_fds(fds)?;
    Ok(())
}
