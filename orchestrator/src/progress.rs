//! Progress of long batch work on stderr: done/total, rate and ETA. On a terminal one line
//! is redrawn in place; otherwise (CI logs, files) a line is printed every few seconds, so
//! logs show progress without thousands of lines.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// A progress line for `total` units of work.
pub struct Progress {
    label: String,
    total: u64,
    done: u64,
    start: Instant,
    last_draw: Option<Instant>,
    terminal: bool,
}

impl Progress {
    /// Starts counting; `done` units were finished before (a resumed run).
    pub fn new(label: &str, total: u64, done: u64) -> Self {
        Progress { label: label.to_owned(), total, done, start: Instant::now(), last_draw: None, terminal: std::io::stderr().is_terminal() }
    }

    /// Records `n` more finished units and redraws when due.
    pub fn advance(&mut self, n: u64) {
        self.done += n;
        let every = if self.terminal { Duration::from_millis(100) } else { Duration::from_secs(5) };
        if self.last_draw.is_none_or(|last| last.elapsed() >= every) || self.done == self.total {
            self.draw();
        }
    }

    /// Prints `message` on a line of its own (a scene that failed, say) without breaking the
    /// progress line: on a terminal the line is cleared first and redrawn after.
    pub fn note(&mut self, message: &str) {
        let mut err = std::io::stderr().lock();
        let _ = if self.terminal { writeln!(err, "\r\x1b[K{message}") } else { writeln!(err, "{message}") };
        drop(err);
        if self.terminal && self.last_draw.is_some() {
            self.draw();
        }
    }

    fn draw(&mut self) {
        self.last_draw = Some(Instant::now());
        let line = self.line(self.start.elapsed());
        let mut err = std::io::stderr().lock();
        // Progress is best effort: a closed stderr must not fail the work.
        let _ = if self.terminal { write!(err, "\r{line}\x1b[K") } else { writeln!(err, "{line}") };
    }

    /// `label  done/total  pct%  rate/s  ETA` for the time elapsed so far.
    fn line(&self, elapsed: Duration) -> String {
        let fraction = if self.total == 0 { 1.0 } else { self.done as f64 / self.total as f64 };
        let rate = self.done as f64 / elapsed.as_secs_f64().max(1e-9);
        let eta = if rate > 0.0 && self.done < self.total { format_duration((self.total - self.done) as f64 / rate) } else { "-".into() };
        format!("{}: {}/{} ({:.0}%), {:.1}/s, ETA {}", self.label, self.done, self.total, 100.0 * fraction, rate, eta)
    }

    /// Draws the final state (unless just drawn) and ends the line on a terminal.
    pub fn finish(mut self) {
        if self.done != self.total || self.last_draw.is_none() {
            self.draw();
        }
        if self.terminal {
            let _ = writeln!(std::io::stderr());
        }
    }
}

/// `1h02m`, `3m05s` or `12s`.
fn format_duration(seconds: f64) -> String {
    let s = seconds.round() as u64;
    match s {
        0..60 => format!("{s}s"),
        60..3600 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, s % 3600 / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_shows_rate_and_eta() {
        let mut progress = Progress::new("staging", 100, 0);
        progress.terminal = true;
        progress.done = 25;
        let line = progress.line(Duration::from_secs(10));
        assert_eq!(line, "staging: 25/100 (25%), 2.5/s, ETA 30s");
        progress.done = 100;
        assert!(progress.line(Duration::from_secs(10)).ends_with("ETA -"));
        assert_eq!(format_duration(3725.0), "1h02m");
    }
}
