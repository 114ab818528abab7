//! Shared fixtures for the hardware-in-the-loop suite.
