//! `optalign jog`: drive a bench by hand while looking. Keys move the selected axis by a
//! chosen relative step (in the controllers' recovery mode, so a lost axis can be brought
//! back into view too), the newest frame's beams are read out and refreshed, positions and
//! faults shown, and `--monitor` serves the live frame to the monitor page. It never leaves
//! a move running: every controller is told to stop when it quits, on an error, on Ctrl-C,
//! on SIGTERM or SIGHUP, and when the monitor's stop button is pressed.

mod keys;
mod terminal;
mod view;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use clap::Args;
use crossterm::event::{Event, EventStream};
use futures::StreamExt;
use optalign_protocol::{AxisValue, Command};
use tokio::signal::unix::{SignalKind, signal};

use self::keys::{Intent, cycled, intent, scaled};
use self::terminal::Terminal;
use self::view::{AxisLine, Screen};
use super::monitor::MonitorArgs;
use crate::imaging::{Beam, Picture, find_beams};
use crate::lab::rigfile::task_axis_names;
use crate::lab::{LabRig, RigFile};
use crate::monitor::{Hub, RunMonitor};
use crate::rig::{Rig, fault_names};

#[derive(Debug, Args)]
pub struct JogArgs {
    /// The bench's rig file.
    #[arg(long, value_name = "FILE")]
    rig: PathBuf,
    /// The step a key moves the selected axis by at first, steps (1 to 100,000).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(i32).range(1..=i64::from(keys::MAX_STEP)))]
    step: i32,
    /// A new frame at least this often while idle, s (0.05 to 60).
    #[arg(long, default_value_t = 0.5)]
    refresh_s: f64,
    #[command(flatten)]
    monitor: MonitorArgs,
}

pub async fn run(args: JogArgs) -> anyhow::Result<()> {
    crate::bounds::number_in("--refresh-s", args.refresh_s, 0.05, 60.0, "s")
        .map_err(anyhow::Error::msg)?;
    let file = RigFile::load(&args.rig)?;
    let title = format!("optalign jog: {} on {}", file.task, args.rig.display());
    let mut bench = LabRig::connect_unscored(file).await?;
    let monitor = args.monitor.run_monitor(&title, false);
    let server = match &monitor {
        Some(monitor) => {
            monitor.begin(&bench.task().to_string(), "jog", 0, 0, None);
            args.monitor.serve(&Hub::single(monitor.clone())).await?
        }
        None => None,
    };
    let mut jog = Jog {
        screen: Screen {
            title,
            step: args.step,
            ..Screen::default()
        },
        refresh: Duration::from_secs_f64(args.refresh_s),
        monitor,
        shown: None,
    };
    let result = match Terminal::enter() {
        Ok(mut terminal) => {
            let result = jog.drive(&mut bench, &mut terminal).await;
            terminal.leave();
            result
        }
        Err(error) => Err(error),
    };
    // Whatever ended the session, nothing is left moving.
    let stopped = bench.stop_all().await;
    if let Some(server) = server {
        server.close().await;
    }
    crate::say!(
        "jog: {} move(s); every controller told to stop",
        jog.screen.moves
    );
    result.and(stopped)
}

struct Jog {
    screen: Screen,
    refresh: Duration,
    monitor: Option<RunMonitor>,
    /// The beams last sent to the monitor.
    shown: Option<Vec<Beam>>,
}

impl Jog {
    async fn drive(&mut self, bench: &mut LabRig, terminal: &mut Terminal) -> anyhow::Result<()> {
        let mut keys = EventStream::new();
        let mut interrupt = signal(SignalKind::interrupt())?;
        let mut terminate = signal(SignalKind::terminate())?;
        let mut hangup = signal(SignalKind::hangup())?;
        let names = task_axis_names(bench.task());
        self.observe(bench, None).await?;
        loop {
            terminal.draw(&self.screen.lines())?;
            let stop_pressed = async {
                match &self.monitor {
                    Some(monitor) => monitor.stopped().await,
                    None => std::future::pending().await,
                }
            };
            let wanted = tokio::select! {
                event = keys.next() => match event {
                    Some(Ok(Event::Key(key))) => intent(&key),
                    Some(Ok(_)) => continue,
                    Some(Err(error)) => return Err(error.into()),
                    None => Some(Intent::Quit),
                },
                () = tokio::time::sleep(self.refresh) => Some(Intent::Refresh),
                _ = interrupt.recv() => Some(Intent::Quit),
                _ = terminate.recv() => Some(Intent::Quit),
                _ = hangup.recv() => Some(Intent::Quit),
                _ = stop_pressed => Some(Intent::Quit),
            };
            let Some(wanted) = wanted else { continue };
            match wanted {
                Intent::Quit => return Ok(()),
                Intent::Select(axis) if axis < names.len() => self.screen.selected = axis,
                Intent::Select(_) => {}
                Intent::Cycle(by) => {
                    self.screen.selected = cycled(self.screen.selected, by, names.len())
                }
                Intent::Scale(times) => self.screen.step = scaled(self.screen.step, times),
                Intent::Stop => bench.stop_all().await?,
                Intent::Refresh => self.observe(bench, None).await?,
                Intent::Move(sign) => {
                    let axis = self.screen.selected;
                    let delta = sign * self.screen.step;
                    let action = format!("{} {delta:+}", names[axis]);
                    self.screen.last = format!("{action}: moving");
                    terminal.draw(&self.screen.lines())?;
                    let (outcome, quit) = self
                        .move_watching(bench, axis, delta, &mut keys, &mut interrupt)
                        .await?;
                    self.screen.moves += 1;
                    self.screen.last = format!("{action}: {outcome}");
                    self.observe(bench, Some(action)).await?;
                    if quit {
                        return Ok(());
                    }
                }
            }
        }
    }

    /// Moves task axis `axis` by `delta` while still reading keys: stop, quit and Ctrl-C
    /// stop it at once. Returns how it ended, and whether to quit.
    async fn move_watching(
        &mut self,
        bench: &LabRig,
        axis: usize,
        delta: i32,
        keys: &mut EventStream,
        interrupt: &mut tokio::signal::unix::Signal,
    ) -> anyhow::Result<(String, bool)> {
        let (client, controller_axis) = bench.controller_axis(axis);
        let deltas = [AxisValue {
            axis: controller_axis,
            steps: bench.sign(axis) * delta,
        }];
        let motion = client.recovery_move_by(&deltas);
        tokio::pin!(motion);
        let mut quit = false;
        loop {
            let stop = tokio::select! {
                report = &mut motion => {
                    let outcome = match report {
                        Ok(report) => format!("{:?}", report.outcome).to_lowercase(),
                        Err(error) => format!("refused: {}", crate::console::one_line(&error.into())),
                    };
                    return Ok((outcome, quit));
                }
                event = keys.next() => match event {
                    Some(Ok(Event::Key(key))) => match intent(&key) {
                        Some(Intent::Quit) => { quit = true; true }
                        Some(Intent::Stop) => true,
                        _ => false,
                    },
                    Some(Ok(_)) => false,
                    Some(Err(_)) | None => { quit = true; true }
                },
                _ = interrupt.recv() => { quit = true; true }
            };
            if stop {
                client.command_ok(Command::Stop).await?;
            }
        }
    }

    /// Reads the axes and takes a frame; shows both, and sends the frame to the monitor
    /// after a move (`action`), or when its beams changed.
    async fn observe(&mut self, bench: &mut LabRig, action: Option<String>) -> anyhow::Result<()> {
        let names = task_axis_names(bench.task());
        let states = bench.axis_states().await?;
        self.screen.axes = names
            .into_iter()
            .zip(states)
            .enumerate()
            .map(|(axis, (name, state))| AxisLine {
                name,
                position: bench.sign(axis) * state.position,
                moving: state.moving,
                faults: fault_names(state.faults),
            })
            .collect();
        let frame = bench.capture().await?;
        let beams = find_beams(&Picture::new(&frame));
        self.screen.frames += 1;
        self.screen.frame = Some(([frame.width(), frame.height()], beams.clone()));
        if let Some(monitor) = &self.monitor {
            let changed = self.shown.as_ref().is_none_or(|shown| moved(shown, &beams));
            if action.is_some() || changed {
                monitor.set_controllers(bench.controllers().await?);
                let feedback = self.screen.last.clone();
                monitor.live(Arc::new(frame), action, feedback);
                self.shown = Some(beams);
            }
        }
        Ok(())
    }
}

/// Whether the beams differ from those shown: another count, or a centre moved by more
/// than half a pixel.
fn moved(shown: &[Beam], now: &[Beam]) -> bool {
    shown.len() != now.len()
        || shown
            .iter()
            .zip(now)
            .any(|(a, b)| (a.centre[0] - b.centre[0]).hypot(a.centre[1] - b.centre[1]) > 0.5)
}
