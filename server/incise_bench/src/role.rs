//! Another role of this program in a process of its own (a report's server or client), started
//! and stopped by the report.

use anyhow::bail;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Command, Stdio};

/// A free TCP port on loopback.
pub fn free_port() -> anyhow::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// A role of this program in a process of its own, ready (it printed `ready`); it stops when
/// its standard input closes ([`Role::finish`]) or when dropped (killed).
pub struct Role {
    child: std::process::Child,
    lines: BufReader<std::process::ChildStdout>,
}

impl Role {
    /// Starts `exe` with `args` (the role's name first) and waits for its `ready`.
    pub fn start(exe: &Path, args: &[String]) -> anyhow::Result<Self> {
        let mut child = Command::new(exe)
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()?;
        let mut lines = BufReader::new(child.stdout.take().expect("piped"));
        let mut line = String::new();
        lines.read_line(&mut line)?;
        if line.trim() != "ready" {
            let _ = child.kill();
            bail!("the {} did not start: {line}", args[0]);
        }
        Ok(Self { child, lines })
    }

    /// Closes its input and returns everything it printed after `ready`.
    pub fn finish(mut self) -> anyhow::Result<String> {
        drop(self.child.stdin.take());
        let mut rest = String::new();
        self.lines.read_to_string(&mut rest)?;
        self.child.wait()?;
        Ok(rest)
    }
}

impl Drop for Role {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
