//! Atomic file output: write to a temporary file in the destination folder, then rename.
//!
//! A failure (encoder error, full disk) never leaves a half-written file at the destination;
//! the temporary file is removed on every error path.
//!
//! Temporary files are named `.NAME.PID-NONCE.drbokeh-tmp` and are exclusively locked
//! (`flock`, via [`File::try_lock`]) by their writer for as long as they exist. The kernel drops
//! the lock when the writer exits, however it exits (SIGKILL included), so
//! [`remove_stale_temps`] can tell a dead writer's leftover from a live one's file by trying
//! the lock: a PID check could not, since `/proc/PID` says nothing about a writer on another
//! host of a shared file system (a Slurm array writing one folder) and a PID is reused.
//! Every temporary file in flight is also listed in a process-wide registry so that a
//! signal handler can remove them before exiting ([`remove_in_flight_temps_and_exit`]).

use crate::error::{Error, Result};
use std::collections::BTreeSet;
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};

/// Longest file name (bytes) that common file systems accept (ext4, XFS, APFS, NTFS in UTF-16
/// units): a hidden sibling longer than this is shortened, see [`hidden_sibling`].
const NAME_MAX: usize = 255;
/// Bytes kept free after `.NAME.` for the suffix of a hidden sibling: a temp suffix is at most
/// 10 (PID) + 1 + 10 (nonce) + 12 (`.drbokeh-tmp`) = 33 bytes.
const SUFFIX_RESERVE: usize = 40;
/// Ending of every temporary file.
pub const TEMP_SUFFIX: &str = ".drbokeh-tmp";

/// Temporary files of this process that exist now (see [`remove_in_flight_temps_and_exit`]).
static IN_FLIGHT: Mutex<BTreeSet<PathBuf>> = Mutex::new(BTreeSet::new());
/// Makes nonces unique within the process (two threads in the same nanosecond).
static COUNTER: AtomicU32 = AtomicU32::new(0);

/// The `NAME` part of the hidden siblings of `path` (`.NAME.SUFFIX`): the file name itself, or,
/// when `.NAME.` plus [`SUFFIX_RESERVE`] would exceed [`NAME_MAX`], its first bytes (cut on a
/// character boundary) followed by `~` and a 64-bit FNV-1a hash of the whole name, so that two
/// long names sharing a prefix still get different siblings.
fn sibling_stem(path: &Path) -> String {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let budget = NAME_MAX - SUFFIX_RESERVE - 2;
    if name.len() <= budget {
        return name;
    }
    let hash = format!("~{:016x}", fnv1a64(name.as_bytes()));
    let mut cut = budget - hash.len();
    while !name.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}{hash}", &name[..cut])
}

/// `.NAME.SUFFIX` beside `path`, with NAME shortened when needed (see [`sibling_stem`]); always
/// fits in [`NAME_MAX`] bytes for a `suffix` of up to [`SUFFIX_RESERVE`] bytes.
pub fn hidden_sibling(path: &Path, suffix: &str) -> PathBuf {
    debug_assert!(suffix.len() <= SUFFIX_RESERVE, "hidden sibling suffix too long: {suffix}");
    path.with_file_name(format!(".{}.{suffix}", sibling_stem(path)))
}

/// 64-bit FNV-1a: a stable hash (unlike `std`'s, which may change between Rust releases), for
/// names and fingerprints that are stored on disk. O(bytes), no allocation.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
}

/// Name of a fresh temporary sibling used while `path` is being written:
/// `.NAME.PID-NONCE.drbokeh-tmp`, NONCE = nanoseconds of the clock plus a process-wide counter.
pub fn temp_path_for(path: &Path) -> PathBuf {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_nanos()).unwrap_or(0);
    let nonce = nanos.wrapping_add(COUNTER.fetch_add(1, Ordering::Relaxed).wrapping_mul(1_000_003));
    hidden_sibling(path, &format!("{}-{nonce}{TEMP_SUFFIX}", std::process::id()))
}

/// True if `name` is the name of a temporary file of this module (any output).
fn is_temp_name(name: &str) -> bool {
    let Some(rest) = name.strip_suffix(TEMP_SUFFIX).filter(|_| name.starts_with('.')) else { return false };
    let Some((_, id)) = rest.rsplit_once('.') else { return false };
    let Some((pid, nonce)) = id.split_once('-') else { return false };
    [pid, nonce].iter().all(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
}

/// Creates, locks and registers a new temporary file for `path`. Retries with a new name when
/// a concurrent [`remove_stale_temps`] took the file between its creation and the lock.
fn create_temp(path: &Path) -> Result<(PathBuf, File)> {
    for _ in 0..16 {
        let tmp = temp_path_for(path);
        let file = {
            // Created and registered under the registry lock, so that a signal handler in
            // `remove_in_flight_temps_and_exit` never misses a file.
            let mut reg = IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner());
            match OpenOptions::new().write(true).create_new(true).open(&tmp) {
                Ok(f) => {
                    reg.insert(tmp.clone());
                    f
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(Error::io(path, e)),
            }
        };
        match file.try_lock() {
            // Still there once locked: no cleaner can remove it any more.
            Ok(()) if tmp.exists() => return Ok((tmp, file)),
            Ok(()) | Err(std::fs::TryLockError::WouldBlock) => {
                drop(file);
                let _ = std::fs::remove_file(&tmp);
                unregister(&tmp);
            }
            // No locks on this file system: cleaners cannot lock it either, so they keep it.
            Err(std::fs::TryLockError::Error(_)) => return Ok((tmp, file)),
        }
    }
    Err(Error::Internal(format!("could not create a temporary file beside {}", path.display())))
}

fn unregister(tmp: &Path) {
    IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner()).remove(tmp);
}

/// How a destination that exists already is written (see [`destination`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Destination {
    /// A regular file, or none yet: a temporary sibling renamed over this path (a symbolic
    /// link's target, so that the link stays a link).
    Replace(PathBuf),
    /// A FIFO or a character device (`/dev/null`, a terminal, a pipe behind `/dev/stdout`):
    /// written through, in place; there is nothing to replace and no temporary file.
    Stream,
}

/// How `path` is written, or why it is not: a folder, a block device, a socket or a link to
/// nothing is refused (usage error naming the file) rather than replaced by a regular file.
/// A few `stat` calls; allocates the resolved path of a link.
pub fn destination(path: &Path) -> Result<Destination> {
    let refuse = |why: &str| Err(Error::usage(format!("cannot write {}: it is {why}; choose a regular file", path.display())));
    let link = match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Destination::Replace(path.to_path_buf())),
        Err(e) => return Err(Error::io(path, e)),
        Ok(m) => m.file_type().is_symlink(),
    };
    // What the path leads to (through any links).
    let kind = match std::fs::metadata(path) {
        Ok(m) => m.file_type(),
        Err(e) if link && e.kind() == std::io::ErrorKind::NotFound => return refuse("a symbolic link to a file that does not exist"),
        Err(e) => return Err(Error::io(path, e)),
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() || kind.is_char_device() {
            return Ok(Destination::Stream);
        } else if kind.is_block_device() {
            return refuse("a block device");
        } else if kind.is_socket() {
            return refuse("a socket");
        }
    }
    if kind.is_dir() {
        refuse("a folder")
    } else if link {
        std::fs::canonicalize(path).map(Destination::Replace).map_err(|e| Error::io(path, e))
    } else {
        Ok(Destination::Replace(path.to_path_buf()))
    }
}

/// Opens a FIFO or character device for writing through. A FIFO is opened without blocking
/// first, so that one nobody reads is an error at once (ENXIO) instead of a hang, and then
/// switched back to blocking writes.
#[cfg(unix)]
fn open_stream(path: &Path) -> Result<File> {
    use std::os::unix::fs::OpenOptionsExt;
    let file = OpenOptions::new().write(true).custom_flags(libc::O_NONBLOCK).open(path).map_err(|e| {
        if e.raw_os_error() == Some(libc::ENXIO) {
            Error::usage(format!("cannot write {}: it is a FIFO that no process is reading", path.display()))
        } else {
            Error::io(path, e)
        }
    })?;
    // SAFETY: `fcntl` on a descriptor this function owns; it changes only its status flags.
    let fd = std::os::fd::AsRawFd::as_raw_fd(&file);
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(Error::io(path, std::io::Error::last_os_error()));
    }
    Ok(file)
}

#[cfg(not(unix))]
fn open_stream(path: &Path) -> Result<File> {
    OpenOptions::new().write(true).open(path).map_err(|e| Error::io(path, e))
}

/// Writes `path` atomically with `write`. The closure gets a buffered writer; the data is
/// flushed and synced before the rename. A destination that is a symbolic link keeps being
/// one (its target is replaced); a FIFO or character device is written through, never
/// replaced; other special files are refused ([`destination`]).
pub fn write_atomic<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<()>,
{
    let target = match destination(path)? {
        Destination::Replace(target) => target,
        Destination::Stream => {
            let mut w = BufWriter::new(open_stream(path)?);
            write(&mut w)?;
            return w.flush().map_err(|e| Error::io(path, e));
        }
    };
    let dir = super::guard::folder_of(&target);
    if !dir.is_dir() {
        return Err(Error::input(path, format!("output folder '{}' does not exist", dir.display())));
    }
    let path = target.as_path();
    let (tmp, file) = create_temp(path)?;
    let result = (|| {
        let mut w = BufWriter::new(file);
        write(&mut w)?;
        w.flush().map_err(|e| Error::io(path, e))?;
        let file = w.into_inner().map_err(|e| Error::io(path, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(path, e))?;
        // Renamed while still locked (the lock follows the file, now at `path`, and is
        // released when `file` is dropped at the end of this closure).
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    unregister(&tmp);
    result
}

/// Removes the temporary files of this process that exist now and exits with `code`, keeping
/// the registry locked so that no new one appears meanwhile: for a SIGINT/SIGTERM handler
/// (`ctrlc` runs it on an ordinary thread, so taking the lock is allowed). A writer whose file
/// vanishes fails, but the process is gone before it could report.
pub fn remove_in_flight_temps_and_exit(code: i32) -> ! {
    let reg = IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner());
    for p in reg.iter() {
        let _ = std::fs::remove_file(p);
    }
    std::process::exit(code)
}

/// Removes the temporary files in `dir` whose writer is gone (their lock is free), whatever
/// output they belonged to; a file whose writer is alive, here or on another host, is kept, and
/// so is every file when the file system has no locks. One `read_dir` of `dir` (O(entries));
/// returns how many files were removed.
pub fn remove_stale_temps(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    let mut removed = 0;
    for e in entries.flatten() {
        if !is_temp_name(&e.file_name().to_string_lossy()) {
            continue;
        }
        // Opened for writing: NFS emulates flock with POSIX locks, whose exclusive form needs it.
        let Ok(f) = OpenOptions::new().write(true).open(e.path()) else { continue };
        if f.try_lock().is_ok() && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_fit_and_are_recognized() {
        let budget = NAME_MAX - SUFFIX_RESERVE - 2;
        for (len, lead) in [1, 200, 213, 214, 250, 255].into_iter().flat_map(|len| [(len, ""), (len, "a")]) {
            // Two-byte characters, so that some cuts fall inside one (a leading `a` puts the
            // cut inside a character: without it every cut falls between two).
            let name = format!("{lead}{}{}.png", "é".repeat(len / 2), "a".repeat(len % 2));
            let p = Path::new("/x").join(&name);
            let t = temp_path_for(&p);
            let tn = t.file_name().unwrap().to_str().unwrap();
            assert!(tn.len() <= NAME_MAX, "{} bytes: {tn}", tn.len());
            assert!(is_temp_name(tn), "{tn}");
            // Any sibling's suffix up to the reserve fits, not only a temp's (at most 33 bytes:
            // cargo-mutants' `- 2` → `+ 2` in the stem's budget fitted those and survived).
            let s = hidden_sibling(&p, &"s".repeat(SUFFIX_RESERVE));
            let sn = s.file_name().unwrap().to_str().unwrap();
            assert!(sn.len() <= NAME_MAX, "{} bytes: {sn}", sn.len());
            // A long name keeps as much of itself as fits (up to a character's bytes less).
            let stem = sibling_stem(&p);
            if name.len() > budget {
                assert!((budget - 1..=budget).contains(&stem.len()), "{} of {budget} bytes: {stem}", stem.len());
                assert!(name.starts_with(&stem[..stem.len() - 17]), "{stem}");
            } else {
                assert_eq!(stem, name);
            }
        }
        assert!(!is_temp_name(".a.png.12-x.drbokeh-tmp"));
        assert!(!is_temp_name("a.png.12-3.drbokeh-tmp"));
        // Two long names sharing their first 250 bytes get different stems.
        let (a, b) = (format!("{}a.png", "x".repeat(250)), format!("{}b.png", "x".repeat(250)));
        assert_ne!(sibling_stem(Path::new(&a)), sibling_stem(Path::new(&b)));
    }

    /// A finished write, and a failed one, leave nothing of theirs in the registry of
    /// temporaries the signal handler removes (a batch writes thousands: cargo-mutants'
    /// `unregister` made a no-op survived).
    #[test]
    fn finished_writes_leave_the_registry() {
        let t = tempfile::tempdir().unwrap();
        write_atomic(&t.path().join("a.png"), |w| w.write_all(b"x").map_err(|e| Error::io("a.png", e))).unwrap();
        let _ = write_atomic(&t.path().join("b.png"), |_| Err(Error::Internal("failed".into())));
        let ours = IN_FLIGHT.lock().unwrap_or_else(|e| e.into_inner()).iter().filter(|p| p.starts_with(t.path())).count();
        assert_eq!(ours, 0);
    }

    /// A FIFO with a reader is opened for writing through and switched back to blocking
    /// writes (a reader slower than the writer must not turn into `EAGAIN` errors); one that
    /// nobody reads is refused at once. (cargo-mutants: the flag switch's `&`, `!` and `||`
    /// survived the library's tests.)
    #[test]
    #[cfg(unix)]
    fn a_fifo_is_written_through_in_blocking_mode() {
        use std::os::unix::fs::OpenOptionsExt;
        let t = tempfile::tempdir().unwrap();
        let fifo = t.path().join("pipe.png");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid C string; mkfifo only creates the file.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        assert!(open_stream(&fifo).unwrap_err().to_string().contains("no process is reading"));
        let _reader = OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(&fifo).unwrap();
        let w = open_stream(&fifo).unwrap();
        // SAFETY: F_GETFL on a descriptor the test owns.
        let flags = unsafe { libc::fcntl(std::os::fd::AsRawFd::as_raw_fd(&w), libc::F_GETFL) };
        assert!(flags >= 0 && flags & libc::O_NONBLOCK == 0, "flags {flags:#x}");
    }

    /// The stored hash is FNV-1a 64 (batch fingerprints are kept on disk across versions):
    /// its published test vectors.
    #[test]
    fn fnv1a64_is_the_published_hash() {
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
    }

    /// A folder where no file can be created (`/proc`: even root gets an error) is the user's
    /// I/O error naming the output, at once, not an internal error after retrying names: only
    /// a name another file took is retried. (cargo-mutants: the retry's guard made `true`, or
    /// its `==` made `!=`, survived.)
    #[test]
    #[cfg(target_os = "linux")]
    fn an_uncreatable_temp_is_an_io_error_naming_the_output() {
        let out = Path::new("/proc/drbokeh-atomic-test.png");
        let e = write_atomic(out, |w| w.write_all(b"x").map_err(|e| Error::io(out, e))).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e:?}");
        assert!(e.to_string().contains("drbokeh-atomic-test.png"), "{e}");
    }

    /// A write that fails half-way (the encoder's error after some bytes) leaves the previous
    /// file as it was and no temporary file beside it.
    #[test]
    fn a_failed_write_keeps_the_previous_output() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path().join("a.png");
        std::fs::write(&out, b"previous").unwrap();
        let r = write_atomic(&out, |w| {
            w.write_all(&[7u8; 100_000]).map_err(|e| Error::io(&out, e))?;
            Err(Error::Internal("encoder failed".into()))
        });
        assert!(r.is_err());
        assert_eq!(std::fs::read(&out).unwrap(), b"previous");
        let names: Vec<_> = std::fs::read_dir(t.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.png")]);
        // A successful one replaces it.
        write_atomic(&out, |w| w.write_all(b"new").map_err(|e| Error::io(&out, e))).unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"new");
    }

    /// Special destinations: what [`destination`] answers for each kind of file.
    #[cfg(unix)]
    #[test]
    fn special_destinations_are_classified() {
        let t = tempfile::tempdir().unwrap();
        let (file, link) = (t.path().join("f.png"), t.path().join("l.png"));
        std::fs::write(&file, b"x").unwrap();
        std::os::unix::fs::symlink(&file, &link).unwrap();
        assert_eq!(destination(&t.path().join("new.png")).unwrap(), Destination::Replace(t.path().join("new.png")));
        assert_eq!(destination(&file).unwrap(), Destination::Replace(file.clone()));
        assert_eq!(destination(&link).unwrap(), Destination::Replace(std::fs::canonicalize(&file).unwrap()));
        assert_eq!(destination(Path::new("/dev/null")).unwrap(), Destination::Stream);
        assert!(destination(t.path()).unwrap_err().to_string().contains("folder"));
        std::os::unix::fs::symlink(t.path().join("none"), t.path().join("d.png")).unwrap();
        assert!(destination(&t.path().join("d.png")).unwrap_err().to_string().contains("does not exist"));
        // A link to itself is an I/O error (too many levels of links), not "does not exist"
        // (cargo-mutants: the dangling-link guard made `true` or its `&&` made `||` survived).
        std::os::unix::fs::symlink(t.path().join("loop.png"), t.path().join("loop.png")).unwrap();
        let e = destination(&t.path().join("loop.png")).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e:?}");
    }

    #[test]
    fn stale_temps_go_live_ones_stay() {
        let t = tempfile::tempdir().unwrap();
        let out = t.path().join("a.png");
        let (live, _file) = create_temp(&out).unwrap();
        let stale = temp_path_for(&out);
        std::fs::write(&stale, b"left by a dead writer").unwrap();
        std::fs::write(t.path().join(".a.png.notatemp"), b"").unwrap();
        assert_eq!(remove_stale_temps(t.path()), 1);
        assert!(live.exists() && !stale.exists() && t.path().join(".a.png.notatemp").exists());
        unregister(&live);
    }
}
