//! Folders hilo writes, claimed for a run's life ([`claim`]).
//!
//! An output folder (a dataset, a study, a validation, a training run, placements, metrics) is
//! hilo's while a run writes it:
//! - **One writer.** The run holds an advisory lock (`flock`) on the folder itself, so no lock
//!   file is left in it. A second run on the same folder is refused at once, with the holder's
//!   process id where the system tells it (`/proc/locks`). Stages of one study or validation
//!   that a workflow engine runs side by side take the folder [`Mode::Shared`] and the
//!   sub-folder each one writes [`Mode::Exclusive`]; a whole run takes the folder exclusive.
//! - **No links.** hilo never makes a symbolic link, so one inside a folder it writes was
//!   planted there: a link in place of a sub-folder would send every write below it to another
//!   folder. The claim walks the folder and refuses any link, naming it. (The folder itself may
//!   be a link: it is the path the user chose.)
//!
//! Claims nest within one process: a command claims its output folder before its first
//! expensive step (so a second run is refused at once), and the library function that writes
//! the folder claims it again; the second claim shares the first's lock.
//!
//! The lock is advisory: it keeps hilo runs apart, not other programs.

use crate::fs::FileError;
use std::path::Path;
use std::sync::{Arc, Mutex, Weak};

/// How a folder is claimed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// The only writer: a whole run, or a stage's own sub-folder.
    Exclusive,
    /// One of several stages of a run that write disjoint sub-folders of this one, each claimed
    /// exclusive; a whole run on the folder is refused while any holds it.
    Shared,
}

/// A claimed folder; the claim ends when this (and every nested claim of the same folder in
/// this process) is dropped.
#[derive(Debug)]
pub struct Claim {
    _lock: Arc<Lock>,
}

/// The folder's open description holding the flock. Dropping it unlocks explicitly: closing
/// the descriptor alone would leave the lock held while a child forked meanwhile (by any thread
/// of this process) still has its copy, for the instant before its `exec`.
#[derive(Debug)]
struct Lock(std::fs::File);

impl Drop for Lock {
    fn drop(&mut self) {
        let _ = self.0.unlock();
    }
}

/// A folder's (device, inode): the same folder under any of its paths.
type FolderId = (u64, u64);

/// The folders this process holds, for nested claims.
static HELD: Mutex<Vec<(FolderId, Weak<Lock>)>> = Mutex::new(Vec::new());

/// Creates `dir` (and its parents) if missing, refuses it when another hilo run holds it (see
/// [`Mode`]) or when a symbolic link lies anywhere inside it, and holds it until the returned
/// [`Claim`] is dropped.
pub fn claim(dir: &Path, mode: Mode) -> Result<Claim, FileError> {
    match std::fs::symlink_metadata(dir) {
        Ok(m) if !m.is_dir() && !std::fs::metadata(dir).is_ok_and(|m| m.is_dir()) => {
            return Err(FileError::content(dir, "exists and is not a folder; an output path names a folder"));
        }
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::create_dir_all(dir).map_err(|e| FileError::io(dir, e))?;
        }
        Err(e) => return Err(FileError::io(dir, e)),
    }
    let lock = std::fs::File::open(dir).map_err(|e| FileError::io(dir, e))?;
    let id = {
        use std::os::unix::fs::MetadataExt as _;
        let m = lock.metadata().map_err(|e| FileError::io(dir, e))?;
        (m.dev(), m.ino())
    };
    let mut held = HELD.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    held.retain(|(_, w)| w.strong_count() > 0);
    if let Some(lock) = held.iter().find(|(k, _)| *k == id).and_then(|(_, w)| w.upgrade()) {
        drop(held);
        refuse_links(dir)?;
        return Ok(Claim { _lock: lock });
    }
    let taken = match mode {
        Mode::Exclusive => lock.try_lock(),
        Mode::Shared => lock.try_lock_shared(),
    };
    match taken {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let holder = holder_pid(&lock).map(|p| format!(" (pid {p})")).unwrap_or_default();
            return Err(FileError::content(
                dir,
                format!(
                    "another hilo run is writing this folder{holder}; wait for it to finish, or choose another output folder"
                ),
            ));
        }
        Err(std::fs::TryLockError::Error(e)) => return Err(FileError::io(dir, e)),
    }
    let lock = Arc::new(Lock(lock));
    held.push((id, Arc::downgrade(&lock)));
    drop(held);
    refuse_links(dir)?;
    Ok(Claim { _lock: lock })
}

/// Refuses the first symbolic link found at any depth inside `dir` (not `dir` itself).
fn refuse_links(dir: &Path) -> Result<(), FileError> {
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        let entries = match std::fs::read_dir(&d) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(FileError::io(&d, e)),
        };
        for entry in entries {
            let entry = entry.map_err(|e| FileError::io(&d, e))?;
            // Stages of one study write beside each other while one claims: an entry renamed
            // away between the listing and its look-up is no link.
            let t = match entry.file_type() {
                Ok(t) => t,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
                Err(e) => return Err(FileError::io(&entry.path(), e)),
            };
            if t.is_symlink() {
                return Err(FileError::content(
                    &entry.path(),
                    format!(
                        "is a symbolic link inside {}, a folder hilo writes; hilo does not follow links there (a write \
                         could land in another folder): remove the link, or choose another output folder",
                        dir.display()
                    ),
                ));
            }
            if t.is_dir() {
                todo.push(entry.path());
            }
        }
    }
    Ok(())
}

/// The process holding an flock on `file`'s inode, from `/proc/locks` (Linux); `None` where the
/// system does not say.
fn holder_pid(file: &std::fs::File) -> Option<u32> {
    use std::os::unix::fs::MetadataExt as _;
    let meta = file.metadata().ok()?;
    let dev = meta.dev();
    let major = ((dev >> 8) & 0xfff) | ((dev >> 32) & !0xfff);
    let minor = (dev & 0xff) | ((dev >> 12) & !0xff);
    let want = format!("{major:02x}:{minor:02x}:{}", meta.ino());
    let locks = std::fs::read_to_string("/proc/locks").ok()?;
    holder_in(&locks, &want)
}

/// The pid on the first FLOCK line of a `/proc/locks` text whose device:inode is `want`.
fn holder_in(locks: &str, want: &str) -> Option<u32> {
    locks.lines().find_map(|line| {
        let f: Vec<&str> = line.split_whitespace().collect();
        // "1: FLOCK  ADVISORY  WRITE 12345 fd:01:1234567 0 EOF"; blocked waiters have a "->".
        let f = if f.get(1) == Some(&"->") { &f[1..] } else { &f[..] };
        (f.get(1) == Some(&"FLOCK") && f.get(5) == Some(&want)).then(|| f.get(4)?.parse().ok()).flatten()
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    #[test]
    fn a_second_claim_is_refused_with_the_holder_and_a_shared_one_admits_shared_ones() {
        let d = tempdir("claims");
        let out = d.join("out");
        std::fs::create_dir_all(&out).unwrap();
        // Another run's lock: an open description of the folder that is not this process's claim.
        let other = std::fs::File::open(&out).unwrap();
        other.try_lock().unwrap();
        let e = claim(&out, Mode::Exclusive).unwrap_err().to_string();
        assert!(e.contains("another hilo run") && e.contains(&out.display().to_string()), "{e}");
        assert!(e.contains(&format!("pid {}", std::process::id())), "{e}");
        assert!(claim(&out, Mode::Shared).is_err());
        other.unlock().unwrap();
        other.try_lock_shared().unwrap();
        let a = claim(&out, Mode::Shared).unwrap();
        drop(a);
        assert!(claim(&out, Mode::Exclusive).is_err(), "a whole run waits for every stage");
        // Unlock, not only close: another test's child, forked at this instant, would hold a
        // copy of the descriptor and with it the lock.
        other.unlock().unwrap();
        drop(other);
        // Nested claims in one process share the lock, and it is free again only after the last.
        let outer = claim(&out, Mode::Exclusive).unwrap();
        let inner = claim(&out, Mode::Exclusive).unwrap();
        let probe = std::fs::File::open(&out).unwrap();
        drop(outer);
        assert!(probe.try_lock().is_err(), "the inner claim still holds the folder");
        drop(inner);
        probe.try_lock().unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_link_anywhere_inside_is_refused_by_name_and_a_file_is_not_a_folder() {
        let d = tempdir("links");
        let out = d.join("out");
        let victim = d.join("victim");
        std::fs::create_dir_all(out.join("a/b")).unwrap();
        std::fs::create_dir_all(&victim).unwrap();
        std::os::unix::fs::symlink(&victim, out.join("a/b/v1.0-trainval")).unwrap();
        let e = claim(&out, Mode::Exclusive).unwrap_err().to_string();
        assert!(e.contains("v1.0-trainval") && e.contains("symbolic link"), "{e}");
        std::fs::remove_file(out.join("a/b/v1.0-trainval")).unwrap();
        claim(&out, Mode::Exclusive).unwrap();
        // The folder itself may be a link: it is the user's path.
        std::os::unix::fs::symlink(&out, d.join("alias")).unwrap();
        claim(&d.join("alias"), Mode::Exclusive).unwrap();
        std::fs::write(d.join("file"), b"x").unwrap();
        let e = claim(&d.join("file"), Mode::Exclusive).unwrap_err().to_string();
        assert!(e.contains("not a folder"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn the_holder_is_read_from_proc_locks_lines() {
        let text = "1: POSIX  ADVISORY  WRITE 7 fd:01:99 0 EOF\n2: FLOCK  ADVISORY  WRITE 4242 fd:01:99 0 EOF\n2: -> FLOCK  ADVISORY  WRITE 5 fd:01:99 0 EOF\n";
        assert_eq!(holder_in(text, "fd:01:99"), Some(4242));
        assert_eq!(holder_in(text, "fd:01:98"), None);
    }

    fn tempdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("hilo-folder-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }
}
