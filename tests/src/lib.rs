//! Helpers for the end-to-end tests: building the firmware's on-target binaries and
//! running them under `qemu-system-arm -M netduinoplus2` (the STM32F405 emulated).
#![deny(missing_docs)]
// Test support: a failed tool invocation is a failed test, so panicking is the right report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

pub mod fuzz;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The Cortex-M4F target the firmware binaries are built for.
pub const TARGET: &str = "thumbv7em-none-eabihf";

/// The workspace root (the parent of this crate).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Builds firmware binary `bin` (release, thumb target, with `features`) into a target
/// directory of its own, so the build never waits on the lock of the `cargo test` that
/// runs this, and returns the ELF's path. Panics with the build's output on failure.
pub fn build_firmware_bin(bin: &str, features: &str) -> PathBuf {
    build_firmware_bin_with_env(bin, features, &[])
}

/// Like [`build_firmware_bin`] with extra environment variables for the build (e.g. a
/// binary's build-time `option_env!` settings).
pub fn build_firmware_bin_with_env(bin: &str, features: &str, env: &[(&str, &str)]) -> PathBuf {
    let root = workspace_root();
    let target_dir = root.join("target").join("qemu");
    let out = Command::new(env!("CARGO"))
        .current_dir(&root)
        .args(["build", "-p", "firmware", "--release", "--target", TARGET])
        .args(["--features", features, "--bin", bin])
        .env("CARGO_TARGET_DIR", &target_dir)
        .envs(env.iter().copied())
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "building {bin} for {TARGET} failed (is the target installed? `rustup target add {TARGET}`; is flip-link? `cargo install flip-link`):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    target_dir.join(TARGET).join("release").join(bin)
}

/// The `KEY VALUE` pairs of the lines of `stdout` that start with `prefix` (e.g. a
/// binary's `budget worst_step 123` lines with prefix `"budget "`); unparsable values are
/// left out.
pub fn keyed_values<'a, T: std::str::FromStr>(
    stdout: &'a str,
    prefix: &str,
) -> std::collections::HashMap<&'a str, T> {
    stdout
        .lines()
        .filter_map(|l| l.strip_prefix(prefix))
        .filter_map(|l| {
            let (k, v) = l.split_once(' ')?;
            Some((k, v.trim().parse().ok()?))
        })
        .collect()
}

/// What a QEMU run printed and how it ended.
#[derive(Debug)]
pub struct QemuRun {
    /// Semihosting output (the binary's stdout).
    pub stdout: String,
    /// QEMU's own messages.
    pub stderr: String,
    /// The exit status the binary gave through semihosting.
    pub success: bool,
}

/// Runs `elf` on the emulated STM32F405 (`-M netduinoplus2`) with semihosting and
/// deterministic instruction counting (`-icount shift=0`), killing it after `timeout`.
pub fn run_in_qemu(elf: &Path, timeout: Duration) -> QemuRun {
    let mut child = Command::new("qemu-system-arm")
        .args(["-cpu", "cortex-m4", "-M", "netduinoplus2", "-nographic"])
        .args(["-monitor", "none", "-serial", "none"])
        .args(["-semihosting-config", "enable=on,target=native", "-icount", "shift=0"])
        .arg("-kernel")
        .arg(elf)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("qemu-system-arm not found: run `apt-get install -y qemu-system-arm` (or `bash .ci/setup`)");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("qemu wait").is_some() {
            break;
        }
        if start.elapsed() > timeout {
            let _ = child.kill();
            let out = child.wait_with_output().expect("qemu output");
            panic!(
                "QEMU run of {} timed out after {timeout:?}; output so far:\n{}",
                elf.display(),
                String::from_utf8_lossy(&out.stdout)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().expect("qemu output");
    QemuRun {
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        success: out.status.success(),
    }
}

/// Disassembles `elf` with `arm-none-eabi-objdump -d`.
pub fn disassemble(elf: &Path) -> String {
    let out = Command::new("arm-none-eabi-objdump")
        .arg("-d")
        .arg(elf)
        .output()
        .expect("arm-none-eabi-objdump not found: run `apt-get install -y binutils-arm-none-eabi` (or `bash .ci/setup`)");
    assert!(out.status.success());
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Section sizes of `elf` as (name, size in bytes, address), from `arm-none-eabi-size -A`.
pub fn section_sizes(elf: &Path) -> Vec<(String, u64, u64)> {
    let out = Command::new("arm-none-eabi-size")
        .arg("-A")
        .arg(elf)
        .output()
        .expect("arm-none-eabi-size not found: run `apt-get install -y binutils-arm-none-eabi`");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            let (name, size, addr) = (it.next()?, it.next()?, it.next()?);
            Some((name.to_string(), size.parse().ok()?, addr.parse().ok()?))
        })
        .collect()
}

/// Parses `a,b,c` into three numbers.
pub fn parse_triple(s: &str) -> [f64; 3] {
    let v: Vec<f64> = s.split(',').map(|x| x.parse().expect("number")).collect();
    [v[0], v[1], v[2]]
}
