//! Camera movers: how the relay's camera gets from one station to another — a robot arm
//! driven by a command or an HTTP endpoint, a person, or the simulation.

mod command;
mod http;
mod manual;

use std::sync::Arc;

use async_trait::async_trait;
use optalign_optics::Station;

pub use command::CommandMover;
pub use http::HttpMover;
pub use manual::ManualMover;

use crate::lab::camera::SimView;

/// Moves the camera to a station and returns once it is there.
#[async_trait]
pub trait CameraMover: Send {
    async fn move_to(&mut self, station: Station) -> anyhow::Result<()>;

    fn describe(&self) -> String;
}

/// Moves the simulated camera (each placement adds the scene's placement error).
pub struct SimMover(pub Arc<SimView>);

#[async_trait]
impl CameraMover for SimMover {
    async fn move_to(&mut self, station: Station) -> anyhow::Result<()> {
        self.0.place(station);
        Ok(())
    }

    fn describe(&self) -> String {
        "simulated camera mover".into()
    }
}
