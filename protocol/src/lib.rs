//! The optalign wire protocol: every message the host and the firmware exchange.
#![no_std]
