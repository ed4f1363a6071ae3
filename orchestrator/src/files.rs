//! Writing output files so that a failure never leaves a half-written file behind and never
//! destroys what was there: write a temporary file beside the target, then rename it over.

use std::io::Write;
use std::path::Path;

use crate::failure::Failure;

/// Atomically replaces (or creates) `path` with `contents`.
pub fn write_atomically(path: &Path, contents: &[u8]) -> Result<(), Failure> {
    let fail = |what: &str, err: std::io::Error| Failure::BadInput(format!("cannot {what} {}: {err}", path.display()));
    let dir = match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    };
    if path.is_dir() {
        return Err(Failure::BadInput(format!("cannot write {}: it is a directory", path.display())));
    }
    let mut temp = tempfile::Builder::new()
        .prefix(".cnfmp-")
        .tempfile_in(dir)
        .map_err(|err| fail("create a temporary file beside", err))?;
    temp.write_all(contents).map_err(|err| fail("write", err))?;
    // tempfile creates 0600 files; outputs are ordinary files others may read.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        temp.as_file().set_permissions(std::fs::Permissions::from_mode(0o644)).map_err(|err| fail("set permissions of", err))?;
    }
    temp.as_file().sync_all().map_err(|err| fail("flush", err))?;
    temp.persist(path).map_err(|err| fail("replace", err.error))?;
    Ok(())
}
