//! Line reader for the text formats: tracks line numbers, strips `\r`, rejects invalid UTF-8 with a location,
//! and never holds more than [`MAX_LINE_BYTES`] of one line.

use std::io::BufRead;

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::io::io_err;

/// Longest line a text reader accepts, bytes (1 MiB). Real lines are short: a vertex is under 100 bytes, and
/// an OBJ face of 65,536 corners (the PLY reader's largest face) is about 500 KiB. A longer line (a file of
/// zeros, a comment without a line break, a gzip bomb) is `input.bad-record` after reading at most this much of it.
pub(crate) const MAX_LINE_BYTES: usize = 1 << 20;

/// Reads lines one at a time into a reused buffer of at most [`MAX_LINE_BYTES`].
pub(crate) struct Lines<'a, 'b> {
    reader: &'a mut (dyn BufRead + 'b),
    buf: Vec<u8>,
    /// 1-based number of the line last returned.
    pub line: u64,
    /// Bytes consumed so far.
    pub bytes: u64,
}

impl<'a, 'b> Lines<'a, 'b> {
    pub fn new(reader: &'a mut (dyn BufRead + 'b)) -> Self {
        Lines { reader, buf: Vec::with_capacity(256), line: 0, bytes: 0 }
    }

    /// The next line without its line ending, and its location, or `None` at the end of the data.
    pub fn next_line(&mut self) -> Result<Option<(&str, Location)>> {
        self.buf.clear();
        let n = self.read_bounded()?;
        if n == 0 {
            return Ok(None);
        }
        self.line += 1;
        self.bytes += n as u64;
        while matches!(self.buf.last(), Some(b'\n' | b'\r')) {
            self.buf.pop();
        }
        let loc = Location::Line(self.line);
        std::str::from_utf8(&self.buf)
            .map(|l| Some((l, loc)))
            .map_err(|_| Error::new(ErrorCode::InputBadRecord, "not valid text (UTF-8)").at(Location::Line(self.line)))
    }

    /// Read up to and including the next `\n` into `buf`, failing once the line passes [`MAX_LINE_BYTES`]
    /// (before the buffer grows past it). Returns the bytes consumed (0 at the end of the data).
    fn read_bounded(&mut self) -> Result<usize> {
        loop {
            let avail = match self.reader.fill_buf() {
                Ok(a) => a,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(io_err(e).at(self.loc_next())),
            };
            if avail.is_empty() {
                return Ok(self.buf.len());
            }
            let (used, done) = match avail.iter().position(|&b| b == b'\n') {
                Some(i) => (i + 1, true),
                None => (avail.len(), false),
            };
            if self.buf.len() + used > MAX_LINE_BYTES + 2 {
                return Err(Error::new(
                    ErrorCode::InputBadRecord,
                    format!(
                        "the line starting at byte {} is longer than {} bytes (the longest line accepted)",
                        self.bytes, MAX_LINE_BYTES
                    ),
                )
                .at(self.loc_next())
                .with_hint("a text mesh or cloud has one short record per line; is this file binary, or not a scan?"));
            }
            self.buf.extend_from_slice(&avail[..used]);
            self.reader.consume(used);
            if done {
                return Ok(self.buf.len());
            }
        }
    }

    /// The line last returned by [`Lines::next_line`] (empty before the first).
    pub fn current(&self) -> &str {
        std::str::from_utf8(&self.buf).unwrap_or("")
    }

    fn loc_next(&self) -> Location {
        Location::Line(self.line + 1)
    }
}

/// Parse a number token, with the line in the error.
#[inline]
pub(crate) fn parse_num<T: std::str::FromStr>(tok: &str, what: &str, loc: Location) -> Result<T> {
    tok.parse::<T>()
        .map_err(|_| Error::new(ErrorCode::InputBadNumber, format!("{what}: {tok:?} is not a number")).at(loc))
}

/// Parse three coordinates from an iterator of tokens.
pub(crate) fn parse_xyz<'t>(toks: &mut impl Iterator<Item = &'t str>, what: &str, loc: Location) -> Result<[f32; 3]> {
    let mut p = [0f32; 3];
    for c in &mut p {
        let tok = toks.next().ok_or_else(|| {
            Error::new(ErrorCode::InputBadRecord, format!("{what}: fewer than 3 coordinates")).at(loc)
        })?;
        *c = parse_num::<f32>(tok, what, loc)?;
    }
    Ok(p)
}
