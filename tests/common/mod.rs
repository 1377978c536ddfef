//! Helpers shared by the end-to-end tests: the `jetbench` binary in a test's
//! own bus namespace, scratch files, and running commands under a watchdog
//! (a hang fails the test; no test asserts a runtime).

// Each test binary uses a subset of these helpers.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// `jetbench` in the bus namespace `<suite><pid>`, so a test neither disturbs
/// nor sees a service set running on the same machine, finding the service
/// binaries next to itself.
pub fn jetbench(suite: &str) -> Command {
    let exe = Path::new(env!("CARGO_BIN_EXE_jetbench"));
    let mut command = Command::new(exe);
    command.env(jetbench_bus::NAMESPACE_ENV, format!("{suite}{}", std::process::id()));
    if let Some(dir) = exe.parent() {
        command.env("JETBENCH_BIN_DIR", dir);
    }
    command
}

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("services/ has a parent").to_path_buf()
}

/// A fresh path `name` in the suite's scratch folder (any old file removed).
pub fn scratch(suite: &str, name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(suite);
    std::fs::create_dir_all(&dir).expect("create scratch dir");
    let path = dir.join(name);
    let _ = std::fs::remove_file(&path);
    path
}

/// Waits for a child, killing it if it outlives `limit` (a hang, not a slow run).
pub fn wait_with_watchdog(child: &mut Child, limit: Duration, what: &str) -> ExitStatus {
    let deadline = Instant::now() + limit;
    loop {
        if let Some(status) = child.try_wait().expect("try_wait") {
            return status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} hung for {limit:?} and was killed");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A child's output lines, as they come, on a thread.
pub fn lines_of(stream: impl std::io::Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stream).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits until a line containing `text` arrives on `lines` (a child's output),
/// at most `limit`; the lines before it, for messages.
pub fn wait_for_line(lines: &mpsc::Receiver<String>, text: &str, limit: Duration) -> Result<Vec<String>, Vec<String>> {
    let deadline = Instant::now() + limit;
    let mut seen = Vec::new();
    while let Ok(line) = lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        let found = line.contains(text);
        seen.push(line);
        if found {
            return Ok(seen);
        }
    }
    Err(seen)
}

/// Runs a command to completion under the watchdog: status, stdout, stderr.
pub fn run(command: &mut Command, limit: Duration, what: &str) -> (ExitStatus, String, String) {
    let mut child =
        command.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start command");
    let stdout = lines_of(child.stdout.take().expect("stdout"));
    let stderr = lines_of(child.stderr.take().expect("stderr"));
    let status = wait_with_watchdog(&mut child, limit, what);
    // The reader threads end when the pipes close; a grandchild that keeps a
    // pipe open cannot hold the test longer than a few seconds.
    let deadline = Instant::now() + Duration::from_secs(10);
    let text = |rx: mpsc::Receiver<String>| {
        let mut lines = Vec::new();
        while let Ok(line) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            lines.push(line);
        }
        lines.join("\n")
    };
    (status, text(stdout), text(stderr))
}

/// Runs `jetbench ARGS` in the suite's namespace to completion under the
/// watchdog: exit code (-1 if killed by a signal), stdout, stderr.
pub fn run_jetbench(suite: &str, args: &[&str], limit: Duration) -> (i32, String, String) {
    let (status, out, err) = run(jetbench(suite).args(args), limit, &format!("jetbench {args:?}"));
    (status.code().unwrap_or(-1), out, err)
}

/// The path of the venv python with the reference MCAP reader.
pub fn python() -> PathBuf {
    let out = Command::new(repo_root().join("scripts/pyenv.sh")).output().expect("run scripts/pyenv.sh");
    assert!(out.status.success(), "scripts/pyenv.sh failed:\n{}", String::from_utf8_lossy(&out.stderr));
    PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
}

/// Starts `command up --sim --quiet --duration SECONDS --record RECORD` with its
/// stdout and stderr read line by line on threads: the child and both streams.
pub fn spawn_up(
    command: Command,
    duration_s: u32,
    record: &Path,
) -> (Child, mpsc::Receiver<String>, mpsc::Receiver<String>) {
    spawn_up_with(command, duration_s, record, &[])
}

/// [`spawn_up`] with more arguments for `jetbench up` (e.g. `--foxglove ADDR`).
pub fn spawn_up_with(
    mut command: Command,
    duration_s: u32,
    record: &Path,
    extra: &[&str],
) -> (Child, mpsc::Receiver<String>, mpsc::Receiver<String>) {
    command.args(["up", "--sim", "--quiet", "--duration", &duration_s.to_string(), "--record"]).arg(record).args(extra);
    spawn_reading(command)
}

/// Starts `command` with its stdout and stderr read line by line on threads.
pub fn spawn_reading(mut command: Command) -> (Child, mpsc::Receiver<String>, mpsc::Receiver<String>) {
    let mut child = command.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("start jetbench");
    let stdout = lines_of(child.stdout.take().expect("stdout"));
    let stderr = lines_of(child.stderr.take().expect("stderr"));
    (child, stdout, stderr)
}
