//! The recorder's faults: killed mid-run, and its disk filling up.
//!
//! - [`recorder_crash`]: SIGKILL of the recorder; how much of the time before
//!   the kill is missing from its file (the last flushed chunk to the kill),
//!   `jetbench recover` on it (exit status, and Python's `mcap` reading the
//!   result), and every offline command reading the truncated file directly.
//! - [`disk_full`]: a recording on a small tmpfs that fills: the recorder's
//!   message, the control loop's rate meanwhile (the commands `jetbench echo`
//!   sees from outside), the safe stop or the run going on (`[recorder] on_error`),
//!   and what `jetbench recover` makes of the file.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use jetbench_record::Recording;
use jetbench_stack::config::OnRecordError;

use crate::set::{kill_now, run_to_end, RunningSet};
use crate::{Bench, FaultsError};

/// An offline command run on a truncated recording.
#[derive(Clone, Debug)]
pub struct TruncatedRead {
    /// The command, e.g. `jetbench info crashed.mcap`.
    pub command: String,
    /// Its exit status (`None`: killed by a signal, e.g. a crash).
    pub status: Option<i32>,
    /// It said the file is truncated.
    pub warned: bool,
}

/// A recorder killed mid-run.
#[derive(Clone, Debug)]
pub struct RecorderCrash {
    /// s after the set was ready.
    pub at_s: f64,
    /// From the newest message in the file to the kill, s: the data lost.
    pub lost_s: f64,
    /// Messages in the truncated file.
    pub messages: usize,
    /// `jetbench recover`'s exit status: 0 nothing lost, 3 data lost.
    pub recover_status: Option<i32>,
    /// Messages in the recovered file.
    pub recovered: usize,
    /// What Python's `mcap` reader made of the recovered file: messages and chunk indexes.
    pub python: Option<Result<(usize, usize), String>>,
    /// The offline commands run on the truncated file, and what each did.
    pub readers: Vec<TruncatedRead>,
    /// Every bound this crash broke, in words (empty: all held).
    pub problems: Vec<String>,
}

/// Most of the time before a recorder's death its file may lack, s (the bound).
pub const MAX_LOSS_S: f64 = 1.0;

/// Kills the recorder `at_s` seconds into a run and measures what is lost and
/// what recovers; `readers` also runs `info`, `replay`, `metrics`, `identify`
/// and `diagnose` on the truncated file.
pub fn recorder_crash(bench: &Bench, at_s: f64, readers: bool) -> Result<RecorderCrash, FaultsError> {
    let namespace = bench.fresh_namespace();
    let record = bench.scratch(&format!("crash-{namespace}.mcap"));
    let record_arg = record.display().to_string();
    let mut set = RunningSet::start(bench, &namespace, &["--duration", "120", "--record", &record_arg])?;
    std::thread::sleep(Duration::from_secs_f64(at_s));
    let pid = set.pid("recorder").ok_or_else(|| FaultsError::Failed {
        what: "jetbench up".into(),
        message: "did not print the recorder's pid".into(),
    })?;
    let kill_ns = kill_now(pid);
    set.wait_exit(Duration::from_secs(60))?;
    let truncated = Recording::open(&record)?;
    let newest_ns = truncated.messages.iter().map(|m| m.log_time_ns).max().unwrap_or(0);
    let mut crash = RecorderCrash {
        at_s,
        lost_s: kill_ns.saturating_sub(newest_ns) as f64 * 1e-9,
        messages: truncated.messages.len(),
        recover_status: None,
        recovered: 0,
        python: None,
        readers: Vec::new(),
        problems: Vec::new(),
    };
    if !truncated.truncated {
        crash.problems.push("the file of a killed recorder is not flagged truncated".into());
    }
    if crash.lost_s > MAX_LOSS_S {
        crash.problems.push(format!("{:.3} s of data before the kill are missing", crash.lost_s));
    }
    let fixed = bench.scratch(&format!("crash-{namespace}-recovered.mcap"));
    (crash.recover_status, crash.recovered) = recover(bench, &namespace, &record, &fixed)?;
    if !matches!(crash.recover_status, Some(0 | 3)) || crash.recovered < crash.messages {
        crash.problems.push(format!(
            "jetbench recover exited {:?} with {} of {} messages",
            crash.recover_status, crash.recovered, crash.messages
        ));
    }
    if let Some(python) = &bench.python {
        let read = python_read(python, &fixed);
        if !read.as_ref().is_ok_and(|&(n, chunks)| n == crash.recovered && chunks > 0) {
            crash.problems.push(format!("Python's mcap reader: {read:?}"));
        }
        crash.python = Some(read);
    }
    if readers {
        let path = record.display().to_string();
        for args in [
            vec!["info", &path],
            vec!["replay", &path],
            vec!["metrics", &path],
            vec!["identify", &path],
            vec!["diagnose", "--model", "p100-diesel", &path],
        ] {
            let (status, said) = run_to_end(bench.command(&namespace).args(&args), args[0])?;
            let read = TruncatedRead {
                command: format!("jetbench {}", args[0]),
                status: status.code(),
                warned: said.contains("truncated"),
            };
            if read.status != Some(0) || !read.warned {
                crash.problems.push(format!("{} on the truncated file: {:?}\n{said}", read.command, read.status));
            }
            crash.readers.push(read);
        }
    }
    Ok(crash)
}

/// `jetbench recover IN --out OUT`: its exit status, and the messages in OUT.
fn recover(bench: &Bench, namespace: &str, input: &Path, output: &Path) -> Result<(Option<i32>, usize), FaultsError> {
    let (status, _) =
        run_to_end(bench.command(namespace).arg("recover").arg(input).arg("--out").arg(output), "jetbench recover")?;
    let messages = Recording::open(output).map(|r| if r.truncated { 0 } else { r.messages.len() }).unwrap_or(0);
    Ok((status.code(), messages))
}

/// Messages and chunk indexes of an MCAP file as Python's `mcap` reads them.
pub fn python_read(python: &Path, path: &Path) -> Result<(usize, usize), String> {
    const READ: &str = "import sys\nfrom mcap.reader import make_reader\n\
        r = make_reader(open(sys.argv[1], 'rb'))\ns = r.get_summary()\n\
        print(sum(1 for _ in r.iter_messages()), len(s.chunk_indexes) if s else 0)";
    let out = Command::new(python).args(["-c", READ]).arg(path).output().map_err(|e| e.to_string())?;
    let text = String::from_utf8_lossy(&out.stdout);
    let mut numbers = text.split_whitespace().filter_map(|n| n.parse().ok());
    match (out.status.success(), numbers.next(), numbers.next()) {
        (true, Some(messages), Some(chunks)) => Ok((messages, chunks)),
        _ => Err(String::from_utf8_lossy(&out.stderr).trim().to_string()),
    }
}

/// A run whose recording's disk filled.
#[derive(Clone, Debug)]
pub struct DiskFull {
    /// The recorder's `[recorder] on_error` setting in this run.
    pub on_error: OnRecordError,
    /// Size of the tmpfs the recording went to, KiB.
    pub disk_kib: u64,
    /// From ready to the recorder's message, s.
    pub full_after_s: Option<f64>,
    /// The recorder's message.
    pub said: String,
    /// From the message to the launcher's exit, ms (`stop`: the safe stop).
    pub stopped_after_ms: Option<f64>,
    /// The launcher's exit status (`None`: killed by a signal).
    pub exit_status: Option<i32>,
    /// Commands published from the recorder's message to the last one (the
    /// safe stop, or the end of the run), as `jetbench echo bench/command` saw
    /// them from outside: their number, their rate (Hz) and the longest
    /// interval between two (ms), on their own `publish_ns`.
    pub commands_after_full: usize,
    /// Their rate, Hz (100 while the loop runs on).
    pub rate_after_full_hz: f64,
    /// The longest interval between two of them, ms.
    pub max_interval_after_full_ms: f64,
    /// Actuation disarmed the board, acknowledged.
    pub disarmed: bool,
    /// `jetbench recover`'s exit status on the file (0: nothing lost).
    pub recover_status: Option<i32>,
    /// Messages in the recovered file.
    pub recovered: usize,
    /// Every bound this run broke, in words (empty: all held).
    pub problems: Vec<String>,
}

/// The lowest acceptable loop rate, Hz (100 Hz less jitter).
pub const MIN_RATE_HZ: f64 = 90.0;
/// The longest acceptable interval between two commands, ms: ten periods.
///
/// A loop held up by the recorder would stop for the rest of the run, not for a
/// period; what this bound must pass is the host stealing a core of a two-core
/// VM for tens of ms (27 ms once, in a full suite run, where 25 ms was the bound).
/// The rate bound above watches the loop's pace.
pub const MAX_INTERVAL_MS: f64 = 100.0;

/// Records onto a tmpfs of `disk_kib` KiB (mounted here: this needs root) until it is full.
pub fn disk_full(bench: &Bench, on_error: OnRecordError, disk_kib: u64) -> Result<DiskFull, FaultsError> {
    let namespace = bench.fresh_namespace();
    let disk = Tmpfs::mount(&bench.scratch_dir().join(format!("disk-{namespace}")), disk_kib)?;
    let record = disk.path.join("run.mcap").display().to_string();
    let config = bench.scratch(&format!("disk-{namespace}.toml"));
    let text = jetbench_stack::config::DEFAULT_SIM_CONFIG.replace(
        "on_error = \"stop\"",
        if on_error == OnRecordError::Continue { "on_error = \"continue\"" } else { "on_error = \"stop\"" },
    );
    std::fs::write(&config, text).map_err(|source| FaultsError::Io { path: config.clone(), source })?;
    let config_arg = config.display().to_string();
    // With `stop` the run ends when the disk fills; with `continue` it runs on
    // for a few seconds of loop rate after that.
    let run_s: u32 = if on_error == OnRecordError::Continue { 12 } else { 60 };
    let mut set = RunningSet::start(
        bench,
        &namespace,
        &["--duration", &run_s.to_string(), "--record", &record, "--config", &config_arg],
    )?;
    let ready = Instant::now();
    let mut echo = RunningSet::watch(bench.command(&namespace).args(["echo", "bench/command"]))?;
    let message = set.wait_for(" is full (", ready + Duration::from_secs(u64::from(run_s)));
    let (status, exited) = set.wait_exit(Duration::from_secs(u64::from(run_s) + 60))?;
    echo.stop()?;
    let log = set.log();
    // The commands published after the message, on their own monotonic stamps.
    let full_ns = message.as_ref().map_or(u64::MAX, |m| m.mono_ns);
    let published: Vec<u64> = echo
        .lines_matching("publish_ns=")
        .iter()
        .filter_map(|l| l.text.split("publish_ns=").nth(1)?.split(',').next()?.trim().parse().ok())
        .filter(|&ns| ns >= full_ns)
        .collect();
    let span_s = match (published.first(), published.last()) {
        (Some(first), Some(last)) if last > first => (last - first) as f64 * 1e-9,
        _ => f64::NAN,
    };
    let mut result = DiskFull {
        on_error,
        disk_kib,
        full_after_s: message.as_ref().map(|m| (m.at - ready).as_secs_f64()),
        said: message.as_ref().map(|m| m.text.clone()).unwrap_or_default(),
        stopped_after_ms: message.as_ref().map(|m| (exited - m.at).as_secs_f64() * 1e3),
        exit_status: status.code(),
        commands_after_full: published.len(),
        rate_after_full_hz: published.len().saturating_sub(1) as f64 / span_s,
        max_interval_after_full_ms: published.windows(2).map(|w| (w[1] - w[0]) as f64 * 1e-6).fold(0.0, f64::max),
        disarmed: log.contains("throttle board disarmed (acknowledged)"),
        recover_status: None,
        recovered: 0,
        problems: Vec::new(),
    };
    let fixed = bench.scratch(&format!("disk-{namespace}-recovered.mcap"));
    (result.recover_status, result.recovered) = recover(bench, &namespace, Path::new(&record), &fixed)?;
    drop(disk);
    judge_disk_full(&mut result, &log);
    Ok(result)
}

fn judge_disk_full(r: &mut DiskFull, log: &str) {
    if r.full_after_s.is_none() {
        r.problems.push(format!("the recorder never said its disk is full:\n{log}"));
    }
    // NaN (no command seen after the disk filled) fails too: the rate was not seen.
    if r.rate_after_full_hz.is_nan()
        || r.rate_after_full_hz < MIN_RATE_HZ
        || r.max_interval_after_full_ms > MAX_INTERVAL_MS
    {
        r.problems.push(format!(
            "the loop after the disk filled: {} commands at {:.1} Hz, longest interval {:.1} ms",
            r.commands_after_full, r.rate_after_full_hz, r.max_interval_after_full_ms
        ));
    }
    if !matches!(r.recover_status, Some(0 | 3)) || r.recovered == 0 {
        r.problems
            .push(format!("what was written did not recover: exit {:?}, {} messages", r.recover_status, r.recovered));
    }
    match r.on_error {
        OnRecordError::Stop => {
            if r.exit_status == Some(0) {
                r.problems.push("jetbench up exited 0 after its recording failed".into());
            }
            if !log.contains("service `recorder` exited with status 1: the disk holding") {
                r.problems.push("the launcher did not name the full disk".into());
            }
            if !r.disarmed || !log.contains("disarmed at the end") {
                r.problems.push("the board was not disarmed".into());
            }
        }
        OnRecordError::Continue => {
            if r.exit_status != Some(0) || !log.contains("RECORDING STOPPED") {
                r.problems.push(format!("the run did not go on unrecorded: exit {:?}", r.exit_status));
            }
        }
    }
}

/// A tmpfs of a given size, unmounted (and its folder removed) when dropped.
struct Tmpfs {
    path: PathBuf,
}

impl Tmpfs {
    fn mount(path: &Path, kib: u64) -> Result<Tmpfs, FaultsError> {
        std::fs::create_dir_all(path).map_err(|source| FaultsError::Io { path: path.into(), source })?;
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={kib}k,mode=0700"), "tmpfs"])
            .arg(path)
            .output()
            .map_err(|source| FaultsError::Start { what: "mount".into(), source })?;
        if !out.status.success() {
            let _ = std::fs::remove_dir(path);
            return Err(FaultsError::Failed {
                what: format!("mount -t tmpfs (size {kib} KiB) on {}", path.display()),
                message: format!(
                    "{} (a small disk that fills needs root, or a user namespace that may mount)",
                    String::from_utf8_lossy(&out.stderr).trim()
                ),
            });
        }
        Ok(Tmpfs { path: path.into() })
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.path).status();
        let _ = std::fs::remove_dir(&self.path);
    }
}
