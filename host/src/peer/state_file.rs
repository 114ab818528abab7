//! The peer's state files: the controller's flash image in one file and the true mount
//! state in another beside it (`FILE.mounts.json`), so a restarted peer finds its record
//! where a board finds it and the mirrors physically where they were left. Each file is
//! replaced atomically (temporary file, then rename) and readable by its owner only (the
//! flash holds the access key).

use std::path::{Path, PathBuf};

use anyhow::Context;
use optalign_firmware::RamStorage;
use optalign_firmware::sim::{MountModel, SimDriver};

/// The flash file and the mounts file of one peer.
#[derive(Clone, Debug)]
pub struct StateFiles {
    flash: PathBuf,
    mounts: PathBuf,
    last_flash: Option<Vec<u8>>,
    last_mounts: Option<Vec<MountModel>>,
}

/// What the files held at start-up.
pub struct SavedBench {
    pub flash: RamStorage,
    /// `None` when the mounts file does not exist yet.
    pub mounts: Option<Vec<MountModel>>,
}

impl StateFiles {
    /// The flash image at `flash`, the mounts beside it.
    pub fn new(flash: PathBuf) -> Self {
        let mut mounts = flash.clone().into_os_string();
        mounts.push(".mounts.json");
        Self {
            flash,
            mounts: mounts.into(),
            last_flash: None,
            last_mounts: None,
        }
    }

    pub fn flash_path(&self) -> &Path {
        &self.flash
    }

    pub fn mounts_path(&self) -> &Path {
        &self.mounts
    }

    /// Reads both files; `None` when the flash file does not exist yet (a fresh board).
    pub fn load(&mut self) -> anyhow::Result<Option<SavedBench>> {
        let image = match std::fs::read(&self.flash) {
            Ok(bytes) => bytes,
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(error) => {
                return Err(error).with_context(|| format!("reading {}", self.flash.display()));
            }
        };
        let expected = RamStorage::new().as_bytes().len();
        anyhow::ensure!(
            image.len() == expected,
            "{} is not a simulated flash image ({} bytes, one is {expected}): a state file \
             from an older optalign? Remove it to start from a fresh board",
            self.flash.display(),
            image.len()
        );
        let mounts = match std::fs::read(&self.mounts) {
            Ok(bytes) => Some(
                serde_json::from_slice::<Vec<MountModel>>(&bytes)
                    .with_context(|| format!("{} is not a mounts file", self.mounts.display()))?,
            ),
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => None,
            Err(error) => {
                return Err(error).with_context(|| format!("reading {}", self.mounts.display()));
            }
        };
        self.last_flash = Some(image.clone());
        self.last_mounts = mounts.clone();
        Ok(Some(SavedBench {
            flash: RamStorage::from_bytes(&image),
            mounts,
        }))
    }

    /// Writes the mounts file when the mounts changed since the last write.
    pub fn save_mounts(&mut self, driver: &SimDriver) -> anyhow::Result<()> {
        let mounts: Vec<MountModel> = (0u8..).map_while(|a| driver.mount(a).cloned()).collect();
        if self.last_mounts.as_ref() == Some(&mounts) {
            return Ok(());
        }
        replace_private(&self.mounts, &serde_json::to_vec(&mounts)?)
            .with_context(|| format!("writing {}", self.mounts.display()))?;
        self.last_mounts = Some(mounts);
        Ok(())
    }

    /// Writes the flash file when the image changed since the last write.
    pub fn save_flash(&mut self, image: &[u8]) -> anyhow::Result<()> {
        if self.last_flash.as_deref() == Some(image) {
            return Ok(());
        }
        replace_private(&self.flash, image)
            .with_context(|| format!("writing {}", self.flash.display()))?;
        self.last_flash = Some(image.to_vec());
        Ok(())
    }
}

/// Replaces `path` with `bytes` through a temporary file beside it that only its owner may
/// read (0600 on Unix), so a reader sees the old or the new contents, never a mix. Not
/// synced to disk: what the files simulate is the controller losing power (the peer
/// process dying), which the operating system's page cache survives.
fn replace_private(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let mut temporary = path.to_path_buf().into_os_string();
    temporary.push(".tmp");
    let temporary = PathBuf::from(temporary);
    match std::fs::remove_file(&temporary) {
        Err(error) if error.kind() != std::io::ErrorKind::NotFound => return Err(error),
        _ => {}
    }
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, 0o600);
    let mut file = options.open(&temporary)?;
    file.write_all(bytes)?;
    std::fs::rename(&temporary, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(unix)]
    #[test]
    fn both_files_are_readable_by_their_owner_only() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("peer.flash");
        let mut files = StateFiles::new(path.clone());
        // A file left world-readable before (and a stale temporary) must not stay so.
        std::fs::write(&path, b"old").unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        std::fs::write(dir.path().join("peer.flash.tmp"), b"stale").unwrap();
        let mut storage = RamStorage::new();
        storage.as_bytes_mut()[0] = 1;
        files
            .save_mounts(&SimDriver::new([MountModel::new(0)]))
            .unwrap();
        files.save_flash(storage.as_bytes()).unwrap();
        for file in [files.flash_path(), files.mounts_path()] {
            let mode = std::fs::metadata(file).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o600, "{} mode {mode:o}", file.display());
        }
        let loaded = StateFiles::new(path).load().unwrap().unwrap();
        assert_eq!(loaded.flash, storage);
        assert_eq!(loaded.mounts, Some(vec![MountModel::new(0)]));
    }

    #[test]
    fn a_file_that_is_no_flash_image_is_refused_clearly() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("peer.json");
        std::fs::write(&path, br#"{"flash":[255],"mounts":[]}"#).unwrap();
        let error = StateFiles::new(path).load().err().unwrap().to_string();
        assert!(error.contains("is not a simulated flash image"), "{error}");
        assert!(error.contains("Remove it"), "{error}");
    }

    #[test]
    fn a_missing_flash_file_is_a_fresh_board() {
        let dir = tempfile::tempdir().unwrap();
        assert!(
            StateFiles::new(dir.path().join("none"))
                .load()
                .unwrap()
                .is_none()
        );
    }
}
