//! Where `retrocomp eval`'s output goes while rows are still being checked: a bad row anywhere means
//! nothing is written, so the output is either written where it can be taken back (stdout is a
//! regular file at its end) or held until every row was good (a spool: memory, then an unlinked
//! temporary file).

use std::io::Write;

/// Where the output goes while rows are still being checked: a bad row anywhere means nothing is
/// written, so either the output can be taken back, or it is held until the end.
pub(super) enum Output {
    /// stdout is a regular file positioned at its end (`> out.csv`): rows go straight into it, and
    /// a bad row truncates it back to `start`, the length it had, so it then holds what it held
    /// before. Writing the rows once instead of twice (spool, then copy) halved the command's CPU
    /// time on 10⁶ rows: the kernel's copies of the ≈ 290 MB were half of it.
    Direct { file: std::fs::File, start: u64 },
    /// Anything else (a pipe, a terminal, a file opened for appending or rewriting in place): held
    /// in memory up to [`Output::IN_MEMORY`], then in an unlinked temporary file (removed by the OS
    /// however the process ends), and copied to stdout once every row was good.
    Spool(tempfile::SpooledTempFile),
}

impl Output {
    const IN_MEMORY: usize = 4 << 20;

    pub(super) fn for_stdout() -> Self {
        use std::io::Seek as _;
        use std::os::fd::AsFd as _;
        let direct = std::io::stdout()
            .as_fd()
            .try_clone_to_owned()
            .ok()
            .map(std::fs::File::from)
            .and_then(|mut file| {
                let meta = file.metadata().ok()?;
                // Taking rows back is exact only when nothing follows them: position = length.
                // (`>>` opens with the position at 0, so a non-empty appended file is spooled.)
                let start = file.stream_position().ok()?;
                (meta.is_file() && start == meta.len()).then_some(Output::Direct { file, start })
            });
        direct.unwrap_or_else(|| Output::Spool(tempfile::SpooledTempFile::new(Self::IN_MEMORY)))
    }

    pub(super) fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        match self {
            Output::Direct { file, .. } => file.write_all(buf),
            Output::Spool(s) => s.write_all(buf).map_err(|e| {
                std::io::Error::new(e.kind(), format!("cannot spool the output: {e}"))
            }),
        }
    }

    /// Every row was good: make the output final.
    pub(super) fn finish(self) -> anyhow::Result<()> {
        use std::io::Seek as _;
        let Output::Spool(mut s) = self else {
            return Ok(());
        };
        let stdout = std::io::stdout();
        let mut w = stdout.lock();
        s.rewind()?;
        match s.into_inner() {
            tempfile::SpooledData::InMemory(c) => w.write_all(c.get_ref())?,
            // File → stdout: std uses copy_file_range/sendfile/splice here, no user-space copy.
            tempfile::SpooledData::OnDisk(mut f) => {
                std::io::copy(&mut f, &mut w)?;
            }
        }
        w.flush()?;
        Ok(())
    }

    /// A row was bad: take back what was written.
    pub(super) fn discard(self) -> std::io::Result<()> {
        use std::io::Seek as _;
        if let Output::Direct { mut file, start } = self {
            file.set_len(start)?;
            // The position is shared with the shell's descriptor (and stderr's, with `2>&1`).
            file.seek(std::io::SeekFrom::Start(start))?;
        }
        Ok(())
    }
}
