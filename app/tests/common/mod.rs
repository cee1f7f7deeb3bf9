//! Running the `likeness` binary from the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs `likeness` with a private runtime folder and without the user's template override.
pub fn likeness(args: &[&str]) -> Output {
    let xdg = std::env::temp_dir().join("likeness-xdg-tests");
    let _ = std::fs::create_dir_all(&xdg);
    Command::new(env!("CARGO_BIN_EXE_likeness"))
        .args(args)
        .env("XDG_RUNTIME_DIR", &xdg)
        .env_remove("LIKENESS_FACEMODEL")
        .output()
        .expect("run likeness")
}

/// A fresh temporary folder for one test.
pub fn out_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("likeness-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}
