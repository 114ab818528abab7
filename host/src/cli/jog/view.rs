//! What `optalign jog` shows: the axes with their positions and faults, the selected one and
//! the step, the newest frame's beams (centre, uncertainty, size, what to be wary of) and
//! what the last move did. Plain lines, drawn by the terminal side.

use crate::imaging::Beam;

/// One task axis as shown.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisLine {
    pub name: String,
    /// The controller's position counter, task steps.
    pub position: i32,
    pub moving: bool,
    pub faults: Vec<&'static str>,
}

/// Everything on the screen.
#[derive(Clone, Debug, Default)]
pub struct Screen {
    pub title: String,
    pub axes: Vec<AxisLine>,
    pub selected: usize,
    pub step: i32,
    /// Frame size, px, and its beams; `None` before the first frame.
    pub frame: Option<([u32; 2], Vec<Beam>)>,
    pub frames: u64,
    pub moves: u64,
    pub last: String,
}

/// The keys, in one line.
pub const HELP: &str = "keys: left/right or h/l move by the step, up/down or k/j step x10 or /10, 1-8 or Tab select, space stop, r refresh, q or Esc quit";

impl Screen {
    /// The screen as lines.
    pub fn lines(&self) -> Vec<String> {
        let mut lines = vec![self.title.clone(), HELP.to_owned(), String::new()];
        lines.push(format!(
            "     {:<15} {:>10}  state      (step {} steps)",
            "axis", "position", self.step
        ));
        for (i, axis) in self.axes.iter().enumerate() {
            let marker = if i == self.selected { '>' } else { ' ' };
            let state = if !axis.faults.is_empty() {
                axis.faults.join(", ")
            } else if axis.moving {
                "moving".to_owned()
            } else {
                "ok".to_owned()
            };
            lines.push(format!(
                "{marker} {}. {:<15} {:>10}  {state}",
                i + 1,
                axis.name,
                axis.position
            ));
        }
        lines.push(String::new());
        match &self.frame {
            None => lines.push("no frame yet".to_owned()),
            Some((size, beams)) => {
                lines.push(format!(
                    "frame {}: {} x {} px, {} beam(s)",
                    self.frames,
                    size[0],
                    size[1],
                    beams.len()
                ));
                if !beams.is_empty() {
                    lines.push(format!(
                        "  {:>2}  {:>18}  {:>7}  {:>8}  {:>7}  notes",
                        "#", "centre (x, y) px", "± px", "size px", "peak"
                    ));
                }
                for (i, beam) in beams.iter().enumerate() {
                    lines.push(format!(
                        "  {:>2}  {:>8.1},{:>8.1}  {:>7.3}  {:>8.1}  {:>7.1}  {}",
                        i + 1,
                        beam.centre[0],
                        beam.centre[1],
                        beam.uncertainty,
                        beam.size(),
                        beam.peak,
                        beam.notes()
                    ));
                }
            }
        }
        lines.push(String::new());
        lines.push(format!("moves: {}; last: {}", self.moves, self.last));
        lines
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_selected_axis_faults_and_moves_are_shown() {
        let screen = Screen {
            title: "jog".into(),
            axes: vec![
                AxisLine {
                    name: "x".into(),
                    position: 120,
                    moving: false,
                    faults: vec![],
                },
                AxisLine {
                    name: "y".into(),
                    position: -40,
                    moving: false,
                    faults: vec!["position-lost"],
                },
            ],
            selected: 1,
            step: 100,
            frame: Some(([480, 270], Vec::new())),
            frames: 3,
            moves: 2,
            last: "y -100: completed".into(),
        };
        let text = screen.lines().join("\n");
        assert!(
            text.contains("  1. x                      120  ok"),
            "{text}"
        );
        assert!(
            text.contains("> 2. y                      -40  position-lost"),
            "{text}"
        );
        assert!(text.contains("step 100"), "{text}");
        assert!(text.contains("frame 3: 480 x 270 px, 0 beam(s)"), "{text}");
        assert!(text.contains("moves: 2; last: y -100: completed"), "{text}");
    }
}
