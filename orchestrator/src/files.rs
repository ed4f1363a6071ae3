//! Writing output files so that a failure never leaves a half-written file behind and never
//! destroys what was there: write a temporary file beside the target, then rename it over.

use std::io::Write;
use std::path::{Path, PathBuf};

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

/// Refuses an output directory that would mix with earlier results: `path` must not exist, or
/// be an empty directory.
pub fn require_new_or_empty_dir(path: &Path) -> Result<(), Failure> {
    let occupied = path.exists()
        && (!path.is_dir()
            || std::fs::read_dir(path)
                .map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", path.display())))?
                .next()
                .is_some());
    if occupied {
        return Err(Failure::BadInput(format!("{} already exists and is not an empty directory; choose a new --out", path.display())));
    }
    Ok(())
}

/// Creates the directory `path` (which must not exist, or be empty) holding `files` (name,
/// contents): written into a hidden sibling, then renamed, so the directory appears complete
/// or not at all.
pub fn write_directory_atomically(path: &Path, files: &[(String, Vec<u8>)]) -> Result<(), Failure> {
    let staged = StagedDirectory::new(path)?;
    for (name, contents) in files {
        staged.write(name, contents)?;
    }
    staged.finish()
}

/// A directory built file by file in a hidden sibling and renamed into place by `finish`, so
/// it appears complete or not at all; dropped unfinished (a failure), the sibling is removed.
#[derive(Debug)]
pub struct StagedDirectory {
    path: PathBuf,
    staging: tempfile::TempDir,
}

impl StagedDirectory {
    /// Starts building `path`, which must not exist, or be an empty directory.
    pub fn new(path: &Path) -> Result<Self, Failure> {
        require_new_or_empty_dir(path)?;
        let parent = match path.parent() {
            Some(dir) if !dir.as_os_str().is_empty() => dir,
            _ => Path::new("."),
        };
        let fail = |what: &str, err: std::io::Error| Failure::BadInput(format!("cannot {what} {}: {err}", path.display()));
        std::fs::create_dir_all(parent).map_err(|err| fail("create the parent of", err))?;
        let staging = tempfile::Builder::new()
            .prefix(".cnfmp-")
            .tempdir_in(parent)
            .map_err(|err| fail("create a temporary directory beside", err))?;
        Ok(StagedDirectory { path: path.to_path_buf(), staging })
    }

    fn fail(&self, what: &str, err: std::io::Error) -> Failure {
        Failure::BadInput(format!("cannot {what} {}: {err}", self.path.display()))
    }

    /// Writes the file `name` (a relative path; its folders are created) with `contents`.
    pub fn write(&self, name: &str, contents: &[u8]) -> Result<(), Failure> {
        let target = self.staging.path().join(name);
        if let Some(folder) = target.parent() {
            std::fs::create_dir_all(folder).map_err(|err| self.fail(&format!("create the folder of {name} for"), err))?;
        }
        std::fs::write(&target, contents).map_err(|err| self.fail(&format!("write {name} for"), err))
    }

    /// Renames the finished directory into place.
    pub fn finish(self) -> Result<(), Failure> {
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(self.staging.path(), std::fs::Permissions::from_mode(0o755))
                .map_err(|err| self.fail("set permissions of", err))?;
        }
        if self.path.is_dir() {
            std::fs::remove_dir(&self.path).map_err(|err| self.fail("replace the empty directory", err))?;
        }
        std::fs::rename(self.staging.path(), &self.path).map_err(|err| self.fail("create", err))?;
        let _moved = self.staging.keep(); // nothing is left to remove
        Ok(())
    }
}

/// A bad-input failure unless `path` is an existing file; `what` names it in the message.
pub fn require_file(path: &Path, what: &str) -> Result<(), Failure> {
    if path.is_file() {
        Ok(())
    } else {
        Err(Failure::BadInput(format!("{what} {} does not exist or is not a file", path.display())))
    }
}

/// The bytes of the input file `path`; `what` names it in the error.
pub fn read_bytes(path: &Path, what: &str) -> Result<Vec<u8>, Failure> {
    std::fs::read(path).map_err(|err| Failure::BadInput(format!("cannot read {what} {}: {err}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_staged_directory_appears_complete_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let staged = StagedDirectory::new(&out).unwrap();
        staged.write("a/b.txt", b"nested").unwrap();
        staged.write("top.txt", b"top").unwrap();
        assert!(!out.exists(), "nothing shows before finish");
        staged.finish().unwrap();
        assert_eq!(std::fs::read(out.join("a/b.txt")).unwrap(), b"nested");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "no staging directory is left");
        assert!(StagedDirectory::new(&out).unwrap_err().to_string().contains("already exists"));

        let abandoned = dir.path().join("abandoned");
        let staged = StagedDirectory::new(&abandoned).unwrap();
        staged.write("x.txt", b"x").unwrap();
        drop(staged); // a failure before finish
        assert!(!abandoned.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "the staging directory is removed");
    }
}
