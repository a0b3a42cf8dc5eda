//! With the `denoise` feature, trevi-submit finds Open Image Denoise where it
//! was linked against it: `OIDN_DIR/lib` goes into its run path (as
//! trevi-denoise's build script does for that crate's own tests; a
//! dependency's link arguments do not reach a binary), so nobody has to set
//! `LD_LIBRARY_PATH`.

fn main() {
    println!("cargo:rerun-if-env-changed=OIDN_DIR");
    if std::env::var_os("CARGO_FEATURE_DENOISE").is_none() {
        return;
    }
    if let Some(dir) = std::env::var_os("OIDN_DIR") {
        let lib = std::path::Path::new(&dir).join("lib");
        println!("cargo:rustc-link-arg-bins=-Wl,-rpath,{}", lib.display());
    }
}
