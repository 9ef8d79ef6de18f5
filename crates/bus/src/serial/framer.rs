//! Line framer for serial instruments: bytes in, lines out. A line ends at CR, LF or CRLF; empty lines
//! are skipped. A line longer than `max_len` is dropped up to its terminator and counted, so noise
//! without terminators cannot grow memory. The framer does not interpret content (STX, signs, units).

/// Default longest line accepted, bytes.
pub(crate) const DEFAULT_MAX_LINE: usize = 128;

#[derive(Debug, Clone)]
pub struct LineFramer {
    buf: Vec<u8>,
    max_len: usize,
    discarding: bool,
    /// Lines dropped for exceeding `max_len`.
    pub overlong: u64,
    /// Complete lines produced.
    pub lines: u64,
}

impl Default for LineFramer {
    fn default() -> Self {
        Self::new(DEFAULT_MAX_LINE)
    }
}

impl LineFramer {
    pub fn new(max_len: usize) -> Self {
        LineFramer {
            buf: Vec::with_capacity(max_len.min(4096)),
            max_len: max_len.max(1),
            discarding: false,
            overlong: 0,
            lines: 0,
        }
    }

    /// Feed bytes; `on_line` is called with every complete line (without terminator).
    pub fn push(&mut self, bytes: &[u8], mut on_line: impl FnMut(&[u8])) {
        for &b in bytes {
            if b == b'\r' || b == b'\n' {
                if self.discarding {
                    self.discarding = false;
                } else if !self.buf.is_empty() {
                    self.lines += 1;
                    on_line(&self.buf);
                }
                self.buf.clear();
            } else if self.discarding {
            } else if self.buf.len() == self.max_len {
                self.overlong += 1;
                self.discarding = true;
                self.buf.clear();
            } else {
                self.buf.push(b);
            }
        }
    }

    /// Bytes of the unfinished line held (a partial line at shutdown is not a reading).
    pub fn partial_len(&self) -> usize {
        self.buf.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_on_cr_lf_crlf_and_drops_overlong() {
        let mut f = LineFramer::new(8);
        let mut got: Vec<Vec<u8>> = Vec::new();
        f.push(b"01A+0000.1", |l| got.push(l.to_vec()));
        assert!(got.is_empty());
        f.push(b"\r\nab\ncd\r\r\n0123456789abc\nok\r", |l| {
            got.push(l.to_vec());
        });
        // `01A+0000.1` and `0123456789abc` exceed 8 bytes: dropped whole, not cut.
        assert_eq!(got, vec![b"ab".to_vec(), b"cd".to_vec(), b"ok".to_vec()]);
        assert_eq!((f.overlong, f.lines), (2, 3));
    }
}
