//! Files, the one set of helpers every hilo crate reads and writes them with, and the one error
//! that names the file ([`FileError`]; each crate's error wraps it).
//!
//! Writes are atomic: the content goes to a temporary file beside the target (same folder, so
//! the rename stays on one file system), then is renamed over it. A reader never sees half a
//! file, an interrupted run leaves the old file intact, and a failed write removes its
//! temporary file. Reads are bounded by the kind of file ([`limit`]).

use std::path::{Path, PathBuf};

/// A file that could not be read or written, or whose content is not what was expected.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("cannot read or write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Content { path: PathBuf, message: String },
}

impl FileError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        FileError::Io { path: path.to_path_buf(), source }
    }

    pub fn content(path: &Path, message: impl std::fmt::Display) -> Self {
        FileError::Content { path: path.to_path_buf(), message: message.to_string() }
    }

    /// The file the error is about.
    pub fn path(&self) -> &Path {
        match self {
            FileError::Io { path, .. } | FileError::Content { path, .. } => path,
        }
    }
}

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
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), FileError> {
    write_atomic_with(path, |tmp| std::fs::write(tmp, bytes), |e| e).map_err(|e| FileError::io(path, e))
}

/// Writes `value` to `path` atomically, as pretty JSON.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<(), FileError> {
    let bytes = serde_json::to_vec_pretty(value).map_err(|e| FileError::content(path, e))?;
    write_atomic(path, &bytes)
}

/// Reads a JSON file of at most `max` bytes into `T`; the error names the file and serde's
/// field and position.
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path, max: u64) -> Result<T, FileError> {
    let text = read_text_bounded(path, max).map_err(|e| FileError::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| FileError::content(path, e))
}

/// Size limits for reading, by kind of file: what the largest legitimate file of that kind
/// needs with room to spare, so a wrong path (`/dev/zero`, a video, a disk image) is refused
/// with a clear error instead of filling memory.
pub mod limit {
    /// A study, scene, catalog, training or detector configuration (TOML or JSON), a placement.
    pub const CONFIG: u64 = 16 << 20;
    /// A mesh imported into a scene (OBJ, glTF and its buffers).
    pub const MESH: u64 = 1 << 30;
    /// A road network (OpenDRIVE `.xodr`, which a city's map makes tens of megabytes).
    pub const ROAD_NETWORK: u64 = 512 << 20;
    /// One point file of a dataset (a LiDAR `.pcd.bin` or radar `.pcd`).
    pub const POINTS: u64 = 256 << 20;
    /// A table of a dataset, a results or metrics file, a checkpoint.
    pub const TABLE: u64 = 4 << 30;
}

/// Reads a whole regular file of at most `max` bytes. A path that is not a regular file (a
/// device such as `/dev/zero`, a FIFO, a folder) or a file larger than `max` is an
/// [`std::io::ErrorKind::InvalidData`] error that says which, before anything large is read.
/// The file type is checked before the file is opened (a FIFO would block `open` until a writer
/// came), and again on the opened file, which is opened non-blocking in case it was swapped
/// for a FIFO between the two.
pub fn read_bounded(path: &Path, max: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read as _;
    use std::os::unix::fs::OpenOptionsExt as _;
    let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidData, m);
    let regular = |meta: &std::fs::Metadata| match kind_of(&meta.file_type()) {
        "a regular file" => Ok(()),
        other => Err(invalid(format!("not a regular file ({other})"))),
    };
    regular(&std::fs::metadata(path)?)?;
    let file = std::fs::OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(path)?;
    let meta = file.metadata()?;
    regular(&meta)?;
    if meta.len() > max {
        return Err(invalid(format!("{} bytes, more than the {max} a file of this kind may have", meta.len())));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    // `take` guards against a file that grows while it is read.
    file.take(max + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max {
        return Err(invalid(format!("more than the {max} bytes a file of this kind may have")));
    }
    Ok(bytes)
}

/// What a file type is, in words, for an error message.
fn kind_of(t: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt as _;
    if t.is_file() {
        "a regular file"
    } else if t.is_dir() {
        "a folder"
    } else if t.is_symlink() {
        "a symbolic link"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_char_device() || t.is_block_device() {
        "a device"
    } else {
        "not a file"
    }
}

/// [`read_bounded`] as UTF-8 text; a leading byte-order mark is dropped (editors on Windows
/// write one, and the TOML and JSON parsers refuse it).
pub fn read_text_bounded(path: &Path, max: u64) -> std::io::Result<String> {
    let bytes = read_bounded(path, max)?;
    let mut text = String::from_utf8(bytes)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, format!("not UTF-8 text: {e}")))?;
    if text.starts_with('\u{feff}') {
        text.drain(..'\u{feff}'.len_utf8());
    }
    Ok(text)
}

/// The files directly in `dir` whose name ends in `.<ext>`, sorted by name (a study sweep's
/// folder, the site library).
pub fn files_with_extension(dir: &Path, ext: &str) -> Result<Vec<PathBuf>, FileError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| FileError::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|x| x == ext))
        .collect();
    files.sort();
    Ok(files)
}

/// Whether a folder holds a file (or anything but a folder) at any depth; a missing folder
/// holds none.
pub fn holds_file(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|d| {
        d.filter_map(|e| e.ok()).any(|e| e.file_type().is_ok_and(|t| !t.is_dir()) || holds_file(&e.path()))
    })
}

/// Checks that `name` can be one component of a path inside the folder it belongs to: not
/// empty, not `.` or `..`, no path separator, no control character (a newline in a file name
/// breaks every tool that lists files by line), not hidden (a leading `.`), at most 200 bytes.
/// Returns why not, for the caller's error (which names the file and field).
pub fn check_file_name(name: &str) -> Result<(), &'static str> {
    if name.is_empty() {
        return Err("is empty; a name becomes a file name");
    }
    if name == "." || name == ".." {
        return Err("names a folder, not a file");
    }
    if name.contains(['/', '\\']) {
        return Err("contains a path separator; a name becomes one file name in its folder");
    }
    if name.chars().any(char::is_control) {
        return Err("contains a control character (newline, tab, ...)");
    }
    if name.starts_with('.') {
        return Err("starts with '.', which would make a hidden file");
    }
    if name.len() > 200 {
        return Err("is longer than 200 bytes");
    }
    Ok(())
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
    fn files_with_an_extension_are_the_plain_files_sorted_by_name() {
        let d = dir();
        for f in ["z.toml", "a.toml", "b.txt", "toml", "c.toml.bak"] {
            std::fs::write(d.join(f), b"").unwrap();
        }
        std::fs::create_dir_all(d.join("m.toml")).unwrap();
        let got = files_with_extension(&d, "toml").unwrap();
        assert_eq!(got, vec![d.join("a.toml"), d.join("z.toml")]);
        let missing = d.join("none");
        let e = files_with_extension(&missing, "toml").unwrap_err();
        assert_eq!(e.path(), missing.as_path());
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

    #[test]
    fn bounded_reads_refuse_devices_and_oversized_files_and_drop_a_bom() {
        let d = dir();
        let e = read_bounded(Path::new("/dev/zero"), 1 << 20).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        assert!(read_bounded(&d, 10).unwrap_err().to_string().contains("not a regular file"));
        let f = d.join("big.toml");
        std::fs::write(&f, vec![b'a'; 101]).unwrap();
        let e = read_bounded(&f, 100).unwrap_err();
        assert!(e.to_string().contains("101 bytes") && e.to_string().contains("100"), "{e}");
        assert_eq!(read_bounded(&f, 101).unwrap().len(), 101);
        std::fs::write(&f, "\u{feff}a = 1").unwrap();
        assert_eq!(read_text_bounded(&f, 100).unwrap(), "a = 1");
        std::fs::write(&f, [0xff, 0xfe, 0x00]).unwrap();
        assert!(read_text_bounded(&f, 100).unwrap_err().to_string().contains("UTF-8"));
        // A link to a regular file reads through; a link to a device does not.
        std::os::unix::fs::symlink(&f, d.join("link.toml")).unwrap();
        assert_eq!(read_bounded(&d.join("link.toml"), 100).unwrap().len(), 3);
        std::os::unix::fs::symlink("/dev/zero", d.join("zero.obj")).unwrap();
        let e = read_bounded(&d.join("zero.obj"), 1 << 20).unwrap_err();
        assert!(e.to_string().contains("a device"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_fifo_is_refused_at_once_instead_of_blocking_on_open() {
        let d = dir();
        let fifo = d.join("study.toml");
        let status = std::process::Command::new("mkfifo").arg(&fifo).status().unwrap();
        assert!(status.success());
        // No writer ever opens the FIFO: an `open` before the type check would block for good.
        let t = std::time::Instant::now();
        let e = read_bounded(&fifo, 1 << 20).unwrap_err();
        assert!(e.to_string().contains("a FIFO"), "{e}");
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn file_names_that_would_leave_their_folder_or_hide_are_refused() {
        for bad in ["", ".", "..", "a/b", "x/../../../ESC3", "..\\x", "a\nb", "a\rb", ".hidden", &"n".repeat(201)] {
            assert!(check_file_name(bad).is_err(), "{bad:?}");
        }
        for good in ["lidar-16", "radar 4d", "v1.0-trainval", "ARS548_rdi", "lidar..16"] {
            assert_eq!(check_file_name(good), Ok(()), "{good:?}");
        }
    }
}
