//! With the `oidn` feature, binaries find Open Image Denoise where they were
//! linked against it: `OIDN_DIR/lib` goes into their run path, so nobody has
//! to set `LD_LIBRARY_PATH` (the library's CPU device is a plugin the library
//! loads from its own directory).

fn main() {
    println!("cargo:rerun-if-env-changed=OIDN_DIR");
    if std::env::var_os("CARGO_FEATURE_OIDN").is_none() {
        return;
    }
    if let Some(dir) = std::env::var_os("OIDN_DIR") {
        let lib = std::path::Path::new(&dir).join("lib");
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    }
}
