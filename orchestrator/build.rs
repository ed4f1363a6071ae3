//! The `cnfmp` binary and its tests embed libpython through segmenter-bridge; give them the
//! rpath to the venv interpreter's libpython that the bridge's build script publishes, or the
//! dynamic loader would pick Debian's system libpython3.11 (../shared/facts.md).

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_CNFMP_LIBPYTHON_LIBDIR");
    if let Ok(lib_dir) = std::env::var("DEP_CNFMP_LIBPYTHON_LIBDIR") {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{lib_dir}");
    }
}
