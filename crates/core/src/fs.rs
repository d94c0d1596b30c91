//! Atomic file writes, the one helper every hilo crate writes files with: the content goes to a
//! temporary file beside the target (same folder, so the rename stays on one file system), then
//! is renamed over it. A reader never sees half a file, an interrupted run leaves the old file
//! intact, and a failed write removes its temporary file.

use std::path::{Path, PathBuf};

/// The temporary name `path`'s content is written under before the rename.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp{}", std::process::id()))
}

/// Writes through `write` (given the temporary path) and renames the result over `path`; on any
/// error the temporary file is removed. The folder is created if missing; `io` turns the file
/// system's own errors (folder, rename) into the caller's.
pub fn write_atomic_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
    io: impl Fn(std::io::Error) -> E,
) -> Result<(), E> {
    if path.file_name().is_none() {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} is not a file path", path.display()),
        )));
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(&io)?;
    }
    let tmp = temp_path(path);
    let done = write(&tmp).and_then(|_| std::fs::rename(&tmp, path).map_err(&io));
    if done.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    done
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |tmp| std::fs::write(tmp, bytes), |e| e)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn dir() -> PathBuf {
        let d = std::env::temp_dir().join(format!("hilo-fs-{}-{:?}", std::process::id(), std::thread::current().id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_failed_write_leaves_nothing_behind_and_a_good_one_replaces_whole() {
        let d = dir();
        // The target is a folder: the rename fails, and the temporary file goes with it.
        let target = d.join("picture.png");
        std::fs::create_dir_all(target.join("inside")).unwrap();
        assert!(write_atomic(&target, b"png").is_err());
        let left: Vec<_> = std::fs::read_dir(&d).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left, vec![std::ffi::OsString::from("picture.png")]);
        // The writer fails half-way: nothing is left either, and the old file is intact.
        let f = d.join("a.json");
        write_atomic(&f, b"old").unwrap();
        let e: std::io::Result<()> = write_atomic_with(
            &f,
            |tmp| {
                std::fs::write(tmp, b"half")?;
                Err(std::io::Error::other("disk full"))
            },
            |e| e,
        );
        assert!(e.is_err());
        assert_eq!(std::fs::read(&f).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 2);
        write_atomic(&f, b"new").unwrap();
        assert_eq!(std::fs::read(&f).unwrap(), b"new");
        // Folders are created.
        write_atomic(&d.join("x/y/z.txt"), b"1").unwrap();
        std::fs::remove_dir_all(&d).unwrap();
    }
}
