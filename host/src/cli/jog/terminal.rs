//! The terminal while jogging: raw mode (keys arrive as pressed, Ctrl-C as a key) on the
//! alternate screen, redrawn whole; left as it was found when the session ends, on every
//! path (dropping the guard leaves too).

use std::io::Write;

use crossterm::cursor::{Hide, MoveTo, Show};
use crossterm::terminal::{
    Clear, ClearType, EnterAlternateScreen, LeaveAlternateScreen, disable_raw_mode, enable_raw_mode,
};
use crossterm::{execute, queue};

/// The terminal in jogging mode.
pub struct Terminal {
    active: bool,
}

impl Terminal {
    /// Raw mode on the alternate screen; an error when standard input is not a terminal.
    pub fn enter() -> anyhow::Result<Self> {
        anyhow::ensure!(
            std::io::IsTerminal::is_terminal(&std::io::stdin()),
            "optalign jog reads keys from a terminal; standard input is not one"
        );
        enable_raw_mode()?;
        let terminal = Self { active: true };
        execute!(std::io::stdout(), EnterAlternateScreen, Hide)?;
        Ok(terminal)
    }

    /// Draws `lines` from the top left, clearing what was there.
    pub fn draw(&mut self, lines: &[String]) -> anyhow::Result<()> {
        let mut out = std::io::stdout().lock();
        queue!(out, MoveTo(0, 0), Clear(ClearType::All))?;
        for line in lines {
            // Raw mode: a line feed alone does not return the carriage.
            write!(out, "{}\r\n", crate::console::escape_controls(line))?;
        }
        out.flush()?;
        Ok(())
    }

    /// Back to the screen and mode it was in.
    pub fn leave(&mut self) {
        if self.active {
            self.active = false;
            let _ = execute!(std::io::stdout(), Show, LeaveAlternateScreen);
            let _ = disable_raw_mode();
        }
    }
}

impl Drop for Terminal {
    fn drop(&mut self) {
        self.leave();
    }
}
