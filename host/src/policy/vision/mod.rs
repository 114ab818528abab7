//! The image-only vision agent ("vision"): from the images, its actions' feedback and the brief
//! alone, it probes each actuator, fits an affine motor-to-image map to clean sightings of the
//! feature that moved, solves it for the target and declares done when a further image agrees.

mod backdrops;
mod bench;
mod cavity;
mod michelson;
mod model;
mod relay;
mod see;
mod servo;
mod sight;
mod tuning;

use async_trait::async_trait;

use super::{Decision, Feedback, Observation, Policy, PolicyError, TaskBrief};
use crate::task::{Action, TaskKind};
use cavity::CavityAgent;
use michelson::MichelsonAgent;
use relay::RelayAgent;

/// The per-task agent (boxed: the relay's carries two servos and a frame).
enum Agent {
    Michelson(Box<MichelsonAgent>),
    Cavity(Box<CavityAgent>),
    Relay(Box<RelayAgent>),
}

/// The image-only alignment policy.
pub struct VisionPolicy {
    agent: Agent,
}

impl VisionPolicy {
    pub fn new(brief: &TaskBrief) -> Self {
        let agent = match brief.task {
            TaskKind::Michelson => {
                Agent::Michelson(Box::new(MichelsonAgent::new(&brief.limits.michelson)))
            }
            TaskKind::Cavity => Agent::Cavity(Box::new(CavityAgent::new(&brief.limits.cavity))),
            TaskKind::Relay => Agent::Relay(Box::new(RelayAgent::new(
                &brief.limits.relay,
                &brief.geometry,
            ))),
        };
        Self { agent }
    }
}

#[async_trait]
impl Policy for VisionPolicy {
    fn name(&self) -> String {
        "vision".into()
    }

    async fn decide(&mut self, observation: &Observation) -> Result<Decision, PolicyError> {
        let rejected = matches!(observation.feedback, Feedback::Rejected { .. });
        let (image, remaining) = (&observation.image, observation.remaining);
        let (claims, action) = match &mut self.agent {
            Agent::Michelson(agent) => {
                let action = agent.decide(image, rejected, remaining);
                (agent.claims(action.is_done()), action)
            }
            Agent::Cavity(agent) => {
                let action = agent.decide(image, rejected, remaining);
                (agent.claims(action.is_done()), action)
            }
            Agent::Relay(agent) => {
                let action = Action::Relay(agent.decide(image, rejected, remaining));
                (agent.claims(), action)
            }
        };
        Ok(Decision {
            claims: Some(claims),
            ..Decision::new(action)
        })
    }
}
