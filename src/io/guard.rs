//! Inputs are never overwritten: every file a run writes is checked against the files it
//! reads before anything is written.
//!
//! Files are compared by identity, not by spelling: on Unix by device and inode (which also
//! catches hard links and symbolic links), elsewhere by canonical path. A destination that does
//! not exist yet cannot be an input.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The identity of an existing file.
#[derive(Clone, Debug, PartialEq, Eq)]
enum FileId {
    #[cfg(unix)]
    Inode(u64, u64),
    #[cfg_attr(unix, allow(dead_code))]
    Canonical(PathBuf),
}

fn file_id(path: &Path) -> Option<FileId> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(path).ok().map(|m| FileId::Inode(m.dev(), m.ino()))
    }
    #[cfg(not(unix))]
    {
        std::fs::canonicalize(path).ok().map(FileId::Canonical)
    }
}

/// The files a run reads, as identities, with the path the user gave for each.
#[derive(Clone, Debug, Default)]
pub struct InputFiles {
    files: Vec<(FileId, PathBuf)>,
}

impl InputFiles {
    /// Records `inputs` (files that do not exist are skipped: their reader reports them).
    pub fn new<P: AsRef<Path>>(inputs: impl IntoIterator<Item = P>) -> Self {
        let files = inputs.into_iter().filter_map(|p| file_id(p.as_ref()).map(|id| (id, p.as_ref().to_path_buf()))).collect();
        InputFiles { files }
    }

    /// Refuses (usage error, nothing written) a destination that is one of the inputs. `what`
    /// names the destination for the message, e.g. "output" or "--save-layers file".
    pub fn check_write(&self, dest: &Path, what: &str) -> Result<()> {
        let Some(id) = file_id(dest) else { return Ok(()) };
        match self.files.iter().find(|(f, _)| *f == id) {
            Some((_, input)) if input.as_path() == dest => Err(Error::usage(format!(
                "{what} {} is also an input of this run; it would be overwritten: choose another destination",
                dest.display()
            ))),
            Some((_, input)) => Err(Error::usage(format!(
                "{what} {} is the input {} (the same file); it would be overwritten: choose another destination",
                dest.display(),
                input.display()
            ))),
            None => Ok(()),
        }
    }

    /// [`InputFiles::check_write`] for every destination, before any is written.
    pub fn check_writes<'a>(&self, dests: impl IntoIterator<Item = &'a Path>, what: &str) -> Result<()> {
        dests.into_iter().try_for_each(|d| self.check_write(d, what))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_file_by_any_name_is_refused() {
        let dir = std::env::temp_dir().join(format!("drbokeh-guard-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let input = dir.join("depth.exr");
        std::fs::write(&input, b"x").unwrap();
        let guard = InputFiles::new([&input]);
        assert!(guard.check_write(&input, "output").is_err());
        // Another spelling of the same path.
        assert!(guard.check_write(&dir.join("sub/../depth.exr"), "output").is_err());
        #[cfg(unix)]
        {
            std::fs::hard_link(&input, dir.join("hard.exr")).unwrap();
            std::os::unix::fs::symlink(&input, dir.join("soft.exr")).unwrap();
            let err = guard.check_write(&dir.join("hard.exr"), "output").unwrap_err().to_string();
            assert!(err.contains("depth.exr"), "{err}");
            assert!(guard.check_write(&dir.join("soft.exr"), "output").is_err());
        }
        // A new file, or another existing one, is fine.
        assert!(guard.check_write(&dir.join("new.png"), "output").is_ok());
        std::fs::write(dir.join("other.png"), b"y").unwrap();
        assert!(guard.check_write(&dir.join("other.png"), "output").is_ok());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
