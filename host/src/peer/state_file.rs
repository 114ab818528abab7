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

/// A state file on disk; written atomically (temporary file, then rename).
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
        std::fs::write(&temporary, serde_json::to_vec(&state)?)?;
        std::fs::rename(&temporary, &self.path)?;
        self.last_written = Some(flash.to_vec());
        Ok(())
    }
}
