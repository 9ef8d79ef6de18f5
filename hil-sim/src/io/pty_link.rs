//! The ptys hil-sim serves serial lines on (Modbus RTU, weighing lines) and the symlinks that name
//! them in its config (`rtu_pty_link`, `pty_link`): a link is made only where no live pty is named
//! already, and removed with the pty, so a gateway never opens a link that outlived its pty (the
//! kernel reuses pty numbers: a stale link may name another process's terminal).

use std::path::{Path, PathBuf};

use tokio_serial::SerialStream;

/// The symlink to one of our ptys: removed when dropped (the program ended, Ctrl-C, SIGTERM) if it
/// still points to our pty, so no link outlives the pty it names. After a SIGKILL the link stays;
/// [`claim_link`] then tells a dead link (replaced) from one whose pty is alive (refused).
#[derive(Debug)]
pub(crate) struct PtyLink {
    link: PathBuf,
    pub(crate) dev: PathBuf,
}

impl Drop for PtyLink {
    fn drop(&mut self) {
        if std::fs::read_link(&self.link).is_ok_and(|t| t == self.dev) {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}

/// Make `link` free for a new pty link: absent, or a symlink whose pty is gone (a killed run's).
/// A symlink to a pty that exists is refused: the kernel may have handed that pty to another
/// process (a gateway opening the link would open someone else's terminal), or another hil-sim uses it.
pub(crate) fn claim_link(link: &Path) -> anyhow::Result<()> {
    let shown = link.display();
    match std::fs::symlink_metadata(link) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(anyhow::anyhow!("pty link {shown}: {e}")),
        Ok(m) if m.file_type().is_symlink() => {
            let target = std::fs::read_link(link)?;
            anyhow::ensure!(
                !target.exists(),
                "pty link {shown} points to {}, a pty this hil-sim does not own (another hil-sim \
                 uses it, or the link is stale and the kernel gave that pty to another process): \
                 stop that hil-sim or remove the link",
                target.display()
            );
            std::fs::remove_file(link)
                .map_err(|e| anyhow::anyhow!("removing the stale pty link {shown}: {e}"))
        }
        Ok(_) => Err(anyhow::anyhow!(
            "pty link {shown} exists and is not a symlink: refusing to replace it"
        )),
    }
}

pub(crate) fn pty_pair(link: &Path) -> anyhow::Result<(SerialStream, SerialStream, PtyLink)> {
    claim_link(link)?;
    let (master, slave) = SerialStream::pair().map_err(|e| anyhow::anyhow!("pty: {e}"))?;
    let dev = PathBuf::from(
        tokio_serial::SerialPort::name(&slave)
            .ok_or_else(|| anyhow::anyhow!("pty: slave has no device name"))?,
    );
    std::os::unix::fs::symlink(&dev, link)
        .map_err(|e| anyhow::anyhow!("pty link {}: {e}", link.display()))?;
    let link = PtyLink {
        link: link.to_path_buf(),
        dev,
    };
    Ok((master, slave, link))
}

#[cfg(test)]
mod tests {
    use super::*;

    // A tokio runtime: the pty pair registers with its reactor.
    #[tokio::test]
    async fn a_dead_link_is_replaced_a_live_one_refused_and_ours_removed_on_drop() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("pty");
        // A killed run's link: its pty is gone.
        std::os::unix::fs::symlink(dir.path().join("gone"), &link).unwrap();
        claim_link(&link).unwrap();
        assert!(std::fs::symlink_metadata(&link).is_err(), "dead link kept");
        // A link to something that exists (here a file standing in for a reused pty).
        let other = dir.path().join("someone-elses-pty");
        std::fs::write(&other, "").unwrap();
        std::os::unix::fs::symlink(&other, &link).unwrap();
        let e = claim_link(&link).unwrap_err().to_string();
        assert!(e.contains("does not own"), "{e}");
        assert!(std::fs::read_link(&link).is_ok(), "a live link was removed");
        std::fs::remove_file(&link).unwrap();
        // A plain file is never replaced.
        std::fs::write(&link, "x").unwrap();
        assert!(claim_link(&link).is_err());
        std::fs::remove_file(&link).unwrap();

        // Ours: made by pty_pair, removed when dropped; a link someone replaced meanwhile stays.
        let (_m, _s, ours) = pty_pair(&link).unwrap();
        assert_eq!(std::fs::read_link(&link).unwrap(), ours.dev);
        drop(ours);
        assert!(
            std::fs::symlink_metadata(&link).is_err(),
            "our link outlived us"
        );
        let (_m2, _s2, ours) = pty_pair(&link).unwrap();
        std::fs::remove_file(&link).unwrap();
        std::os::unix::fs::symlink(&other, &link).unwrap();
        drop(ours);
        assert_eq!(std::fs::read_link(&link).unwrap(), other);
    }
}
