//! Background load for `jetbench latency`: stress-ng where installed, else a
//! built-in generator (`jetbench latency-load`) with the same three kinds of
//! pressure: CPU hogs, memory traffic, file I/O.
//!
//! The load runs at the normal scheduler priority, like the rest of a bench
//! PC's work; it is what the real-time settings have to win against.

use std::hint::black_box;
use std::io::{Seek, SeekFrom, Write};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// What `--load` asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum LoadKind {
    /// No load: the idle machine.
    None,
    /// Every core busy with computation.
    Cpu,
    /// Computation, memory traffic and file I/O at once.
    All,
}

impl LoadKind {
    /// Every kind with its name and what it does, for `--help`.
    pub const ALL: [(LoadKind, &'static str, &'static str); 3] = [
        (LoadKind::None, "none", "no load: the idle machine"),
        (LoadKind::Cpu, "cpu", "every core busy with computation"),
        (LoadKind::All, "all", "computation, memory traffic and file I/O at once"),
    ];

    /// Its name on the command line (`--load none|cpu|all`).
    pub fn name(self) -> &'static str {
        Self::ALL.iter().find(|(k, ..)| *k == self).map_or("none", |(_, name, _)| name)
    }
}

impl std::str::FromStr for LoadKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .iter()
            .find(|(_, name, _)| *name == s)
            .map(|(k, ..)| *k)
            .ok_or_else(|| format!("unknown load {s:?}: none, cpu or all"))
    }
}

/// Why a load could not run.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// The load's processes (stress-ng or `jetbench latency-load`) did not start.
    #[error("cannot start the load `{description}`: {source}")]
    Start {
        /// The command line of the load.
        description: String,
        /// The system's reason.
        source: std::io::Error,
    },
    /// The built-in load's file-I/O part could not create its scratch file.
    #[error("the built-in load cannot create {path}: {source}")]
    TempFile {
        /// The scratch file.
        path: std::path::PathBuf,
        /// The system's reason.
        source: std::io::Error,
    },
}

/// A running load; stopped when dropped.
pub struct Load {
    child: Option<Child>,
    /// What runs, e.g. `stress-ng --cpu 2`.
    pub description: String,
}

fn stress_ng_installed() -> bool {
    Command::new("stress-ng")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

impl Load {
    /// Starts `kind` on every core; `exe` is the jetbench binary, whose
    /// hidden `latency-load` command runs [`run_builtin`].
    pub fn start(kind: LoadKind, exe: &Path) -> Result<Load, LoadError> {
        let cpus = jetbench_stack::runtime::rt::online_cpus().to_string();
        let (program, args): (String, Vec<String>) = match kind {
            LoadKind::None => return Ok(Load { child: None, description: "none".into() }),
            _ if stress_ng_installed() => {
                let mut args = vec!["--cpu".to_string(), cpus.clone()];
                if kind == LoadKind::All {
                    args.extend(
                        ["--vm", "1", "--vm-bytes", "256M", "--hdd", "1", "--hdd-bytes", "128M"].map(String::from),
                    );
                }
                ("stress-ng".into(), args)
            }
            _ => {
                let mut args = vec!["latency-load".to_string(), "--cpu".into(), cpus.clone()];
                if kind == LoadKind::All {
                    args.extend(["--vm", "1", "--io", "1"].map(String::from));
                }
                (exe.display().to_string(), args)
            }
        };
        let description = format!(
            "{} {}",
            Path::new(&program).file_name().map_or(program.clone(), |n| n.to_string_lossy().into()),
            args.join(" ")
        );
        // Own process group, so stopping it reaches stress-ng's workers too; its
        // temporary files go to the system's temporary folder.
        let child = Command::new(&program)
            .args(&args)
            .current_dir(std::env::temp_dir())
            .process_group(0)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|source| LoadError::Start { description: description.clone(), source })?;
        Ok(Load { child: Some(child), description })
    }

    /// True while the load runs (`--load none`: always).
    pub fn running(&mut self) -> bool {
        match &mut self.child {
            Some(child) => matches!(child.try_wait(), Ok(None)),
            None => true,
        }
    }
}

impl Drop for Load {
    fn drop(&mut self) {
        let Some(mut child) = self.child.take() else { return };
        let group = child.id() as i32;
        // SAFETY: signals a process group this process created.
        unsafe { libc::kill(-group, libc::SIGTERM) };
        for _ in 0..50 {
            if matches!(child.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        // SAFETY: as above.
        unsafe { libc::kill(-group, libc::SIGKILL) };
        let _ = child.wait();
    }
}

/// What the built-in generator runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BuiltinLoad {
    /// Threads that compute without pause.
    pub cpu: usize,
    /// Threads that stream through 128 MiB of memory each.
    pub vm: usize,
    /// Threads that write and sync a 64 MiB file each.
    pub io: usize,
}

/// Runs the built-in load until `stop()` says so (SIGINT/SIGTERM in `jetbench latency-load`).
pub fn run_builtin(load: BuiltinLoad, stop: fn() -> bool) -> Result<(), LoadError> {
    let BuiltinLoad { cpu, vm, io } = load;
    let mut threads = Vec::new();
    for _ in 0..cpu {
        threads.push(std::thread::spawn(move || {
            let mut x = 1.000_000_1_f64;
            while !stop() {
                for _ in 0..1_000_000 {
                    x = black_box(x * 1.000_000_1 + 1e-9).fract() + 1.0;
                }
            }
            black_box(x);
        }));
    }
    for _ in 0..vm {
        threads.push(std::thread::spawn(move || {
            let mut a = vec![1u8; 64 << 20];
            let mut b = vec![0u8; 64 << 20];
            while !stop() {
                b.copy_from_slice(&a);
                std::mem::swap(&mut a, &mut b);
                black_box(&a);
            }
        }));
    }
    for i in 0..io {
        let path = std::env::temp_dir().join(format!("jetbench-load-{}-{i}", std::process::id()));
        let mut file =
            std::fs::File::create(&path).map_err(|source| LoadError::TempFile { path: path.clone(), source })?;
        threads.push(std::thread::spawn(move || {
            let block = vec![0x5au8; 1 << 20];
            let mut written = 0usize;
            while !stop() {
                if file.write_all(&block).is_err() {
                    break;
                }
                written += block.len();
                if written.is_multiple_of(16 << 20) {
                    let _ = file.sync_data();
                }
                if written >= 64 << 20 {
                    written = 0;
                    let _ = file.seek(SeekFrom::Start(0));
                }
            }
            drop(file);
            let _ = std::fs::remove_file(&path);
        }));
    }
    for t in threads {
        let _ = t.join();
    }
    Ok(())
}
