//! optalign firmware core: motion planning, backlash, limits, persistence and the command dispatcher.
#![cfg_attr(not(test), no_std)]
