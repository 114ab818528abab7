//! The simulated camera: the scene renderer looking at the true shaft positions of
//! simulated peers in this process, through the rig file's axis map. It lets the whole lab
//! rig path (controllers over TCP, camera, camera mover) run without hardware.

use std::sync::{Arc, Mutex};

use async_trait::async_trait;
use optalign_optics::{CameraPose, Cavity, Frame, Michelson, Relay, Station};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::Camera;
use crate::lab::rigfile::AxisRoute;
use crate::peer::SimPeer;

/// The scene a simulated camera looks at.
pub enum SimScene {
    Michelson(Michelson),
    Cavity(Cavity),
    Relay(Box<Relay>),
}

/// What the simulated camera sees and where it stands; shared with the simulated mover.
pub struct SimView {
    scene: SimScene,
    pose: Mutex<(CameraPose, ChaCha8Rng)>,
}

impl SimView {
    pub fn new(scene: SimScene, seed: u64) -> Self {
        let mut placements = ChaCha8Rng::seed_from_u64(seed ^ 0x51_4d_43_41);
        let pose = match &scene {
            SimScene::Relay(relay) => {
                CameraPose::place(Station::C8, &relay.params().camera, &mut placements)
            }
            _ => CameraPose::nominal(Station::C8),
        };
        Self {
            scene,
            pose: Mutex::new((pose, placements)),
        }
    }

    /// Places the camera at `station` with a fresh placement error (relay).
    pub fn place(&self, station: Station) {
        if let SimScene::Relay(relay) = &self.scene {
            let mut guard = self.pose.lock().unwrap_or_else(|e| e.into_inner());
            let (pose, placements) = &mut *guard;
            *pose = CameraPose::place(station, &relay.params().camera, placements);
        }
    }

    fn render(&self, shafts: &[i32], frame_index: u64) -> Frame {
        match &self.scene {
            SimScene::Michelson(scene) => scene.render(shafts, frame_index),
            SimScene::Cavity(scene) => scene.render(shafts, frame_index),
            SimScene::Relay(scene) => {
                let pose = self.pose.lock().unwrap_or_else(|e| e.into_inner()).0;
                scene.render(shafts, &pose, frame_index)
            }
        }
    }
}

/// Renders the view from the peers' true shafts.
pub struct SimCamera {
    view: Arc<SimView>,
    peers: Vec<Arc<SimPeer>>,
    routes: Vec<AxisRoute>,
    frames: u64,
}

impl SimCamera {
    /// `peers[i]` is the simulated peer behind controller `i`; `routes` maps task axes.
    pub fn new(view: Arc<SimView>, peers: Vec<Arc<SimPeer>>, routes: Vec<AxisRoute>) -> Self {
        Self {
            view,
            peers,
            routes,
            frames: 0,
        }
    }

    /// True task-axis shaft positions (the mechanics, through the rig's axis map).
    pub fn task_shafts(&self) -> Vec<i32> {
        let shafts: Vec<Vec<i32>> = self.peers.iter().map(|p| p.shaft_positions()).collect();
        self.routes
            .iter()
            .map(|route| {
                route.sign
                    * shafts[route.controller]
                        .get(usize::from(route.axis))
                        .copied()
                        .unwrap_or(0)
            })
            .collect()
    }
}

#[async_trait]
impl Camera for SimCamera {
    async fn capture(&mut self) -> anyhow::Result<Frame> {
        let frame = self.view.render(&self.task_shafts(), self.frames);
        self.frames += 1;
        Ok(frame)
    }

    fn describe(&self) -> String {
        "simulated camera".into()
    }
}
