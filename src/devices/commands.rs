//! Command lines for the simulators (typed on stdin, or sent to a control socket), read with a bound: a line
//! longer than [`MAX_COMMAND_BYTES`] is dropped, not buffered, so `scanstation sim turntable < /dev/zero` or a
//! peer that never sends a newline holds at most that many bytes.

use std::io::Read;

/// Longest command line, bytes (the longest command, `error 4294967295`, is 16).
pub const MAX_COMMAND_BYTES: usize = 256;

/// A line read with [`for_each_line`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CommandLine {
    /// A line, without its line ending (invalid UTF-8 replaced).
    Line(String),
    /// A line over the bound, dropped: its length in bytes so far (counting stops at the bound's 1024 times).
    TooLong(usize),
}

/// Read `r` to its end (or an error), handing each line to `each` until it returns `false`. At most
/// [`MAX_COMMAND_BYTES`] of a line are held; the rest of an overlong line is skipped up to its newline and the
/// line reported as [`CommandLine::TooLong`] once. Cost: O(bytes read), 4 KiB of buffer.
pub fn for_each_line(mut r: impl Read, mut each: impl FnMut(CommandLine) -> bool) {
    let mut line: Vec<u8> = Vec::with_capacity(MAX_COMMAND_BYTES);
    let mut over = 0usize;
    let mut buf = [0u8; 4096];
    loop {
        let n = match r.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) => break,
        };
        for &b in &buf[..n] {
            if b == b'\n' {
                let item = if over > 0 {
                    CommandLine::TooLong(over)
                } else {
                    CommandLine::Line(String::from_utf8_lossy(&line).trim_end_matches('\r').to_string())
                };
                line.clear();
                over = 0;
                if !each(item) {
                    return;
                }
            } else if over > 0 {
                over = over.saturating_add(1).min(MAX_COMMAND_BYTES * 1024);
            } else if line.len() == MAX_COMMAND_BYTES {
                over = line.len() + 1;
                line.clear();
            } else {
                line.push(b);
            }
        }
    }
    if over > 0 {
        each(CommandLine::TooLong(over));
    } else if !line.is_empty() {
        each(CommandLine::Line(String::from_utf8_lossy(&line).to_string()));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(r: impl Read) -> Vec<CommandLine> {
        let mut out = Vec::new();
        for_each_line(r, |l| {
            out.push(l);
            true
        });
        out
    }

    #[test]
    fn lines_are_split_and_a_last_line_without_newline_counts() {
        let got = all(&b"unplug\r\nerror 9\n\nquit"[..]);
        let want = ["unplug", "error 9", "", "quit"].map(|s| CommandLine::Line(s.into()));
        assert_eq!(got, want);
    }

    /// `sim turntable < /dev/zero` grew by 750 MB/s until the kernel killed it: 50 MB of NULs with no
    /// newline now cost one dropped line, and the command after it still arrives.
    #[test]
    fn an_endless_line_is_dropped_not_buffered() {
        let zeros = std::io::repeat(0).take(50_000_000);
        let got = all(zeros.chain(&b"\nreplug\n"[..]));
        assert_eq!(got, [CommandLine::TooLong(MAX_COMMAND_BYTES * 1024), CommandLine::Line("replug".into())]);
        let got = all(std::io::repeat(b'x').take(MAX_COMMAND_BYTES as u64 + 1).chain(&b"\nquit\n"[..]));
        assert_eq!(got, [CommandLine::TooLong(MAX_COMMAND_BYTES + 1), CommandLine::Line("quit".into())]);
        let exact = "y".repeat(MAX_COMMAND_BYTES);
        assert_eq!(all(format!("{exact}\n").as_bytes()), [CommandLine::Line(exact)]);
    }

    #[test]
    fn the_reader_stops_when_told() {
        let mut n = 0;
        for_each_line(&b"a\nb\nc\n"[..], |_| {
            n += 1;
            n < 2
        });
        assert_eq!(n, 2);
    }
}
