//! Fixtures for the hardware-in-the-loop suite: a controller under test, which is either a
//! freshly started simulated peer (the default, with hidden truth available) or a real
//! board named by `OPTALIGN_HIL=tcp://HOST:PORT` or `serial://PATH`.

use std::sync::Arc;

use optalign::link::{AccessKey, Client, ClientOptions, Endpoint};
use optalign::peer::{MechanicsOptions, PeerOptions, SimPeer, TimeMode};
use optalign_protocol::{AxisConfig, Command};

/// The key the simulated peers are provisioned with.
pub const SIM_KEY: &str = "hil-test-key";

/// Environment variable naming a real board to test instead of the simulator.
pub const HIL_ENV: &str = "OPTALIGN_HIL";

/// Environment variable with the real board's access key.
pub const KEY_ENV: &str = "OPTALIGN_KEY";

/// A controller under test.
pub struct Target {
    pub endpoint: Endpoint,
    /// Serial endpoint (the simulator's pseudo-terminal), when there is one.
    pub serial: Option<Endpoint>,
    pub key: Option<String>,
    /// The simulator, when testing against it (hidden truth lives here).
    pub sim: Option<Arc<SimPeer>>,
}

/// How the simulated peer for one test is set up.
#[derive(Clone, Debug)]
pub struct SimSetup {
    pub axes: u8,
    pub backlash: u32,
    pub time: TimeMode,
    pub key: Option<String>,
    pub state_file: Option<std::path::PathBuf>,
}

impl Default for SimSetup {
    fn default() -> Self {
        Self {
            axes: 4,
            backlash: 0,
            time: TimeMode::Instant,
            key: Some(SIM_KEY.into()),
            state_file: None,
        }
    }
}

impl Target {
    /// The real board from `OPTALIGN_HIL` if set, otherwise a new simulated peer.
    pub async fn acquire(setup: SimSetup) -> anyhow::Result<Self> {
        match std::env::var(HIL_ENV) {
            Ok(url) => {
                let endpoint: Endpoint = url.parse()?;
                Ok(Self {
                    serial: endpoint.is_serial().then(|| endpoint.clone()),
                    endpoint,
                    key: std::env::var(KEY_ENV).ok(),
                    sim: None,
                })
            }
            Err(_) => Self::simulated(setup).await,
        }
    }

    /// A simulated peer on a loopback port and a pseudo-terminal.
    pub async fn simulated(setup: SimSetup) -> anyhow::Result<Self> {
        let options = PeerOptions {
            axes: setup.axes,
            mechanics: MechanicsOptions {
                backlash: setup.backlash,
                ..MechanicsOptions::default()
            },
            key: setup.key.clone(),
            state_file: setup.state_file,
            time: setup.time,
            ..PeerOptions::default()
        };
        let peer = SimPeer::start(&options)?;
        let address = peer.listen_tcp("127.0.0.1:0".parse()?).await?;
        let pty = peer.open_pty()?;
        Ok(Self {
            endpoint: Endpoint::Tcp {
                host: address.ip().to_string(),
                port: address.port(),
            },
            serial: Some(Endpoint::Serial { path: pty }),
            key: setup.key,
            sim: Some(peer),
        })
    }

    /// Whether hidden truth is available; prints why a case is skipped when it is not.
    pub fn truth_available(&self, case: &str) -> bool {
        if self.sim.is_none() {
            eprintln!("skipped {case}: needs the simulator's hidden truth (true shaft positions)");
        }
        self.sim.is_some()
    }

    /// True shaft positions (simulator only).
    pub fn shafts(&self) -> Vec<i32> {
        self.sim
            .as_ref()
            .expect("checked with truth_available")
            .shaft_positions()
    }

    /// Connects with the target's key.
    pub async fn client(&self) -> anyhow::Result<Client> {
        self.client_with_key(self.key.as_deref()).await
    }

    /// Connects with a given key (or none).
    pub async fn client_with_key(&self, key: Option<&str>) -> anyhow::Result<Client> {
        Ok(Client::connect(self.endpoint.clone(), options(key)).await?)
    }

    /// Connects over the serial link (the simulator's pseudo-terminal).
    pub async fn serial_client(&self) -> anyhow::Result<Client> {
        let endpoint = self
            .serial
            .clone()
            .ok_or_else(|| anyhow::anyhow!("no serial link"))?;
        Ok(Client::connect(endpoint, options(None)).await?)
    }
}

fn options(key: Option<&str>) -> ClientOptions {
    ClientOptions {
        key: key.map(AccessKey::passphrase),
        ..ClientOptions::default()
    }
}

/// Sets backlash compensation on `axis`, keeping the rest of its configuration.
pub async fn configure_backlash(
    client: &Client,
    axis: u8,
    backlash: u16,
    mode: optalign_protocol::BacklashMode,
) -> anyhow::Result<AxisConfig> {
    let mut config = client.get_config(axis).await?;
    config.backlash = backlash;
    config.backlash_mode = mode;
    client
        .command_ok(Command::SetConfig { axis, config })
        .await?;
    Ok(config)
}
