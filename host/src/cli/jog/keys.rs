//! What a key does in `optalign jog`.

use crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};

/// The largest jog step, steps.
pub const MAX_STEP: i32 = 100_000;

/// What the operator asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Intent {
    /// Move the selected axis one step this way (+1 or -1).
    Move(i32),
    /// Select task axis `n` (0-based).
    Select(usize),
    /// Select the next (+1) or previous (-1) axis.
    Cycle(i32),
    /// Multiply (+1) or divide (-1) the step by ten.
    Scale(i32),
    /// Decelerate whatever moves.
    Stop,
    /// Take a frame now.
    Refresh,
    /// Stop and leave.
    Quit,
}

/// The intent of a key press (releases and unknown keys mean nothing).
pub fn intent(key: &KeyEvent) -> Option<Intent> {
    if key.kind == KeyEventKind::Release {
        return None;
    }
    if key.modifiers.contains(KeyModifiers::CONTROL) {
        return matches!(key.code, KeyCode::Char('c' | 'd')).then_some(Intent::Quit);
    }
    Some(match key.code {
        KeyCode::Right | KeyCode::Char('l' | '+' | '=') => Intent::Move(1),
        KeyCode::Left | KeyCode::Char('h' | '-') => Intent::Move(-1),
        KeyCode::Up | KeyCode::Char('k') => Intent::Scale(1),
        KeyCode::Down | KeyCode::Char('j') => Intent::Scale(-1),
        KeyCode::Tab => Intent::Cycle(1),
        KeyCode::BackTab => Intent::Cycle(-1),
        KeyCode::Char(digit @ '1'..='8') => Intent::Select(digit as usize - '1' as usize),
        KeyCode::Char(' ' | 's') => Intent::Stop,
        KeyCode::Char('r') => Intent::Refresh,
        KeyCode::Char('q') | KeyCode::Esc => Intent::Quit,
        _ => return None,
    })
}

/// The step after scaling `step` by ten `times` (+1 or -1), within 1..=[`MAX_STEP`].
pub fn scaled(step: i32, times: i32) -> i32 {
    let step = if times > 0 {
        step.saturating_mul(10)
    } else {
        step / 10
    };
    step.clamp(1, MAX_STEP)
}

/// The axis after moving the selection by `by` among `count` axes (wrapping).
pub fn cycled(selected: usize, by: i32, count: usize) -> usize {
    let count = count.max(1) as i64;
    (selected as i64 + i64::from(by)).rem_euclid(count) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(code: KeyCode) -> KeyEvent {
        KeyEvent::new(code, KeyModifiers::NONE)
    }

    #[test]
    fn keys_move_select_scale_stop_and_quit() {
        assert_eq!(intent(&key(KeyCode::Right)), Some(Intent::Move(1)));
        assert_eq!(intent(&key(KeyCode::Char('h'))), Some(Intent::Move(-1)));
        assert_eq!(intent(&key(KeyCode::Char('3'))), Some(Intent::Select(2)));
        assert_eq!(intent(&key(KeyCode::Char('9'))), None);
        assert_eq!(intent(&key(KeyCode::Up)), Some(Intent::Scale(1)));
        assert_eq!(intent(&key(KeyCode::Char(' '))), Some(Intent::Stop));
        assert_eq!(intent(&key(KeyCode::Esc)), Some(Intent::Quit));
        let ctrl_c = KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL);
        assert_eq!(intent(&ctrl_c), Some(Intent::Quit));
        let ctrl_l = KeyEvent::new(KeyCode::Char('l'), KeyModifiers::CONTROL);
        assert_eq!(intent(&ctrl_l), None, "a control key is not its letter");
    }

    #[test]
    fn steps_scale_by_ten_within_bounds_and_selection_wraps() {
        assert_eq!(scaled(10, 1), 100);
        assert_eq!(scaled(10, -1), 1);
        assert_eq!(scaled(1, -1), 1);
        assert_eq!(scaled(MAX_STEP, 1), MAX_STEP);
        assert_eq!(cycled(3, 1, 4), 0);
        assert_eq!(cycled(0, -1, 4), 3);
    }
}
