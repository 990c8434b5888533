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

    /// The input (as the user gave it) that `path` is the same file as, if any.
    fn input_at(&self, path: &Path) -> Option<&(FileId, PathBuf)> {
        let id = file_id(path)?;
        self.files.iter().find(|(f, _)| *f == id)
    }

    /// True when `path` is one of the inputs, by any name.
    pub fn contains(&self, path: &Path) -> bool {
        self.input_at(path).is_some()
    }

    /// Refuses (usage error, nothing written) a destination that is one of the inputs. `what`
    /// names the destination for the message, e.g. "output" or "--save-layers file".
    pub fn check_write(&self, dest: &Path, what: &str) -> Result<()> {
        match self.input_at(dest) {
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

/// The folder `path` is written in: its parent, or `.` for a bare name (whose parent is
/// empty).
pub fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Where `path` would be written: the identity of its folder and its name there, so that two
/// spellings of a file that does not exist yet (`o/a.npy`, `./o/../o/a.npy`) compare equal.
/// None when the folder does not exist (the write will fail on it anyway).
fn place(path: &Path) -> Option<(FileId, std::ffi::OsString)> {
    let dir = folder_of(path);
    Some((file_id(dir)?, path.file_name()?.to_os_string()))
}

/// True when writing `a` and writing `b` would write the same file: the same place
/// ([`place`]), or, for files that exist, the same identity (links and hard links included).
pub fn same_destination(a: &Path, b: &Path) -> bool {
    let same_file = matches!((file_id(a), file_id(b)), (Some(x), Some(y)) if x == y);
    same_file || matches!((place(a), place(b)), (Some(x), Some(y)) if x == y) || a == b
}

/// Refuses (usage error, nothing written) two destinations of one run that are the same file
/// ([`same_destination`]): the second write would replace the first. `dests` pairs each path
/// with its name for the message (a flag or parameter name, e.g. "dfd.log"). O(n²) in the
/// handful of destinations a run has.
pub fn check_distinct(dests: &[(&Path, &str)]) -> Result<()> {
    for (i, (a, what_a)) in dests.iter().enumerate() {
        if let Some((b, what_b)) = dests[..i].iter().find(|(b, _)| same_destination(a, b)) {
            return Err(Error::usage(format!(
                "{what_a} {} and {what_b} {} are the same file: each file a run writes must be distinct (the second would replace the first)",
                a.display(),
                b.display()
            )));
        }
    }
    Ok(())
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
        // The input's own name is named once; another spelling names the input as well.
        let err = guard.check_write(&input, "output").unwrap_err().to_string();
        assert!(err.contains("is also an input of this run"), "{err}");
        let err = guard.check_write(&dir.join("sub/../depth.exr"), "output").unwrap_err().to_string();
        assert!(err.contains("sub/../depth.exr is the input") && err.ends_with("choose another destination"), "{err}");
        // Every destination is checked, wherever the input is among them.
        let (fresh, spare) = (dir.join("new.png"), dir.join("spare.png"));
        assert!(guard.check_writes([fresh.as_path(), input.as_path(), spare.as_path()], "--save-layers file").is_err());
        assert!(guard.check_writes([fresh.as_path(), spare.as_path()], "--save-layers file").is_ok());
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

    #[test]
    fn two_spellings_of_one_destination_are_refused() {
        let t = tempfile::tempdir().unwrap();
        let dir = t.path();
        std::fs::create_dir(dir.join("o")).unwrap();
        let (a, b) = (dir.join("o/al.npy"), dir.join("o/../o/./al.npy"));
        // Neither exists yet: the folder and the name decide.
        assert!(same_destination(&a, &b));
        let err = check_distinct(&[(&a, "output"), (&dir.join("o/al.csv"), "dfd.log"), (&b, "dfd.plot")]).unwrap_err().to_string();
        assert!(err.contains("dfd.plot") && err.contains("output") && err.contains("al.npy"), "{err}");
        assert!(check_distinct(&[(&a, "output"), (&dir.join("o/al.csv"), "dfd.log")]).is_ok());
        // One name in two folders is two files.
        std::fs::create_dir(dir.join("p")).unwrap();
        assert!(!same_destination(&a, &dir.join("p/al.npy")));
        assert!(check_distinct(&[(&a, "output"), (&dir.join("p/al.npy"), "dfd.log")]).is_ok());
        assert_eq!((folder_of(&a), folder_of(Path::new("al.npy"))), (dir.join("o").as_path(), Path::new(".")));
        // An existing file and a link to it.
        std::fs::write(&a, b"x").unwrap();
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(&a, dir.join("link.npy")).unwrap();
            assert!(same_destination(&dir.join("link.npy"), &a));
        }
        // Relative to the working folder: `x.png` and `./x.png`.
        assert!(same_destination(Path::new("x.png"), Path::new("./x.png")));
        assert!(!same_destination(Path::new("x.png"), Path::new("y.png")));
    }
}
