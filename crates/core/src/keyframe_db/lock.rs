//! One writer per map ([`MapLock`]): an advisory lock on `<map>.lock` (the operating system releases
//! it when the process ends, however it ends), holding the owner's pid for the message a second
//! writer gets.

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::MapError;

/// The lock on a map file, held while this value lives.
#[derive(Debug)]
pub struct MapLock {
    _file: File,
    path: PathBuf,
}

impl MapLock {
    /// Takes the lock of the map `map`, or says which process holds it.
    pub fn acquire(map: &Path) -> Result<Self, MapError> {
        let path = PathBuf::from(format!("{}.lock", map.display()));
        let name = map.display().to_string();
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| MapError::Io {
                path: name.clone(),
                source,
            })?;
        }
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|source| MapError::Io {
                path: name.clone(),
                source,
            })?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => {
                let mut owner = String::new();
                let _ = file.read_to_string(&mut owner);
                return Err(MapError::Locked {
                    path: name,
                    reason: format!(
                        "in use by another dc_loc (pid {}, lock {}): two writers would overwrite each other's keyframes",
                        owner.trim(),
                        path.display()
                    ),
                });
            }
            Err(TryLockError::Error(source)) => return Err(MapError::Io { path: name, source }),
        }
        let _ = file.set_len(0);
        let _ = file.seek(SeekFrom::Start(0));
        let _ = write!(file, "{}", std::process::id());
        Ok(MapLock { _file: file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}
