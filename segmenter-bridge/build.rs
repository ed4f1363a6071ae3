//! Links the bridge (and everything that depends on it: the binary, test binaries, doctests)
//! against the project venv's libpython with an rpath, so the process never silently picks up
//! Debian's system libpython3.11 instead (../shared/facts.md, "Linking trap").
//! Also records the venv that PYO3_PYTHON points at as the default venv to start on.

use std::path::Path;

fn main() {
    pyo3_build_config::add_libpython_rpath_link_args();
    println!("cargo:rerun-if-env-changed=PYO3_PYTHON");
    // PYO3_PYTHON = <venv>/bin/python3 (set for every cargo call by .cargo/config.toml).
    let venv = std::env::var("PYO3_PYTHON")
        .ok()
        .and_then(|python| Path::new(&python).parent()?.parent().map(Path::to_path_buf));
    if let Some(venv) = venv {
        println!("cargo:rustc-env=CNFMP_BUILD_VENV={}", venv.display());
    }
}
