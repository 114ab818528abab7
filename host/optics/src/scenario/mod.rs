//! Scenario parameters: the TOML tables `[michelson]`, `[cavity]` and `[relay]` that configure
//! the three simulated scenes, their documented defaults, and validation that names the
//! offending field.
//!
//! Every table and sub-table uses `#[serde(default, deny_unknown_fields)]`: a missing key takes
//! its default, a misspelt key is an error naming the key. After parsing, [`Scenario::validate`]
//! (or the per-scene `validate`) checks ranges and reports `table.field: reason`.

mod cavity;
mod check;
mod michelson;
mod noise;
mod realism;
mod relay;

pub use cavity::{
    CavityParams, GhostParams, HaloParams, PrimaryParams, RingParams, SecondaryParams,
};
pub use michelson::MichelsonParams;
pub use noise::NoiseParams;
pub use realism::{BackgroundPhoto, BeamProfile, RealismParams, StraySpot, Texture};
pub use relay::{RelayCameraParams, RelayParams, SpeckleParams};

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Why a scenario could not be used.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ScenarioError {
    /// The TOML text did not parse, or named a field that does not exist.
    #[error("scenario TOML: {0}")]
    Parse(String),
    /// A value parsed but is out of its allowed range.
    #[error("{field}: {reason}")]
    Invalid {
        /// Dotted path of the field, e.g. `relay.mirror_diameter_mm`.
        field: String,
        /// What is wrong with it, including the value found.
        reason: String,
    },
}

/// The three scene tables of a scenario file.
///
/// A host scenario file may hold more tables (the mount, the rig); such a file embeds these
/// parameter types in its own top-level struct. This type covers the scenes alone.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// The Michelson interferometer scene.
    pub michelson: MichelsonParams,
    /// The two-mirror cavity scene.
    pub cavity: CavityParams,
    /// The four-mirror relay scene.
    pub relay: RelayParams,
}

impl Scenario {
    /// Parses a scenario from TOML text (missing keys take defaults) and validates it.
    pub fn from_toml_str(text: &str) -> Result<Self, ScenarioError> {
        let scenario: Scenario =
            toml::from_str(text).map_err(|e| ScenarioError::Parse(e.to_string()))?;
        scenario.validate()?;
        Ok(scenario)
    }

    /// Checks every table; the first problem found is returned.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        self.michelson.validate()?;
        self.cavity.validate()?;
        self.relay.validate()
    }
}
