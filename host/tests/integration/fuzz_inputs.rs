//! Fuzzing the host's text inputs from a seed corpus (`fuzz/corpus/<target>/`, valid
//! inputs): rig files, scenario files, the VLM's replies and the operator's typed actions,
//! for every task. Each case takes a seed and damages it one to eight times (bits flipped,
//! bytes set, tokens a parser cares about inserted, ranges deleted, repeated or cut off,
//! pieces of another seed spliced in) with proptest on the stable toolchain.
//!
//! Every seed must parse (the corpus is valid); every damaged input must give a value that
//! keeps the parser's promises or an error that says something, never a panic.
//! `OPTALIGN_FUZZ_CASES=N` runs N cases per target (500 by default).

use std::cell::Cell;
use std::path::{Path, PathBuf};

use optalign::lab::RigFile;
use optalign::policy::manual::parse_line;
use optalign::policy::vlm::schema::parse_reply;
use optalign::scenario::ScenarioFile;
use optalign::task::relay::RelayAction;
use optalign::task::{Action, TaskKind};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};

fn cases() -> u32 {
    match std::env::var("OPTALIGN_FUZZ_CASES") {
        Ok(text) => text
            .parse()
            .unwrap_or_else(|_| panic!("OPTALIGN_FUZZ_CASES must be a whole number, got {text:?}")),
        Err(_) => 500,
    }
}

fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/corpus")
        .join(target)
}

/// The seeds of `target`, by file name.
fn corpus(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = corpus_dir(target);
    let mut seeds: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("no corpus at {}: {e}", dir.display()))
        .map(|entry| {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&path).unwrap())
        })
        .collect();
    seeds.sort();
    assert!(!seeds.is_empty(), "{} holds no seed", dir.display());
    seeds
}

/// Pieces of text the parsers give meaning to, and values at the edges of their types.
const TOKENS: &[&str] = &[
    "\"",
    "'",
    "{",
    "}",
    "[",
    "]",
    "[[",
    "]]",
    ",",
    ":",
    "=",
    ".",
    "\n",
    "#",
    "\\",
    "\\u0000",
    "-",
    "0",
    "-1",
    "2147483647",
    "2147483648",
    "-2147483649",
    "18446744073709551616",
    "1e400",
    "-0.0",
    "nan",
    "inf",
    "-inf",
    "true",
    "null",
    "\"\"",
    "[]",
    "{}",
    "\"x\"",
    "é",
    "\u{0}",
    "done",
    "tilt",
    "measure",
    "M4",
    "M5",
    "C8",
    "C9",
    "task = \"relay\"",
    "[camera]",
    "[[controller]]",
    "controller = ",
    "axis = 255",
    "tcp://",
    "serial://",
];

/// One change to an input; positions and lengths are taken modulo the input's length.
#[derive(Clone, Debug)]
enum Mutation {
    FlipBit {
        at: usize,
        bit: u8,
    },
    SetByte {
        at: usize,
        byte: u8,
    },
    Insert {
        at: usize,
        token: usize,
    },
    Delete {
        at: usize,
        len: usize,
    },
    Repeat {
        at: usize,
        len: usize,
        times: usize,
    },
    Truncate {
        at: usize,
    },
    Splice {
        at: usize,
        seed: usize,
        from: usize,
        len: usize,
    },
    Nest {
        at: usize,
        depth: usize,
    },
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let at = any::<usize>();
    prop_oneof![
        3 => (at, 0u8..8).prop_map(|(at, bit)| Mutation::FlipBit { at, bit }),
        2 => (at, any::<u8>()).prop_map(|(at, byte)| Mutation::SetByte { at, byte }),
        4 => (at, 0..TOKENS.len()).prop_map(|(at, token)| Mutation::Insert { at, token }),
        2 => (at, 1usize..40).prop_map(|(at, len)| Mutation::Delete { at, len }),
        1 => (at, 1usize..40, 2usize..50)
            .prop_map(|(at, len, times)| Mutation::Repeat { at, len, times }),
        1 => at.prop_map(|at| Mutation::Truncate { at }),
        2 => (at, any::<usize>(), any::<usize>(), 1usize..200)
            .prop_map(|(at, seed, from, len)| Mutation::Splice { at, seed, from, len }),
        1 => (at, 1usize..300).prop_map(|(at, depth)| Mutation::Nest { at, depth }),
    ]
}

fn apply(input: &mut Vec<u8>, change: &Mutation, seeds: &[(String, Vec<u8>)]) {
    let place = |at: usize, len: usize| if len == 0 { 0 } else { at % (len + 1) };
    match *change {
        Mutation::FlipBit { at, bit } if !input.is_empty() => {
            let at = at % input.len();
            input[at] ^= 1 << bit;
        }
        Mutation::SetByte { at, byte } if !input.is_empty() => {
            let at = at % input.len();
            input[at] = byte;
        }
        Mutation::FlipBit { .. } | Mutation::SetByte { .. } => {}
        Mutation::Insert { at, token } => {
            let at = place(at, input.len());
            input.splice(at..at, TOKENS[token].bytes());
        }
        Mutation::Delete { at, len } => {
            let at = place(at, input.len());
            let end = (at + len).min(input.len());
            input.drain(at..end);
        }
        Mutation::Repeat { at, len, times } => {
            let at = place(at, input.len());
            let end = (at + len).min(input.len());
            let piece = input[at..end].repeat(times);
            input.splice(end..end, piece);
        }
        Mutation::Truncate { at } => input.truncate(place(at, input.len())),
        Mutation::Splice {
            at,
            seed,
            from,
            len,
        } => {
            let other = &seeds[seed % seeds.len()].1;
            let from = place(from, other.len());
            let end = (from + len).min(other.len());
            let at = place(at, input.len());
            input.splice(at..at, other[from..end].iter().copied());
        }
        Mutation::Nest { at, depth } => {
            let at = place(at, input.len());
            let opening = if depth % 2 == 0 { "[" } else { "{\"a\":" };
            input.splice(at..at, opening.repeat(depth).bytes());
        }
    }
}

/// Runs `check` on every seed of `target` (it must accept them) and then on `cases()`
/// damaged seeds (it must not panic; what it promises is up to it).
fn fuzz(target: &str, check: impl Fn(&str) -> Result<(), String>) {
    let seeds = corpus(target);
    for (name, seed) in &seeds {
        let text = String::from_utf8_lossy(seed);
        if let Err(error) = check(&text) {
            panic!("{target}: the seed {name} is refused: {error}");
        }
    }
    let mut runner = TestRunner::new(Config {
        cases: cases(),
        failure_persistence: None,
        ..Config::default()
    });
    let strategy = (0..seeds.len(), prop::collection::vec(mutation(), 1..=8));
    let (accepted, refused) = (Cell::new(0u64), Cell::new(0u64));
    let result = runner.run(&strategy, |(seed, changes)| {
        let mut input = seeds[seed].1.clone();
        for change in &changes {
            apply(&mut input, change, &seeds);
        }
        let text = String::from_utf8_lossy(&input);
        match check(&text) {
            Ok(()) => {
                accepted.set(accepted.get() + 1);
                Ok(())
            }
            Err(error) if !error.trim().is_empty() => {
                refused.set(refused.get() + 1);
                Ok(())
            }
            Err(_) => Err(TestCaseError::fail(format!("an empty error for {text:?}"))),
        }
    });
    if let Err(failure) = result {
        panic!("{target}: {failure}");
    }
    let (accepted, refused) = (accepted.get(), refused.get());
    println!("{target}: {accepted} damaged inputs accepted, {refused} refused");
    // Both paths are reached: damage the parser lets through (so its promises are
    // checked) and damage it refuses.
    assert!(
        accepted > 0 && refused > 0,
        "{target}: {accepted} accepted, {refused} refused"
    );
}

/// A promise a parsed value must keep; a broken one fails the campaign at once (proptest
/// reports the panic with the input that caused it).
fn promise(holds: bool, what: impl FnOnce() -> String) -> Result<(), String> {
    if holds {
        Ok(())
    } else {
        panic!("a broken promise: {}", what())
    }
}

#[test]
fn rig_files() {
    fuzz("rig", |text| {
        let rig = RigFile::parse(text, Path::new("/nonexistent")).map_err(|e| format!("{e:#}"))?;
        // What the rig promises once parsed: every task axis routes to a controller it
        // names.
        let routes = rig.routes();
        promise(
            routes.iter().all(|r| r.controller < rig.controllers.len()),
            || format!("a route to a missing controller in {text:?}"),
        )
    });
}

#[test]
fn scenario_files() {
    fuzz("scenario", |text| {
        let scenario = ScenarioFile::parse(text).map_err(|e| format!("{e:#}"))?;
        // A scenario that parsed is valid and survives writing out and reading back.
        let written = toml::to_string(&scenario).expect("a parsed scenario writes out");
        let again = ScenarioFile::parse(&written).map_err(|e| format!("{e:#}"));
        promise(again.as_ref() == Ok(&scenario), || {
            format!("{text:?} came back as {again:?}")
        })
    });
}

fn kind_holds(task: TaskKind, action: &Action) -> Result<(), String> {
    promise(action.task() == task, || {
        format!("{action:?} for a {task:?} task")
    })?;
    if let Action::Relay(RelayAction::Tilt { mirror, .. }) = action {
        promise(*mirror < 4, || format!("mirror {mirror} in {action:?}"))?;
    }
    Ok(())
}

fn vlm_replies(target: &str, task: TaskKind) {
    fuzz(target, |text| {
        let parsed = parse_reply(task, text)?;
        kind_holds(task, &parsed.action)?;
        promise(parsed.claims.is_object(), || {
            format!("claims {:?}", parsed.claims)
        })
    });
}

#[test]
fn vlm_replies_michelson() {
    vlm_replies("vlm_michelson", TaskKind::Michelson);
}

#[test]
fn vlm_replies_cavity() {
    vlm_replies("vlm_cavity", TaskKind::Cavity);
}

#[test]
fn vlm_replies_relay() {
    vlm_replies("vlm_relay", TaskKind::Relay);
}

fn typed_actions(target: &str, task: TaskKind) {
    fuzz(target, |text| {
        // The prompt hands the parser one line at a time.
        let line = text.lines().next().unwrap_or("");
        let action = parse_line(task, line)?;
        kind_holds(task, &action)
    });
}

#[test]
fn typed_actions_michelson() {
    typed_actions("manual_michelson", TaskKind::Michelson);
}

#[test]
fn typed_actions_cavity() {
    typed_actions("manual_cavity", TaskKind::Cavity);
}

#[test]
fn typed_actions_relay() {
    typed_actions("manual_relay", TaskKind::Relay);
}
