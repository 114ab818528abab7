//! Whole-controller tests against the simulated mount.

mod backlash;
mod control;
mod dispatch;
mod hostile;
mod motion;
mod persistence;
mod rig;
mod robustness;
mod saving;
mod sessions;
