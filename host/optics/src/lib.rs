//! Simulated optical scenes rendered from true motor shaft positions.
