//! `optalign provision`: Wi-Fi credentials and the access key, over the trusted serial link.

use anyhow::{Context, bail};
use clap::Args;
use optalign_protocol::Command;
use optalign_protocol::limits::{PASSPHRASE_LEN, SSID_LEN};

use crate::link::{AccessKey, Client, ClientOptions, Endpoint};

#[derive(Debug, Args)]
pub struct ProvisionArgs {
    /// The controller's USB serial port (e.g. /dev/ttyACM0).
    #[arg(long, value_name = "PATH")]
    serial: String,
    /// Wi-Fi network name.
    #[arg(long, requires = "psk")]
    ssid: Option<String>,
    /// Wi-Fi passphrase (WPA2); prefer OPTALIGN_WIFI_PSK.
    #[arg(
        long,
        env = "OPTALIGN_WIFI_PSK",
        hide_env_values = true,
        requires = "ssid"
    )]
    psk: Option<String>,
    /// Access key that network clients must prove; prefer OPTALIGN_KEY. A passphrase is
    /// stretched with Argon2id salted with the board's id and only the result is stored;
    /// `hex:` and 64 hex digits stores those 32 bytes as they are.
    #[arg(long, env = "OPTALIGN_KEY", hide_env_values = true)]
    key: Option<String>,
}

pub async fn run(args: ProvisionArgs) -> anyhow::Result<()> {
    if args.ssid.is_none() && args.key.is_none() {
        bail!("nothing to provision: give --ssid and --psk, and/or --key");
    }
    let key = args
        .key
        .as_deref()
        .map(str::parse::<AccessKey>)
        .transpose()
        .context("reading --key (or OPTALIGN_KEY)")?;
    let ssid = args
        .ssid
        .as_deref()
        .map(|s| bounded::<SSID_LEN>("--ssid", s))
        .transpose()?;
    let psk = args
        .psk
        .as_deref()
        .map(|s| bounded::<PASSPHRASE_LEN>("--psk", s))
        .transpose()?;
    if let Some(psk) = &psk
        && !(8..=63).contains(&psk.len())
    {
        bail!(
            "--psk must be 8 to 63 characters for WPA2, got {}",
            psk.len()
        );
    }
    let endpoint = Endpoint::Serial {
        path: args.serial.clone(),
    };
    let client = Client::connect(endpoint, ClientOptions::default())
        .await
        .with_context(|| format!("opening serial port {}", args.serial))?;
    if let (Some(ssid), Some(passphrase)) = (ssid, psk) {
        let name = ssid.to_string();
        client
            .command_ok(Command::ProvisionWifi { ssid, passphrase })
            .await?;
        crate::say!("Wi-Fi credentials stored for network {name:?}");
    }
    if let Some(key) = key {
        if let AccessKey::Passphrase(passphrase) = &key
            && passphrase.chars().count() < 12
        {
            eprintln!(
                "warning: a key shorter than 12 characters is easy to guess offline from one recorded handshake, even stretched"
            );
        }
        let board_id = client.identity().board_id;
        let derived = tokio::task::spawn_blocking(move || key.for_board(board_id)).await?;
        client.command_ok(Command::SetKey { key: derived }).await?;
        crate::say!("access key stored; network clients must now present it (OPTALIGN_KEY)");
    }
    Ok(())
}

fn bounded<const N: usize>(flag: &str, value: &str) -> anyhow::Result<heapless::String<N>> {
    heapless::String::try_from(value)
        .map_err(|_| anyhow::anyhow!("{flag} is longer than {N} bytes"))
}
