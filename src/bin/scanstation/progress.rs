//! Progress of a long command on stderr at `-v`: one `tracing` line when the phase changes or the share done
//! has grown by 5 points since the last line.

use std::sync::Mutex;
use std::time::Instant;

use scanstation::stages::Progress;

/// Logs a command's progress (phase and share done) at INFO, so `-v` shows it.
pub struct LogProgress {
    command: &'static str,
    start: Instant,
    last: Mutex<Option<(String, f64)>>,
}

impl LogProgress {
    /// Progress of `command` (the subcommand's name, the first word of every line).
    pub fn new(command: &'static str) -> Self {
        LogProgress { command, start: Instant::now(), last: Mutex::new(None) }
    }
}

impl Progress for LogProgress {
    fn report(&self, fraction: f64, phase: &str) {
        let f = if fraction.is_finite() { fraction.clamp(0.0, 1.0) } else { 0.0 };
        let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
        let due = match &*last {
            None => true,
            Some((p, g)) => p != phase || f >= g + 0.05,
        };
        if due {
            *last = Some((phase.to_string(), f));
            tracing::info!(
                "{}: {:5.1} % {phase} ({:.1} s)",
                self.command,
                100.0 * f,
                self.start.elapsed().as_secs_f64()
            );
        }
    }
}
