//! Links against the project venv's libpython with an rpath, so the process never silently
//! picks up Debian's system libpython3.11 instead (../shared/facts.md, "Linking trap").
//!
//! `rustc-link-arg` only reaches this package's own targets (its tests and doctests), so the
//! library directory is also published as `DEP_CNFMP_LIBPYTHON_LIBDIR` (the `links` key):
//! every binary crate that depends on the bridge adds the same rpath from it in its build.rs.
//! Also records the venv that PYO3_PYTHON points at as the default venv to start on.

use std::path::Path;

fn main() {
    pyo3_build_config::add_libpython_rpath_link_args();
    if let Some(lib_dir) = pyo3_build_config::get().lib_dir() {
        println!("cargo:libdir={lib_dir}");
    }
    println!("cargo:rerun-if-env-changed=PYO3_PYTHON");
    // PYO3_PYTHON = <venv>/bin/python3 (set for every cargo call by .cargo/config.toml).
    let venv = std::env::var("PYO3_PYTHON")
        .ok()
        .and_then(|python| Path::new(&python).parent()?.parent().map(Path::to_path_buf));
    if let Some(venv) = venv {
        println!("cargo:rustc-env=CNFMP_BUILD_VENV={}", venv.display());
    }
}
