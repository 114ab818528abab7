//! `optalign jog` driven through a pseudo-terminal against the rehearsal peer (its own
//! process, as on a bench): keystrokes select axes, scale the step and move, the true
//! shafts (the peer's mounts file) moved by exactly what was typed, and quitting in the
//! middle of a long move stops it rather than leaving it running.

use std::io::{Read, Write};
use std::os::fd::{FromRawFd, OwnedFd};
use std::path::Path;
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use optalign_firmware::sim::MountModel;

use super::rehearsal::{KEY, optalign, rehearsal_bench_at};

/// The true mirror positions in the peer's mounts file.
fn shafts(state: &Path) -> Vec<i32> {
    let mut path = state.as_os_str().to_owned();
    path.push(".mounts.json");
    match std::fs::read(&path) {
        Ok(bytes) => serde_json::from_slice::<Vec<MountModel>>(&bytes)
            .unwrap()
            .iter()
            .map(MountModel::mirror_position)
            .collect(),
        // Nothing moved yet: a fresh bench is at zero.
        Err(_) => vec![0; 4],
    }
}

/// `optalign jog` on a pseudo-terminal: what it drew so far, and the terminal to type on.
struct Jog {
    child: tokio::process::Child,
    keyboard: std::fs::File,
    screen: Arc<Mutex<String>>,
}

impl Jog {
    fn start(dir: &Path, rig: &Path, args: &[&str]) -> Self {
        let (mut master, mut slave) = (0, 0);
        // SAFETY: openpty writes two descriptors it opened into the given integers.
        let opened = unsafe {
            libc::openpty(
                &mut master,
                &mut slave,
                std::ptr::null_mut(),
                std::ptr::null(),
                std::ptr::null(),
            )
        };
        assert_eq!(opened, 0, "openpty failed");
        // SAFETY: both descriptors were just opened by openpty and are owned here alone.
        let (master, slave) =
            unsafe { (OwnedFd::from_raw_fd(master), OwnedFd::from_raw_fd(slave)) };
        let stdio = || Stdio::from(slave.try_clone().unwrap());
        let child = tokio::process::Command::new(crate::BIN)
            .args(["jog", "--rig"])
            .arg(rig)
            .args(args)
            .current_dir(dir)
            .env("OPTALIGN_KEY", KEY)
            .env("RUST_LOG", "error")
            .stdin(stdio())
            .stdout(stdio())
            .stderr(stdio())
            .kill_on_drop(true)
            .spawn()
            .unwrap();
        drop(slave);
        let keyboard = std::fs::File::from(master.try_clone().unwrap());
        let screen = Arc::new(Mutex::new(String::new()));
        let drawn = screen.clone();
        std::thread::spawn(move || {
            let mut display = std::fs::File::from(master);
            let mut buffer = [0u8; 4096];
            // Ends when the child has gone and the terminal hangs up.
            while let Ok(count @ 1..) = display.read(&mut buffer) {
                drawn
                    .lock()
                    .unwrap()
                    .push_str(&String::from_utf8_lossy(&buffer[..count]));
            }
        });
        Self {
            child,
            keyboard,
            screen,
        }
    }

    /// Waits until the screen shows `text`.
    async fn shows(&self, text: &str) {
        let deadline = Instant::now() + Duration::from_secs(30);
        while !self.screen.lock().unwrap().contains(text) {
            assert!(
                Instant::now() < deadline,
                "the screen never showed {text:?}:\n{}",
                self.screen.lock().unwrap()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    fn type_keys(&mut self, keys: &str) {
        self.keyboard.write_all(keys.as_bytes()).unwrap();
        self.keyboard.flush().unwrap();
    }

    /// Waits for the program to end; returns its exit status and how long that took.
    async fn ended(&mut self) -> (std::process::ExitStatus, Duration) {
        let started = Instant::now();
        let status = tokio::time::timeout(Duration::from_secs(30), self.child.wait())
            .await
            .expect("jog ends")
            .unwrap();
        (status, started.elapsed())
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn keystrokes_move_the_selected_axis_by_exactly_the_chosen_steps() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.flash");
    let bench = rehearsal_bench_at(dir.path(), 3, "0", &["--state", state.to_str().unwrap()]).await;
    let start = shafts(&state);
    let mut jog = Jog::start(
        dir.path(),
        &bench.rig,
        &["--step", "100", "--refresh-s", "0.2"],
    );
    jog.shows("moves: 0").await;
    jog.shows("beam(s)").await;
    jog.type_keys("l");
    jog.shows("moves: 1").await;
    // Axis 2, two steps back (arrow keys as the terminal sends them).
    jog.type_keys("2\x1b[D");
    jog.shows("moves: 2").await;
    jog.type_keys("h");
    jog.shows("moves: 3").await;
    // Step x10, axis 1 again, one step on.
    jog.type_keys("k1\x1b[C");
    jog.shows("moves: 4").await;
    jog.shows("mirror_1_axis_1 +1000: completed").await;
    jog.type_keys("q");
    let (status, _) = jog.ended().await;
    assert!(status.success(), "{}", jog.screen.lock().unwrap());
    let end = shafts(&state);
    assert_eq!(end[0] - start[0], 100 + 1000, "{start:?} -> {end:?}");
    assert_eq!(end[1] - start[1], -200, "{start:?} -> {end:?}");
    assert_eq!(&end[2..], &start[2..]);
    assert!(
        jog.screen
            .lock()
            .unwrap()
            .contains("every controller told to stop")
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn quitting_in_the_middle_of_a_long_move_stops_it() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.flash");
    // Real time: 20,000 steps take about 25 s.
    let bench = rehearsal_bench_at(dir.path(), 3, "1", &["--state", state.to_str().unwrap()]).await;
    let start = shafts(&state);
    let mut jog = Jog::start(dir.path(), &bench.rig, &["--step", "20000"]);
    jog.shows("moves: 0").await;
    jog.type_keys("l");
    jog.shows("mirror_1_axis_1 +20000: moving").await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    jog.type_keys("q");
    let (status, took) = jog.ended().await;
    assert!(status.success(), "{}", jog.screen.lock().unwrap());
    assert!(took < Duration::from_secs(10), "quitting took {took:?}");
    // Nothing is left moving, and the shaft stopped short of the target.
    let url = std::fs::read_to_string(&bench.rig)
        .unwrap()
        .lines()
        .find_map(|l| {
            l.strip_prefix("url = \"")
                .map(|u| u.trim_end_matches('"').to_owned())
        })
        .unwrap();
    let (output, printed) = optalign(dir.path(), &["status", "--controller", &url, "--json"]).await;
    assert!(output.status.success(), "{printed}");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let axes = report["axes"].as_array().unwrap();
    assert!(axes.iter().all(|a| a["moving"] == false), "{printed}");
    let moved = shafts(&state)[0] - start[0];
    assert!((1..20_000).contains(&moved), "moved {moved}");
}
