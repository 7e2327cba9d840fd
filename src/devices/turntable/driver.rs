//! The turntable driver: Grbl 1.1 over a serial line (tokio-serial for hardware and ptys; any
//! `AsyncRead + AsyncWrite` for tests).
//!
//! [`Turntable::connect`] soft-resets the board, waits for the banner and checks the version
//! (`device.wrong-firmware`), reads the board's settings (`$$`: homing, steps, top rate, acceleration) and
//! reconciles the configuration with them ([`Motion::reconcile`]: the board is the truth; a config asking for
//! more than it allows is `device.config`), then homes, unlocks or does nothing as the board needs
//! ([`Homing::Auto`]). [`Turntable::move_to`] sends one absolute
//! move (`G90 G1 X… F…`), waits for its `ok`, then polls `?` until the board reports `Idle` and checks the
//! reported position against the target (`device.position`); a tilting table's [`Turntable::move_to_tilted`]
//! moves the cradle on Y along the same straight path (`G1 X… Y…`), within the configured range. Every wait has a deadline: a reply's is
//! [`TurntableSettings::reply_timeout`], a move's is derived from its distance, speed and acceleration, a
//! homing cycle's is [`TurntableSettings::home_timeout`] (`device.timeout`). End of file or EIO on the line is
//! `device.unplugged`; the caller drops the driver and reopens the port ([`super::transport::open_serial`]) with backoff, and a
//! new driver re-homes before its first move. `error:n` is `device.refused`, `ALARM:n` `device.alarm`. Lines
//! that parse as nothing are counted ([`Turntable::garbage_lines`]) and logged, never acted on.

use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

use super::protocol::{
    BoardSettings, MAX_REPLY_BYTES, MachineState, Reply, SOFT_RESET, STATUS_QUERY, StatusReport, alarm_text,
    error_text, move_line, move_line_tilted, move_seconds, version_supported,
};
use crate::error::{Error, ErrorCode, Result};

/// How the table's zero is established after a reset.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Homing {
    /// As the board is set up: `$H` where it has homing (`$22=1`), `$X` where it is locked without it, nothing
    /// otherwise (the zero is where the board stands).
    #[default]
    Auto,
    /// Run the homing cycle (`$H`): the table's zero is its home switch. The board must have homing.
    Home,
    /// Unlock (`$X`) when locked and take the position the board reports.
    Unlock,
}

impl Homing {
    /// The config's word for it.
    pub fn as_str(self) -> &'static str {
        match self {
            Homing::Auto => "auto",
            Homing::Home => "home",
            Homing::Unlock => "unlock",
        }
    }
}

/// The driver's settings (`[devices.turntable]` in the daemon's config).
#[derive(Clone, Debug, PartialEq)]
pub struct TurntableSettings {
    /// Top speed of a move, degrees per second (sent as `F`, per minute); `None`: the board's (`$110`).
    pub speed: Option<f64>,
    /// The acceleration the config expects, degrees per second²; `None`: the board's (`$120`). The moves'
    /// deadlines always use the board's.
    pub accel: Option<f64>,
    /// How the zero is established after a reset.
    pub homing: Homing,
    /// Deadline of one reply (`ok`, a status report).
    pub reply_timeout: Duration,
    /// Deadline of the banner after a reset (Arduino-class boards reset when the port opens: about 2 s).
    pub banner_timeout: Duration,
    /// Deadline of a homing cycle.
    pub home_timeout: Duration,
    /// A reached position may differ from the target by this much, degrees.
    pub position_tolerance: f64,
    /// Interval of `?` polls while a move runs.
    pub poll_interval: Duration,
    /// A tilting table's cradle on Grbl's Y, in degrees: its allowed range (lowest, highest); `None`: a
    /// single-axis table (a tilted move is `device.config`).
    pub tilt: Option<(f64, f64)>,
}

impl Default for TurntableSettings {
    fn default() -> Self {
        TurntableSettings {
            speed: None,
            accel: None,
            homing: Homing::Auto,
            reply_timeout: Duration::from_secs(2),
            banner_timeout: Duration::from_secs(5),
            home_timeout: Duration::from_secs(60),
            position_tolerance: 0.01,
            poll_interval: Duration::from_millis(50),
            tilt: None,
        }
    }
}

/// How the table moves: the configuration reconciled with the board's own settings.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// Top speed of a move, degrees per second (the config's, else the board's).
    pub speed: f64,
    /// The board's acceleration, degrees per second².
    pub accel: f64,
    /// How the zero is established (never [`Homing::Auto`]).
    pub homing: Homing,
    /// Where the config and the board disagree without harm, one line each naming both values.
    pub warnings: Vec<String>,
}

impl Motion {
    /// Reconcile `settings` with what the board reports: the board is the truth. A config speed below the
    /// board's top rate is used (a warning); one above it, or an acceleration above the board's, or
    /// `homing = "home"` on a board without homing, is an error. A lower configured acceleration is a
    /// warning; the deadlines use the board's.
    ///
    /// # Errors
    /// `device.config`, naming the config key and the board's setting.
    pub fn reconcile(settings: &TurntableSettings, board: &BoardSettings) -> Result<Motion> {
        let mut warnings = Vec::new();
        let top = board.max_speed();
        let bad = |m: String| Err(Error::new(ErrorCode::DeviceConfig, m));
        let speed = match settings.speed {
            None => top,
            Some(s) if s > top * (1.0 + 1e-9) => {
                return bad(format!(
                    "speed = {s} °/s is more than the board allows: $110 = {} °/min ({top:.3} °/s)",
                    board.max_rate
                ));
            }
            Some(s) => {
                if s < top * (1.0 - 1e-9) {
                    warnings.push(format!(
                        "speed = {s} °/s is below the board's $110 = {} °/min ({top:.3} °/s): moves run at {s} °/s",
                        board.max_rate
                    ));
                }
                s
            }
        };
        if let Some(a) = settings.accel {
            if a > board.accel * (1.0 + 1e-9) {
                return bad(format!("accel = {a} °/s² is more than the board's $120 = {} °/s²", board.accel));
            }
            if a < board.accel * (1.0 - 1e-9) {
                warnings.push(format!(
                    "accel = {a} °/s² differs from the board's $120 = {} °/s²: the deadlines use the board's",
                    board.accel
                ));
            }
        }
        let homing = match (settings.homing, board.homing) {
            (Homing::Home, false) => {
                return bad("homing = \"home\" but the board has homing disabled ($22 = 0): set $22=1 on the board, or use homing = \"auto\"".into());
            }
            (Homing::Auto | Homing::Home, true) => Homing::Home,
            (Homing::Auto | Homing::Unlock, _) => Homing::Unlock,
        };
        Ok(Motion { speed, accel: board.accel, homing, warnings })
    }

    /// The deadline of a move of `distance` degrees: twice its trapezoid's time at the board's acceleration,
    /// plus `reply_timeout`.
    pub fn move_timeout(&self, distance: f64, reply_timeout: Duration) -> Duration {
        let t = move_seconds(distance, self.speed, self.accel);
        Duration::from_secs_f64(2.0 * t) + reply_timeout
    }
}

/// One finished move.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct MoveReport {
    /// The target, degrees.
    pub target: f64,
    /// Where the board reports the table, degrees.
    pub reached: f64,
    /// Seconds from sending the move to `Idle`.
    pub seconds: f64,
    /// Where the board reports the cradle (Y), degrees (0 on a single-axis table).
    pub tilt: f64,
}

/// A connected turntable.
pub struct Turntable<S> {
    io: S,
    buf: Vec<u8>,
    settings: TurntableSettings,
    board: BoardSettings,
    motion: Motion,
    firmware: String,
    homed: bool,
    angle: f64,
    tilt: f64,
    garbage: u64,
    name: String,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Turntable<S> {
    /// Reset the board behind `io`, check its firmware, read its settings, and home or unlock it as it
    /// needs. `name` names the device in errors and logs (its port).
    ///
    /// # Errors
    /// `device.wrong-firmware`, `device.timeout` (no banner, no reply), `device.unplugged`, `device.alarm`,
    /// `device.refused`; `device.config` when the config asks for more than the board allows.
    pub async fn connect(io: S, settings: TurntableSettings, name: &str) -> Result<Self> {
        let mut t = Turntable {
            io,
            buf: Vec::new(),
            // Both until the board's `$$` is read (step 2).
            motion: Motion { speed: 0.0, accel: 0.0, homing: Homing::Unlock, warnings: Vec::new() },
            board: BoardSettings::FACTORY,
            settings,
            firmware: String::new(),
            homed: false,
            angle: 0.0,
            tilt: 0.0,
            garbage: 0,
            name: name.to_string(),
        };
        // 1. Soft reset, then the banner (lines before it — a power-on banner, line noise — are skipped).
        t.write(&[SOFT_RESET]).await?;
        let deadline = Instant::now() + t.settings.banner_timeout;
        let version = loop {
            match t.read_reply(deadline, "the banner").await? {
                Reply::Banner(v) => break v,
                other => tracing::debug!(device = %t.name, ?other, "before the banner"),
            }
        };
        if !version_supported(&version) {
            return Err(t.err(
                ErrorCode::DeviceWrongFirmware,
                format!("the board answers as Grbl {version}; the driver speaks Grbl 1.1"),
            ));
        }
        t.firmware = format!("Grbl {version}");
        // 2. The board's settings, and the config reconciled with them.
        t.board = t.read_board().await?;
        t.motion = Motion::reconcile(&t.settings, &t.board).map_err(|e| t.err(e.code, e.message))?;
        for w in &t.motion.warnings {
            tracing::warn!(device = %t.name, "{w}");
        }
        // 3. Locked (homing enabled, or an alarm before the reset)? Home or unlock.
        let status = t.status().await?;
        (t.angle, t.tilt) = (status.x, status.y);
        if status.state == MachineState::Alarm {
            t.unlock_or_home().await?;
        } else {
            t.homed = t.motion.homing == Homing::Unlock;
        }
        Ok(t)
    }

    /// Read the board's settings (`$$`: `$n=v` lines, then `ok`).
    async fn read_board(&mut self) -> Result<BoardSettings> {
        self.write(b"$$\n").await?;
        let deadline = Instant::now() + self.settings.reply_timeout;
        let mut pairs = Vec::new();
        loop {
            match self.read_reply(deadline, "the board's settings ($$)").await? {
                Reply::Setting(n, v) => pairs.push((n, v)),
                Reply::Ok => break,
                Reply::Error(n) => {
                    return Err(
                        self.err(ErrorCode::DeviceRefused, format!("$$ was refused: error:{n}, {}", error_text(n)))
                    );
                }
                Reply::Alarm(n) => return Err(self.alarm(n)),
                _ => {}
            }
        }
        BoardSettings::from_settings(&pairs).map_err(|m| self.err(ErrorCode::DeviceWrongFirmware, format!("$$: {m}")))
    }

    /// The board's settings as read at connect.
    pub fn board(&self) -> &BoardSettings {
        &self.board
    }

    /// How the table moves (the config reconciled with the board).
    pub fn motion(&self) -> &Motion {
        &self.motion
    }

    /// The firmware's name and version (`Grbl 1.1h`).
    pub fn firmware(&self) -> &str {
        &self.firmware
    }

    /// Whether the table's zero is established (homed, or unlocked when so configured).
    pub fn homed(&self) -> bool {
        self.homed
    }

    /// The table's angle as last reported, degrees.
    pub fn angle(&self) -> f64 {
        self.angle
    }

    /// The cradle's tilt as last reported, degrees (0 on a single-axis table).
    pub fn tilt(&self) -> f64 {
        self.tilt
    }

    /// Lines from the board that parsed as nothing.
    pub fn garbage_lines(&self) -> u64 {
        self.garbage
    }

    /// Run the homing cycle (`$H`), or unlock (`$X`), as the board and config need ([`Motion::homing`]).
    ///
    /// # Errors
    /// As [`Turntable::connect`].
    pub async fn unlock_or_home(&mut self) -> Result<()> {
        match self.motion.homing {
            Homing::Home | Homing::Auto => {
                self.command("$H\n", self.settings.home_timeout, "the homing cycle").await?;
                (self.angle, self.tilt) = (0.0, 0.0);
            }
            Homing::Unlock => {
                self.command("$X\n", self.settings.reply_timeout, "the unlock").await?;
                let s = self.status().await?;
                (self.angle, self.tilt) = (s.x, s.y);
            }
        }
        self.homed = true;
        Ok(())
    }

    /// Turn the table to `degrees` (absolute), homing first if the zero is not established. The cradle of a
    /// tilting table stays where it is.
    ///
    /// # Errors
    /// `input.bad-argument` for a non-finite target; `device.timeout` when the move does not finish within
    /// its deadline (a stalled table); `device.position` when the board stops off the target;
    /// `device.alarm`, `device.refused`, `device.unplugged`.
    pub async fn move_to(&mut self, degrees: f64) -> Result<MoveReport> {
        self.move_axes(degrees, None).await
    }

    /// Turn the table to `degrees` and tilt the cradle to `tilt` (both absolute, degrees), along one straight
    /// path (`G1 X… Y…`), homing first if the zero is not established.
    ///
    /// # Errors
    /// As [`Turntable::move_to`]; `device.config` on a table with no tilt axis configured;
    /// `input.bad-argument` for a tilt outside the configured range.
    pub async fn move_to_tilted(&mut self, degrees: f64, tilt: f64) -> Result<MoveReport> {
        let Some((lo, hi)) = self.settings.tilt else {
            return Err(self.err(
                ErrorCode::DeviceConfig,
                "this turntable has no tilt axis: set tilt_min and tilt_max in [devices.turntable] for a cradle on Grbl's Y",
            ));
        };
        if !(tilt.is_finite() && (lo..=hi).contains(&tilt)) {
            return Err(Error::new(
                ErrorCode::InputBadArgument,
                format!(
                    "a tilt of {tilt}° is outside the cradle's range {lo}° to {hi}° ([devices.turntable] tilt_min, tilt_max)"
                ),
            ));
        }
        self.move_axes(degrees, Some(tilt)).await
    }

    /// One absolute move: X to `degrees`, and Y to `tilt` when given. Waits for `Idle` within the move's
    /// deadline (its straight path's length at the table's speed and acceleration) and checks both axes.
    async fn move_axes(&mut self, degrees: f64, tilt: Option<f64>) -> Result<MoveReport> {
        if !degrees.is_finite() || degrees.abs() > 1e6 {
            return Err(Error::new(ErrorCode::InputBadArgument, format!("a turntable target of {degrees}°")));
        }
        if !self.homed {
            self.unlock_or_home().await?;
        }
        let start = Instant::now();
        let path = (degrees - self.angle).hypot(tilt.map_or(0.0, |t| t - self.tilt));
        let allowed = self.motion.move_timeout(path, self.settings.reply_timeout);
        let deadline = start + allowed;
        let feed = self.motion.speed * 60.0;
        let line = match tilt {
            Some(t) => move_line_tilted(degrees, t, feed),
            None => move_line(degrees, feed),
        };
        self.command(&line, self.settings.reply_timeout, "the move").await?;
        loop {
            tokio::time::sleep(self.settings.poll_interval).await;
            let s = self.status().await?;
            (self.angle, self.tilt) = (s.x, s.y);
            match s.state {
                MachineState::Idle => break,
                MachineState::Alarm => return Err(self.err(ErrorCode::DeviceAlarm, "the board locked during the move")),
                _ => {}
            }
            if Instant::now() > deadline {
                return Err(self.err(
                    ErrorCode::DeviceTimeout,
                    format!(
                        "the move to {degrees:.3}° did not finish within {:.1} s (stopped at {:.3}°, tilt {:.3}°, state {:?})",
                        allowed.as_secs_f64(),
                        s.x,
                        s.y,
                        s.state
                    ),
                ));
            }
        }
        let tol = self.settings.position_tolerance;
        if (self.angle - degrees).abs() > tol || tilt.is_some_and(|t| (self.tilt - t).abs() > tol) {
            let asked = tilt.map_or(String::new(), |t| format!(" tilted {t:.4}°"));
            return Err(self.err(
                ErrorCode::DevicePosition,
                format!(
                    "the table stopped at {:.4}° tilted {:.4}°, not at {degrees:.4}°{asked}",
                    self.angle, self.tilt
                ),
            ));
        }
        Ok(MoveReport { target: degrees, reached: self.angle, seconds: start.elapsed().as_secs_f64(), tilt: self.tilt })
    }

    /// Hold the table where it is (`!`), then reset the board so that the held move is dropped; the board's
    /// position is kept (a reset in a hold is not an alarm).
    ///
    /// # Errors
    /// `device.unplugged`.
    pub async fn stop(&mut self) -> Result<()> {
        self.write(b"!").await?;
        tokio::time::sleep(self.settings.poll_interval).await;
        self.write(&[SOFT_RESET]).await?;
        let deadline = Instant::now() + self.settings.banner_timeout;
        while !matches!(self.read_reply(deadline, "the banner after a stop").await?, Reply::Banner(_)) {}
        let s = self.status().await?;
        (self.angle, self.tilt) = (s.x, s.y);
        if s.state == MachineState::Alarm {
            self.homed = false;
        }
        Ok(())
    }

    /// A status report (`?`).
    ///
    /// # Errors
    /// `device.timeout`, `device.unplugged`, `device.alarm` (an `ALARM:n` line arrived instead).
    pub async fn status(&mut self) -> Result<StatusReport> {
        self.write(&[STATUS_QUERY]).await?;
        let deadline = Instant::now() + self.settings.reply_timeout;
        loop {
            match self.read_reply(deadline, "a status report").await? {
                Reply::Status(s) => return Ok(s),
                Reply::Alarm(n) => return Err(self.alarm(n)),
                // An `ok` or feedback of an earlier line, or a banner: not the answer.
                _ => {}
            }
        }
    }

    /// Send `line` and wait for its `ok` until `timeout`.
    async fn command(&mut self, line: &str, timeout: Duration, what: &str) -> Result<()> {
        self.write(line.as_bytes()).await?;
        let deadline = Instant::now() + timeout;
        loop {
            match self.read_reply(deadline, what).await? {
                Reply::Ok => return Ok(()),
                Reply::Error(n) => {
                    return Err(self.err(
                        ErrorCode::DeviceRefused,
                        format!("{what} ({}) was refused: error:{n}, {}", line.trim(), error_text(n)),
                    ));
                }
                Reply::Alarm(n) => return Err(self.alarm(n)),
                _ => {}
            }
        }
    }

    fn alarm(&mut self, n: u32) -> Error {
        self.homed = false;
        self.err(ErrorCode::DeviceAlarm, format!("ALARM:{n}, {}", alarm_text(n)))
    }

    fn err(&self, code: ErrorCode, message: impl Into<String>) -> Error {
        Error::new(code, format!("turntable {}: {}", self.name, message.into()))
    }

    async fn write(&mut self, bytes: &[u8]) -> Result<()> {
        let r = async {
            self.io.write_all(bytes).await?;
            self.io.flush().await
        };
        match tokio::time::timeout(self.settings.reply_timeout, r).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(self.err(ErrorCode::DeviceUnplugged, format!("writing failed: {e}"))),
            Err(_) => Err(self.err(ErrorCode::DeviceTimeout, "the port did not take a write")),
        }
    }

    /// The next line that parses; garbage is counted and skipped.
    async fn read_reply(&mut self, deadline: Instant, what: &str) -> Result<Reply> {
        loop {
            while let Some(end) = self.buf.iter().position(|&b| b == b'\n') {
                let raw: Vec<u8> = self.buf.drain(..=end).collect();
                let line = String::from_utf8_lossy(&raw);
                let line = line.trim_matches(|c: char| c == '\r' || c == '\n' || c == '\0');
                if line.is_empty() {
                    continue;
                }
                match Reply::parse(line) {
                    Some(r) => return Ok(r),
                    None => {
                        self.garbage += 1;
                        tracing::warn!(device = %self.name, line = %line.escape_debug(), "garbage from the turntable");
                    }
                }
            }
            if self.buf.len() > MAX_REPLY_BYTES {
                self.garbage += 1;
                tracing::warn!(device = %self.name, bytes = self.buf.len(), "an overlong line from the turntable");
                self.buf.clear();
            }
            let mut chunk = [0u8; 256];
            match tokio::time::timeout_at(deadline, self.io.read(&mut chunk)).await {
                Err(_) => return Err(self.err(ErrorCode::DeviceTimeout, format!("no answer while waiting for {what}"))),
                Ok(Ok(0)) => return Err(self.err(ErrorCode::DeviceUnplugged, "the port reached end of file")),
                Ok(Err(e)) => return Err(self.err(ErrorCode::DeviceUnplugged, format!("reading failed: {e}"))),
                Ok(Ok(n)) => self.buf.extend_from_slice(&chunk[..n]),
            }
        }
    }
}
