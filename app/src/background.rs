//! Files the studio writes on their own threads (session saves, autosaves, exports), so a
//! long clip's session or a rig export never freezes the window; the UI polls each one
//! every frame and reports how it ended.

use std::path::PathBuf;
use std::sync::mpsc;

/// One file being written in the background.
pub struct BackgroundWrite {
    /// What is written, for messages ("session", "glTF animation", ...).
    pub what: String,
    receiver: mpsc::Receiver<Result<PathBuf, String>>,
}

impl BackgroundWrite {
    /// Runs `job` (which returns the path it wrote) on a new thread named after `what`.
    pub fn spawn(
        what: impl Into<String>,
        job: impl FnOnce() -> Result<PathBuf, String> + Send + 'static,
    ) -> Result<Self, String> {
        let what = what.into();
        let (sender, receiver) = mpsc::channel();
        std::thread::Builder::new()
            .name(format!("likeness write: {what}"))
            .spawn(move || {
                // The receiver is gone only if the studio closed; nothing is left to tell.
                let _ = sender.send(job());
            })
            .map_err(|e| format!("{what}: cannot start writing: {e}"))?;
        Ok(Self { what, receiver })
    }

    /// Blocks until the write ends (when the studio closes with it still running).
    pub fn wait(self) -> Result<PathBuf, String> {
        self.receiver
            .recv()
            .unwrap_or_else(|_| Err(stopped(&self.what)))
    }

    /// `None` while the write runs; then the path written or the error. A thread that
    /// ended without an answer (it panicked) is reported as an error, never as success.
    pub fn poll(&self) -> Option<Result<PathBuf, String>> {
        match self.receiver.try_recv() {
            Ok(result) => Some(result),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => Some(Err(stopped(&self.what))),
        }
    }
}

/// The error of a write whose thread ended without an answer (it panicked).
fn stopped(what: &str) -> String {
    format!("{what}: the write stopped without finishing")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    fn wait(write: &BackgroundWrite) -> Result<PathBuf, String> {
        let started = Instant::now();
        loop {
            if let Some(result) = write.poll() {
                return result;
            }
            assert!(
                started.elapsed() < Duration::from_secs(10),
                "write never ended"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn reports_the_written_file_and_errors_and_a_panicked_write() {
        let dir = std::env::temp_dir().join(format!("likeness-bg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("out.txt");
        let target = path.clone();
        let (release, gate) = mpsc::channel::<()>();
        let write = BackgroundWrite::spawn("text", move || {
            // Held until the test has seen the write still running.
            let _ = gate.recv();
            std::fs::write(&target, "hello").map_err(|e| e.to_string())?;
            Ok(target)
        })
        .unwrap();
        assert!(write.poll().is_none(), "still running");
        release.send(()).unwrap();
        assert_eq!(wait(&write), Ok(path.clone()));
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "hello");

        let failing = BackgroundWrite::spawn("rig", || Err("disk full".into())).unwrap();
        assert_eq!(wait(&failing), Err("disk full".into()));
        let blocking = BackgroundWrite::spawn("session", || Err("read-only".into())).unwrap();
        assert_eq!(blocking.wait(), Err("read-only".into()));

        let panicking = BackgroundWrite::spawn("csv", || panic!("bug")).unwrap();
        let error = wait(&panicking).unwrap_err();
        assert!(error.starts_with("csv: "), "{error}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
