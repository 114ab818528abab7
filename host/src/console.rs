//! What the command prints on the terminal: lines on stdout that end quietly when the
//! reader goes away (`optalign status | head -1`), outside text with its control
//! characters escaped, and colours only where a person is looking at a terminal.

use std::borrow::Cow;
use std::fmt;
use std::io::{IsTerminal, Write};

/// Prints one line on stdout, like `println!`, but a closed stdout (a pipe whose reader
/// has gone) is not an error: the output ends quietly and the command carries on.
#[macro_export]
macro_rules! say {
    () => {
        $crate::console::write_line(format_args!(""))
    };
    ($($arg:tt)*) => {
        $crate::console::write_line(format_args!($($arg)*))
    };
}

/// Writes `line` and a newline to stdout; see [`say!`].
pub fn write_line(line: fmt::Arguments<'_>) {
    let mut out = std::io::stdout().lock();
    if let Err(error) = writeln!(out, "{line}").and_then(|()| out.flush())
        && error.kind() != std::io::ErrorKind::BrokenPipe
    {
        tracing::warn!("cannot write to standard output: {error}");
    }
}

/// `text` with every control character but the newline written as an escape (`\u{1b}`
/// for ESC), so that text from outside (a controller's reason, a server's error body, a
/// file's contents quoted in an error) cannot move the cursor, recolour or retitle the
/// terminal.
pub fn escape_controls(text: &str) -> Cow<'_, str> {
    if !text.chars().any(is_escaped) {
        return Cow::Borrowed(text);
    }
    let mut escaped = String::with_capacity(text.len() + 16);
    for c in text.chars() {
        if is_escaped(c) {
            escaped.extend(c.escape_default());
        } else {
            escaped.push(c);
        }
    }
    Cow::Owned(escaped)
}

fn is_escaped(c: char) -> bool {
    c.is_control() && c != '\n'
}

/// Whether to colour what goes to stderr: only on a terminal, and never with `NO_COLOR`
/// set to anything but the empty string (<https://no-color.org>).
pub fn colours_on_stderr() -> bool {
    let no_colour = std::env::var_os("NO_COLOR").is_some_and(|value| !value.is_empty());
    !no_colour && std::io::stderr().is_terminal()
}

/// Joins an error and its causes into one line, skipping causes already quoted, with
/// control characters from outside text escaped.
pub fn one_line(error: &anyhow::Error) -> String {
    let mut line = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !line.contains(&cause) {
            line.push_str(": ");
            line.push_str(&cause);
        }
    }
    escape_controls(&line).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_characters_are_escaped_and_plain_text_kept() {
        assert!(matches!(escape_controls("plain text"), Cow::Borrowed(_)));
        assert_eq!(
            escape_controls("bad \u{1b}[31mred\u{7}\r\ttab\nline"),
            "bad \\u{1b}[31mred\\u{7}\\r\\ttab\nline"
        );
        assert_eq!(escape_controls("µm ± 3"), "µm ± 3");
        assert_eq!(escape_controls("\u{9b}31m"), "\\u{9b}31m");
    }
}
