//! A service set started by `jetbench up`, watched line by line; a second set
//! in its namespace; and who may read its files.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use jetbench_stack::runtime::supervise::describe_task;

use crate::{Bench, FaultsError};

/// How long a set may take to report every service ready.
const READY_LIMIT: Duration = Duration::from_secs(60);

/// One line the launcher (or one of its services) printed, and when it came.
#[derive(Clone, Debug)]
pub struct Line {
    /// The line, without its end.
    pub text: String,
    /// When it was read.
    pub at: Instant,
    /// `CLOCK_MONOTONIC` when it was read, ns: the clock of the samples' stamps.
    pub mono_ns: u64,
}

/// A running `jetbench up --sim --quiet ...`.
pub struct RunningSet {
    child: Child,
    lines: mpsc::Receiver<Line>,
    log: Vec<Line>,
    /// Service name -> pid, as the launcher printed them.
    pids: BTreeMap<String, u32>,
    /// The bus namespace the set runs in (`JETBENCH_BUS`).
    pub namespace: String,
}

impl RunningSet {
    /// Starts `jetbench up --sim --quiet ARGS` in `namespace` and waits until
    /// every service is ready.
    pub fn start(bench: &Bench, namespace: &str, args: &[&str]) -> Result<RunningSet, FaultsError> {
        let mut command = bench.command(namespace);
        command.args(["up", "--sim", "--quiet"]).args(args);
        let mut set = Self::spawn(&mut command, namespace)?;
        let deadline = Instant::now() + READY_LIMIT;
        loop {
            let Some(line) = set.next_line(deadline) else {
                let _ = set.child.kill();
                let status = set.child.wait().ok();
                return Err(FaultsError::Failed {
                    what: format!("jetbench up {}", args.join(" ")),
                    message: format!("never became ready ({status:?}):\n{}", set.log()),
                });
            };
            if let Some((name, pid)) = parse_started(&line.text) {
                set.pids.insert(name, pid);
            }
            if line.text.starts_with("all ") && line.text.contains("services ready") {
                return Ok(set);
            }
        }
    }

    /// Starts any `jetbench` command (`hz`, `echo`, ...) and reads its lines as they come.
    pub fn watch(command: &mut Command) -> Result<RunningSet, FaultsError> {
        Self::spawn(command, "")
    }

    fn spawn(command: &mut Command, namespace: &str) -> Result<RunningSet, FaultsError> {
        let mut child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|source| FaultsError::Start { what: "jetbench up".into(), source })?;
        let (tx, lines) = mpsc::channel();
        let stdout = child.stdout.take().map(|s| Box::new(s) as Box<dyn std::io::Read + Send>);
        let stderr = child.stderr.take().map(|s| Box::new(s) as Box<dyn std::io::Read + Send>);
        for stream in [stdout, stderr].into_iter().flatten() {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for text in BufReader::new(stream).lines().map_while(Result::ok) {
                    let line = Line { text, at: Instant::now(), mono_ns: jetbench_record::clock::monotonic_ns() };
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
        }
        Ok(RunningSet { child, lines, log: Vec::new(), pids: BTreeMap::new(), namespace: namespace.into() })
    }

    /// The next line, waiting until `deadline`.
    pub fn next_line(&mut self, deadline: Instant) -> Option<Line> {
        let line = self.lines.recv_timeout(deadline.saturating_duration_since(Instant::now())).ok()?;
        self.log.push(line.clone());
        Some(line)
    }

    /// Reads lines until one contains `needle` or `deadline` passes.
    pub fn wait_for(&mut self, needle: &str, deadline: Instant) -> Option<Line> {
        if let Some(line) = self.log.iter().find(|l| l.text.contains(needle)) {
            return Some(line.clone());
        }
        while let Some(line) = self.next_line(deadline) {
            if line.text.contains(needle) {
                return Some(line);
            }
        }
        None
    }

    /// The pid of service `name` (`sim-bench`, `control`, ...).
    pub fn pid(&self, name: &str) -> Option<u32> {
        self.pids.get(name).copied()
    }

    /// Every service's pid.
    pub fn service_pids(&self) -> Vec<(String, u32)> {
        self.pids.iter().map(|(n, p)| (n.clone(), *p)).collect()
    }

    /// The pid of the launcher, `jetbench up` itself.
    pub fn launcher_pid(&self) -> u32 {
        self.child.id()
    }

    /// Waits for the launcher to exit, killing it after `limit` (a hang); then
    /// reads what is left of its output.
    pub fn wait_exit(&mut self, limit: Duration) -> Result<(ExitStatus, Instant), FaultsError> {
        let deadline = Instant::now() + limit;
        let status = loop {
            if let Some(status) =
                self.child.try_wait().map_err(|source| FaultsError::Start { what: "wait".into(), source })?
            {
                break status;
            }
            if Instant::now() > deadline {
                let processes = self.snapshot();
                let _ = self.child.kill();
                let _ = self.child.wait();
                self.kill_services();
                return Err(FaultsError::Hang { what: "jetbench up".into(), limit, processes });
            }
            // Keep the pipes drained meanwhile.
            while let Ok(line) = self.lines.try_recv() {
                self.log.push(line);
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        let exited = Instant::now();
        // The reader threads end when the pipes close (a service that outlives
        // the launcher holds them open a little longer).
        let drain_until = exited + Duration::from_secs(3);
        while self.next_line(drain_until).is_some() {}
        Ok((status, exited))
    }

    /// Asks the process to stop (SIGTERM) and waits for it.
    pub fn stop(&mut self) -> Result<(ExitStatus, Instant), FaultsError> {
        // SAFETY: SIGTERM to our own child.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        self.wait_exit(Duration::from_secs(30))
    }

    /// The lines printed so far that contain `needle`.
    pub fn lines_matching(&self, needle: &str) -> Vec<Line> {
        self.log.iter().filter(|l| l.text.contains(needle)).cloned().collect()
    }

    /// Everything printed so far, one line each.
    pub fn log(&self) -> String {
        self.log.iter().map(|l| l.text.as_str()).collect::<Vec<_>>().join("\n")
    }
}

impl Drop for RunningSet {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            // SAFETY: SIGTERM to our own child: it stops its set safely.
            unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
            let deadline = Instant::now() + Duration::from_secs(20);
            while matches!(self.child.try_wait(), Ok(None)) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        self.kill_services();
    }
}

/// How long the services of a set whose launcher is gone get to stop on
/// their own (its parent-death signal) before they are killed.
const ORPHAN_GRACE: Duration = Duration::from_secs(10);

impl RunningSet {
    /// The launcher and every service it reported, thread by thread: state,
    /// scheduling, CPU time and where the kernel has it waiting. What a hang
    /// report needs to name the process that held the set up.
    pub fn snapshot(&self) -> String {
        let mut out = String::new();
        let launcher = ("launcher".to_string(), self.child.id());
        for (name, pid) in std::iter::once(launcher).chain(self.service_pids()) {
            out.push_str(&format!("\n  {name} (pid {pid}):"));
            let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
                out.push_str(" gone");
                continue;
            };
            for task in tasks.flatten() {
                out.push_str(&format!("\n    {}", describe_task(&task.path())));
            }
        }
        out
    }

    /// SIGKILLs the services still running once the launcher is gone, after
    /// [`ORPHAN_GRACE`] to stop on their own: a set that would not stop must
    /// not hold its namespace (and the machine) for the experiments after it.
    fn kill_services(&mut self) {
        let deadline = Instant::now() + ORPHAN_GRACE;
        let ours = |pid: u32| {
            // A pid the system gave to another program since is not ours, nor
            // is a service that has exited (a zombie until it is reaped).
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            stat.contains("(jetbench") && stat.rsplit_once(") ").is_some_and(|(_, rest)| !rest.starts_with('Z'))
        };
        let pids: Vec<u32> = self.pids.values().copied().collect();
        while pids.iter().any(|&p| ours(p)) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(50));
        }
        for pid in pids.into_iter().filter(|&p| ours(p)) {
            // SAFETY: kill(2) on a service of the set this value started.
            unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
        }
    }
}

fn parse_started(line: &str) -> Option<(String, u32)> {
    let rest = line.strip_prefix("started ")?;
    let (name, pid) = rest.split_once(" (pid ")?;
    Some((name.to_string(), pid.strip_suffix(')')?.parse().ok()?))
}

/// Sends SIGKILL to `pid`; returns `CLOCK_REALTIME` just before, ns.
pub fn kill_now(pid: u32) -> u64 {
    let at = jetbench_record::clock::realtime_ns();
    // SAFETY: kill(2) on a pid a launcher we started reported (or itself).
    unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
    at
}

/// True while `pid` runs (a zombie does not).
pub fn alive(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // The state follows the command name in parentheses.
        Ok(stat) => stat.rsplit_once(')').is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z')),
        Err(_) => false,
    }
}

/// Waits until none of `pids` runs, or `limit` passes; returns those still running.
pub fn wait_gone(pids: &[u32], limit: Duration) -> Vec<u32> {
    let deadline = Instant::now() + limit;
    loop {
        let left: Vec<u32> = pids.iter().copied().filter(|&p| alive(p)).collect();
        if left.is_empty() || Instant::now() >= deadline {
            return left;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A second `jetbench up` in a namespace that is in use.
#[derive(Clone, Debug)]
pub struct SecondUp {
    /// Exit status of the second launcher (`None`: killed by a signal).
    pub status: Option<i32>,
    /// It said which set holds the namespace, with that set's pid.
    pub names_the_first: bool,
    /// The second launcher's line saying the namespace is in use.
    pub message: String,
    /// A set in another namespace ran beside the first meanwhile.
    pub side_by_side: bool,
}

/// Starts a set, then a second `up` in its namespace (refused, naming the
/// first) and one in another namespace (runs beside it).
pub fn second_up(bench: &Bench) -> Result<SecondUp, FaultsError> {
    let namespace = bench.fresh_namespace();
    let first = RunningSet::start(bench, &namespace, &["--duration", "30"])?;
    let second =
        run_to_end(bench.command(&namespace).args(["up", "--sim", "--quiet", "--duration", "2"]), "second up")?;
    let other = run_to_end(
        bench.command(&bench.fresh_namespace()).args(["up", "--sim", "--quiet", "--duration", "2"]),
        "up in another namespace",
    )?;
    let message = second.1.lines().find(|l| l.contains("in use")).unwrap_or_default().to_string();
    let names_the_first = message.contains(&format!("pid {}", first.launcher_pid()));
    drop(first);
    Ok(SecondUp { status: second.0.code(), names_the_first, message, side_by_side: other.0.success() })
}

/// Runs a command to its end under a watchdog: status and everything it printed.
pub fn run_to_end(command: &mut Command, what: &str) -> Result<(ExitStatus, String), FaultsError> {
    let mut set = RunningSet::spawn(command, "")?;
    let (status, _) = set.wait_exit(Duration::from_secs(120)).map_err(|e| match e {
        FaultsError::Hang { limit, processes, .. } => FaultsError::Hang { what: what.into(), limit, processes },
        e => e,
    })?;
    Ok((status, set.log()))
}

/// Who may touch a running set's files: what another user could do to them.
#[derive(Clone, Debug, Default)]
pub struct Access {
    /// Files and sockets of the set tried (shared memory, doorbells, sockets, the lock).
    pub tried: usize,
    /// Those another user could open for reading or writing (should be none).
    pub open_to_others: Vec<String>,
    /// `jetbench echo` as another user: its exit status and what it said.
    pub echo_status: Option<i32>,
    /// What that `jetbench echo` printed (its error).
    pub echo_said: String,
    /// Files whose mode gives anything to group or others.
    pub loose_modes: Vec<String>,
}

/// The files of namespace `namespace`: iceoryx2's shared memory and its
/// folders' files, the doorbells, the lock, the sockets and their folders.
fn files_of(namespace: &str) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mine = |name: &str| {
        name.starts_with(&format!("jb_{namespace}_")) || name.starts_with(&format!("jetbench.{namespace}."))
    };
    let list =
        |dir: &Path| std::fs::read_dir(dir).into_iter().flatten().flatten().map(|e| e.path()).collect::<Vec<_>>();
    files.extend(
        list(Path::new("/dev/shm")).into_iter().filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(mine)),
    );
    let tmp = std::env::temp_dir();
    for dir in [tmp.join("jetbench-can").join(namespace).join("simcan0"), tmp.join(format!("jetbench-sim-{namespace}"))]
    {
        files.push(dir.clone());
        files.extend(list(&dir));
    }
    files
}

/// Starts a set as this user (root here) and tries, as the unprivileged user
/// `nobody` (uid 65534, through `setpriv`), to read and write each of its
/// files and sockets and to watch a channel with `jetbench echo`.
pub fn access_as_another_user(bench: &Bench) -> Result<Access, FaultsError> {
    let namespace = bench.fresh_namespace();
    let set = RunningSet::start(bench, &namespace, &["--duration", "30"])?;
    let as_nobody = |args: &[&str]| {
        let mut command = Command::new("setpriv");
        command.args(["--reuid=65534", "--regid=65534", "--clear-groups", "--"]).args(args);
        command
    };
    let mut access = Access::default();
    for path in files_of(&namespace) {
        let Ok(meta) = std::fs::symlink_metadata(&path) else { continue };
        if meta.file_type().is_symlink() {
            continue;
        }
        access.tried += 1;
        let mode = std::os::unix::fs::PermissionsExt::mode(&meta.permissions());
        if mode & 0o077 != 0 {
            access.loose_modes.push(format!("{} {:o}", path.display(), mode & 0o777));
        }
        let p = path.display().to_string();
        let (read_from, write_to) = (format!("if={p}"), format!("of={p}"));
        // A socket is written by sending to it; a folder read by listing it.
        let probes: Vec<Vec<&str>> = if meta.file_type().is_dir() {
            vec![vec!["ls", &p]]
        } else if std::os::unix::fs::FileTypeExt::is_socket(&meta.file_type()) {
            vec![vec![
                "python3",
                "-c",
                "import socket,sys; s=socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM); s.sendto(b'x', sys.argv[1])",
                &p,
            ]]
        } else {
            vec![
                vec!["dd", "status=none", "count=1", &read_from, "of=/dev/null"],
                vec!["dd", "status=none", "count=0", "conv=notrunc", "if=/dev/null", &write_to],
            ]
        };
        for probe in probes {
            let done = as_nobody(&probe).stdout(Stdio::null()).stderr(Stdio::null()).status();
            if done.is_ok_and(|s| s.success()) {
                access.open_to_others.push(format!("{}: `{}` succeeded", path.display(), probe[0]));
            }
        }
    }
    let exe = bench.exe.display().to_string();
    let mut echo = as_nobody(&[&exe, "echo", "bench/thrust", "-n", "1"]);
    echo.env("JETBENCH_BUS", &namespace);
    let (status, said) = run_to_end(&mut echo, "jetbench echo as another user")?;
    access.echo_status = status.code();
    access.echo_said = said.lines().last().unwrap_or_default().to_string();
    drop(set);
    Ok(access)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hang_report_names_each_thread_its_state_and_where_it_waits() {
        let mut sleeper = Command::new("sleep");
        sleeper.arg("30");
        let mut set = RunningSet::watch(&mut sleeper).expect("sleep starts");
        // Until the kernel has it asleep.
        let deadline = Instant::now() + Duration::from_secs(10);
        let mut report = set.snapshot();
        while !report.contains("state S") && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
            report = set.snapshot();
        }
        assert!(report.starts_with(&format!("\n  launcher (pid {}):", set.launcher_pid())), "{report}");
        assert!(report.contains("\n    sleep: state S, normal, cpu "), "{report}");
        assert!(report.contains("waiting in ") && report.contains("sleep"), "{report}");
        let _ = set.child.kill();
        let _ = set.child.wait();
        let after = set.snapshot();
        assert!(after.ends_with(" gone"), "a reaped process is said to be gone: {after}");
    }
}
