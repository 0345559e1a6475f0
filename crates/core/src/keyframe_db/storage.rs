//! Writing a file crash-safely ([`write_atomically`]): to a temporary file beside it, synced, renamed
//! over the old one, the directory synced. A kill at any moment leaves the previous or the new file,
//! never a partial one; a failed step removes the temporary file and reports the error. The
//! file-system steps go through [`Storage`], so that tests can inject ENOSPC, EIO or a kill at each.
//! Temporary files a killed process left behind are removed at the next start ([`clean_temp_files`]).

use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// The file-system steps of a crash-safe write.
pub trait Storage {
    /// Creates `path` (truncating it) with `bytes`.
    fn write_file(&mut self, path: &Path, bytes: &[u8]) -> io::Result<()>;
    /// Flushes `path`'s data to the disk.
    fn sync_file(&mut self, path: &Path) -> io::Result<()>;
    /// Renames `from` over `to`.
    fn rename(&mut self, from: &Path, to: &Path) -> io::Result<()>;
    /// Flushes the directory `dir` (the rename) to the disk.
    fn sync_dir(&mut self, dir: &Path) -> io::Result<()>;
    /// Removes `path`.
    fn remove(&mut self, path: &Path) -> io::Result<()>;
    /// False once the process is gone (a test's simulated kill): nothing is cleaned up after it.
    fn alive(&self) -> bool {
        true
    }
}

/// The real file system.
pub struct Disk;

impl Storage for Disk {
    fn write_file(&mut self, path: &Path, bytes: &[u8]) -> io::Result<()> {
        std::fs::File::create(path)?.write_all(bytes)
    }
    fn sync_file(&mut self, path: &Path) -> io::Result<()> {
        std::fs::OpenOptions::new()
            .write(true)
            .open(path)?
            .sync_all()
    }
    fn rename(&mut self, from: &Path, to: &Path) -> io::Result<()> {
        std::fs::rename(from, to)
    }
    fn sync_dir(&mut self, dir: &Path) -> io::Result<()> {
        std::fs::File::open(dir)?.sync_all()
    }
    fn remove(&mut self, path: &Path) -> io::Result<()> {
        std::fs::remove_file(path)
    }
}

/// The directory of `path` (`.` for a bare file name).
pub fn dir_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

fn temp_prefix(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_else(|| "map".into());
    format!(".{name}.tmp-")
}

/// The temporary file a write of `path` by this process goes through.
pub fn temp_path(path: &Path) -> PathBuf {
    dir_of(path).join(format!("{}{}", temp_prefix(path), std::process::id()))
}

/// Writes `bytes` to `path` crash-safely (see the module documentation).
pub fn write_atomically(storage: &mut dyn Storage, path: &Path, bytes: &[u8]) -> io::Result<()> {
    let dir = dir_of(path);
    std::fs::create_dir_all(dir)?;
    let tmp = temp_path(path);
    let written = storage
        .write_file(&tmp, bytes)
        .and_then(|()| storage.sync_file(&tmp))
        .and_then(|()| storage.rename(&tmp, path));
    if let Err(e) = written {
        if storage.alive() {
            let _ = storage.remove(&tmp);
        }
        return Err(e);
    }
    // The file is in place; an unsynced directory only risks the rename on a power cut.
    storage.sync_dir(dir)
}

/// Removes the temporary files that writes of `path` left behind (a process killed while writing);
/// returns them. Only the writer holding the map's lock may call it.
pub fn clean_temp_files(path: &Path) -> Vec<PathBuf> {
    let prefix = temp_prefix(path);
    let mut removed = Vec::new();
    for entry in std::fs::read_dir(dir_of(path))
        .into_iter()
        .flatten()
        .flatten()
    {
        let is_temp = entry.file_name().to_string_lossy().starts_with(&prefix);
        if is_temp && std::fs::remove_file(entry.path()).is_ok() {
            removed.push(entry.path());
        }
    }
    removed
}
