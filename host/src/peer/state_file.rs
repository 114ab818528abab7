//! The peer's state file: the controller's persisted flash record and the true mount
//! state, so a restarted peer comes back where it was (positions restored, as a board's
//! flash record restores them, and the mirrors physically where they were left).

use std::path::{Path, PathBuf};

use anyhow::Context;
use optalign_firmware::RamStorage;
use optalign_firmware::sim::{MountModel, SimDriver};
use serde::{Deserialize, Serialize};

/// What a state file holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SavedState {
    /// Raw bytes of the simulated flash region holding the controller's record slots.
    pub flash: Vec<u8>,
    /// The true state of every mount (dead band position, shaft, motor).
    pub mounts: Vec<MountModel>,
}

/// A state file on disk; written atomically (temporary file, then rename), readable and
/// writable by its owner only (it holds the access key).
pub struct StateFile {
    path: PathBuf,
    last_written: Option<Vec<u8>>,
}

impl StateFile {
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            last_written: None,
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Reads the file; `None` when it does not exist yet.
    pub fn load(&self) -> anyhow::Result<Option<SavedState>> {
        match std::fs::read(&self.path) {
            Ok(bytes) => {
                let state =
                    serde_json::from_slice(&bytes).context("the file is not a peer state file")?;
                Ok(Some(state))
            }
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(error) => Err(error.into()),
        }
    }

    /// Writes the flash image and mount state when the flash image changed since the
    /// last write (the firmware writes its record when motion stops, so this is then).
    pub fn save_if_changed(
        &mut self,
        storage: &RamStorage,
        driver: &SimDriver,
        axes: u8,
    ) -> anyhow::Result<()> {
        let flash = storage.as_bytes();
        if self.last_written.as_deref() == Some(flash) {
            return Ok(());
        }
        let state = SavedState {
            flash: flash.to_vec(),
            mounts: (0..axes)
                .filter_map(|axis| driver.mount(axis).cloned())
                .collect(),
        };
        let temporary = self.path.with_extension("tmp");
        write_private(&temporary, &serde_json::to_vec(&state)?)?;
        std::fs::rename(&temporary, &self.path)?;
        self.last_written = Some(flash.to_vec());
        Ok(())
    }
}

/// Writes `bytes` to a new file at `path` that only its owner may read (0600 on Unix); a
/// file left there before is replaced, so its permissions never carry over.
fn write_private(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    match std::fs::remove_file(path) {
        Err(error) if error.kind() != std::io::ErrorKind::NotFound => return Err(error),
        _ => {}
    }
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let mut file = options.open(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn the_state_file_is_readable_by_its_owner_only() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("peer.json");
        // A file left world-readable before (and a stale temporary) must not stay so.
        std::fs::write(&path, b"{}").unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        std::fs::write(path.with_extension("tmp"), b"stale").unwrap();
        let mut storage = RamStorage::new();
        storage.as_bytes_mut()[0] = 1;
        let mut file = StateFile::new(path.clone());
        file.save_if_changed(&storage, &SimDriver::new([MountModel::new(0)]), 1)
            .unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600, "state file mode {mode:o}");
        let loaded = file.load().unwrap().unwrap();
        assert_eq!(loaded.flash, storage.as_bytes());
    }
}
