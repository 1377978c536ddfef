//! Child processes of a run: started, watched, and stopped in order.
//!
//! Both the launcher behind `jetbench up` (the service processes) and the
//! latency experiment's floor chain start their processes here. Each child
//! gets its own process group, so a Ctrl-C at the terminal reaches only the
//! parent, which then stops the children in the order it chooses; its stdout
//! is read line by line on a thread of its own and handed to the parent
//! ([`Supervisor::next_line`]), which speaks its protocol over it (`ready`, ...).
//!
//! ```no_run
//! use jetbench_stack::runtime::supervise::{Supervisor, StopOrder};
//! use std::process::Command;
//! use std::time::Duration;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let mut children = Supervisor::new();
//! let sleeper = children.spawn("sleeper", Command::new("sleep").arg("30"), Default::default())?;
//! if let Some((child, line)) = children.next_line(Duration::from_millis(100)) {
//!     println!("{}: {line}", children.name(child));
//! }
//! assert!(children.reap().is_none(), "still running");
//! let failure = children.stop(StopOrder::Together, Duration::from_secs(5));
//! assert!(failure.is_some_and(|(i, _)| i == sleeper), "SIGTERM ended it: not a clean exit");
//! # Ok(())
//! # }
//! ```

use std::io::{BufRead, BufReader};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Hands each line read from `pipe` to `tx` as child `index`'s, on a thread of its own.
fn forward_lines(pipe: impl std::io::Read + Send + 'static, index: usize, tx: mpsc::Sender<(usize, String)>) {
    std::thread::spawn(move || {
        for line in BufReader::new(pipe).lines().map_while(Result::ok) {
            if tx.send((index, line)).is_err() {
                break;
            }
        }
    });
}

/// How a child is started.
#[derive(Clone, Copy, Debug, Default)]
pub struct SpawnOptions {
    /// Give the parent a pipe to the child's stdin ([`Supervisor::stdin`]).
    pub stdin: bool,
    /// Signal the child receives when the parent dies (`PR_SET_PDEATHSIG`), so
    /// it cannot outlive the run; `None` leaves it running.
    pub parent_death_signal: Option<i32>,
    /// Read the child's stderr line by line too ([`Supervisor::try_err_line`])
    /// instead of letting it write to the parent's: the parent prints it where
    /// it belongs (above a live status line). Without it, stderr is inherited.
    pub stderr_lines: bool,
}

/// Why a child could not be started.
#[derive(Debug, thiserror::Error)]
#[error("cannot start {name}: {source}")]
pub struct SpawnError {
    /// The child's name.
    pub name: String,
    /// Why it did not start.
    #[source]
    pub source: std::io::Error,
}

/// In which order [`Supervisor::stop`] stops the children still running.
#[derive(Clone, Debug)]
pub enum StopOrder {
    /// One after the other in this order (indices), each given the whole
    /// timeout to exit before the next gets SIGTERM.
    InTurn(Vec<usize>),
    /// SIGTERM to all at once, then each reaped.
    Together,
}

struct Supervised {
    name: String,
    child: Child,
    stdin: Option<ChildStdin>,
    exited: Option<ExitStatus>,
}

/// The children of one run. Dropping it stops those still running.
pub struct Supervisor {
    children: Vec<Supervised>,
    lines_tx: mpsc::Sender<(usize, String)>,
    lines_rx: mpsc::Receiver<(usize, String)>,
    err_lines_tx: mpsc::Sender<(usize, String)>,
    err_lines_rx: mpsc::Receiver<(usize, String)>,
}

impl Default for Supervisor {
    fn default() -> Self {
        Self::new()
    }
}

impl Supervisor {
    /// No children yet.
    pub fn new() -> Self {
        let (lines_tx, lines_rx) = mpsc::channel();
        let (err_lines_tx, err_lines_rx) = mpsc::channel();
        Supervisor { children: Vec::new(), lines_tx, lines_rx, err_lines_tx, err_lines_rx }
    }

    /// Starts `command` as child `name` in its own process group, its stdout
    /// read line by line (stderr is inherited unless [`SpawnOptions::stderr_lines`]).
    /// Returns the child's index.
    pub fn spawn(
        &mut self,
        name: impl Into<String>,
        command: &mut Command,
        options: SpawnOptions,
    ) -> Result<usize, SpawnError> {
        let name = name.into();
        let stderr = if options.stderr_lines { Stdio::piped() } else { Stdio::inherit() };
        command.process_group(0).stdout(Stdio::piped()).stderr(stderr);
        command.stdin(if options.stdin { Stdio::piped() } else { Stdio::null() });
        if let Some(signal) = options.parent_death_signal {
            let parent = std::process::id() as libc::pid_t;
            // SAFETY: runs between fork and exec and calls only prctl and
            // getppid, which are async-signal-safe, on plain integers; it
            // allocates nothing (the error is built from a static string).
            unsafe {
                command.pre_exec(move || {
                    if libc::prctl(libc::PR_SET_PDEATHSIG, signal as libc::c_ulong) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    // The parent may have died between fork and prctl: then no
                    // signal will ever come, so do not start at all.
                    if libc::getppid() != parent {
                        return Err(std::io::Error::from(std::io::ErrorKind::BrokenPipe));
                    }
                    Ok(())
                });
            }
        }
        let mut child = command.spawn().map_err(|source| SpawnError { name: name.clone(), source })?;
        let index = self.children.len();
        if let Some(stdout) = child.stdout.take() {
            forward_lines(stdout, index, self.lines_tx.clone());
        }
        if let Some(stderr) = child.stderr.take() {
            forward_lines(stderr, index, self.err_lines_tx.clone());
        }
        let stdin = child.stdin.take();
        self.children.push(Supervised { name, child, stdin, exited: None });
        Ok(index)
    }

    /// The next line a child printed, waiting at most `timeout`.
    pub fn next_line(&self, timeout: Duration) -> Option<(usize, String)> {
        self.lines_rx.recv_timeout(timeout).ok()
    }

    /// A line a child printed, if one is waiting.
    pub fn try_line(&self) -> Option<(usize, String)> {
        self.lines_rx.try_recv().ok()
    }

    /// A line a child printed on stderr, if one is waiting (children spawned
    /// with [`SpawnOptions::stderr_lines`]).
    pub fn try_err_line(&self) -> Option<(usize, String)> {
        self.err_lines_rx.try_recv().ok()
    }

    /// Children started.
    pub fn len(&self) -> usize {
        self.children.len()
    }

    /// True before the first child is started.
    pub fn is_empty(&self) -> bool {
        self.children.is_empty()
    }

    /// The name of child `index`.
    pub fn name(&self, index: usize) -> &str {
        &self.children[index].name
    }

    /// The process id of child `index`.
    pub fn pid(&self, index: usize) -> u32 {
        self.children[index].child.id()
    }

    /// The pipe to a child's stdin (when spawned with [`SpawnOptions::stdin`]).
    pub fn stdin(&mut self, index: usize) -> Option<&mut ChildStdin> {
        self.children[index].stdin.as_mut()
    }

    /// How the child ended, if it has (as far as the last [`Supervisor::reap`] saw).
    pub fn exited(&self, index: usize) -> Option<ExitStatus> {
        self.children[index].exited
    }

    /// Looks at every running child; returns the first that has ended since
    /// the last look, with its exit status.
    pub fn reap(&mut self) -> Option<(usize, ExitStatus)> {
        for (i, s) in self.children.iter_mut().enumerate() {
            if s.exited.is_none() {
                if let Ok(Some(status)) = s.child.try_wait() {
                    s.exited = Some(status);
                    return Some((i, status));
                }
            }
        }
        None
    }

    /// Stops every child still running: SIGTERM, and SIGKILL for one that
    /// has not exited within `timeout`. Returns the first child that did not
    /// end cleanly, with how it ended.
    pub fn stop(&mut self, order: StopOrder, timeout: Duration) -> Option<(usize, String)> {
        let (order, in_turn) = match order {
            StopOrder::InTurn(order) => (order, true),
            StopOrder::Together => {
                for s in self.children.iter().filter(|s| s.exited.is_none()) {
                    signal(&s.child, libc::SIGTERM);
                }
                ((0..self.children.len()).collect(), false)
            }
        };
        let mut failure = None;
        for i in order {
            let Some(s) = self.children.get_mut(i) else { continue };
            s.stdin = None;
            if s.exited.is_some() {
                continue;
            }
            if in_turn {
                signal(&s.child, libc::SIGTERM);
            }
            let deadline = Instant::now() + timeout;
            let how = loop {
                match s.child.try_wait() {
                    Ok(Some(status)) => {
                        s.exited = Some(status);
                        break (!status.success()).then(|| describe_exit(status));
                    }
                    Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(5)),
                    _ => {
                        let _ = s.child.kill();
                        s.exited = reap_killed(&mut s.child);
                        break Some(match s.exited {
                            Some(_) => format!("did not stop within {timeout:?} and was killed"),
                            None => format!(
                                "did not stop within {timeout:?}, and was still there {KILL_WAIT:?} after SIGKILL \
                                 ({}); left behind",
                                describe_task(&std::path::Path::new("/proc").join(s.child.id().to_string()))
                            ),
                        });
                    }
                }
            };
            if let Some(how) = how {
                failure = failure.or(Some((i, how)));
            }
        }
        failure
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        if self.children.iter().any(|s| s.exited.is_none()) {
            let _ = self.stop(StopOrder::Together, Duration::from_secs(5));
        }
    }
}

/// The longest a stop waits for a SIGKILLed child to be gone. A process the
/// kernel cannot run (starved under a real-time policy, or in an
/// uninterruptible wait) cannot die either: the launcher says so and goes on
/// rather than hang with it.
const KILL_WAIT: Duration = Duration::from_secs(5);

/// Waits up to [`KILL_WAIT`] for a killed child; its status, or `None` if it is still there.
fn reap_killed(child: &mut Child) -> Option<ExitStatus> {
    let deadline = Instant::now() + KILL_WAIT;
    loop {
        match child.try_wait() {
            Ok(Some(status)) => return Some(status),
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(5)),
            _ => return None,
        }
    }
}

/// One line for a process or thread from its /proc folder (`/proc/PID` or
/// `/proc/PID/task/TID`): name, state, scheduling policy and real-time
/// priority, CPU time, and the kernel function it waits in, e.g.
/// `jetbench-actuat: state R, FIFO 80, cpu 3.12 s, waiting in running`.
pub fn describe_task(dir: &std::path::Path) -> String {
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap_or_default();
    task_line(&read("stat"), read("wchan").trim())
}

/// [`describe_task`] from the texts of its `stat` and `wchan` files.
fn task_line(stat: &str, wchan: &str) -> String {
    let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
        return "(unreadable)".into();
    };
    let name = &stat[open + 1..close];
    let fields: Vec<&str> = stat[close + 1..].split_whitespace().collect();
    // Fields after the name, from 0: state 0, utime 11, stime 12, rt_priority 37, policy 38.
    let field = |i: usize| fields.get(i).copied().unwrap_or("?");
    let ticks = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    let policy = match field(38) {
        "0" => "normal".to_string(),
        "1" => format!("FIFO {}", field(37)),
        "2" => format!("RR {}", field(37)),
        p => format!("policy {p}"),
    };
    let wchan = if wchan.is_empty() || wchan == "0" { "running" } else { wchan };
    format!("{name}: state {}, {policy}, cpu {:.2} s, waiting in {wchan}", field(0), (ticks(11) + ticks(12)) / hz)
}

fn signal(child: &Child, signal: i32) {
    // SAFETY: kill(2) on our own child's pid; no memory is involved.
    unsafe { libc::kill(child.id() as libc::pid_t, signal) };
}

/// Describes how a process ended, e.g. `was killed by signal 9 (SIGKILL)`.
pub fn describe_exit(status: ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(0), _) => "exited normally".into(),
        (Some(code), _) => format!("exited with status {code}"),
        (None, Some(sig)) => {
            let name = match sig {
                libc::SIGKILL => " (SIGKILL)",
                libc::SIGTERM => " (SIGTERM)",
                libc::SIGSEGV => " (SIGSEGV)",
                libc::SIGABRT => " (SIGABRT)",
                libc::SIGINT => " (SIGINT)",
                _ => "",
            };
            format!("was killed by signal {sig}{name}")
        }
        (None, None) => "ended for an unknown reason".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_task_line_reads_policy_priority_and_cpu_from_its_stat() {
        // A real-time thread as /proc shows it: FIFO 80, 250 ticks of CPU.
        let mut fields = vec!["0"; 45];
        (fields[0], fields[11], fields[12], fields[37], fields[38]) = ("R", "200", "50", "80", "1");
        let stat = format!("4242 (jetbench-actuat) {}", fields.join(" "));
        // SAFETY: sysconf has no preconditions.
        let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
        let line = task_line(&stat, "0");
        let cpu = format!("cpu {:.2} s", 250.0 / hz);
        assert_eq!(line, format!("jetbench-actuat: state R, FIFO 80, {cpu}, waiting in running"));
        assert_eq!(task_line("garbage", ""), "(unreadable)");
    }

    #[test]
    fn lines_are_attributed_and_exits_described() {
        let mut children = Supervisor::new();
        let a = children
            .spawn("a", Command::new("sh").args(["-c", "echo ready; exit 3"]), SpawnOptions::default())
            .unwrap();
        let (i, line) = children.next_line(Duration::from_secs(10)).expect("a line");
        assert_eq!((i, line.as_str(), children.name(i)), (a, "ready", "a"));
        let deadline = Instant::now() + Duration::from_secs(10);
        let (i, status) = loop {
            if let Some(exit) = children.reap() {
                break exit;
            }
            assert!(Instant::now() < deadline, "the child never exited");
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!((i, describe_exit(status)), (a, "exited with status 3".to_string()));
        assert!(children.stop(StopOrder::Together, Duration::from_secs(1)).is_none(), "nothing left to stop");
    }

    #[test]
    fn stopping_terminates_in_turn_and_reports_the_first_unclean_end() {
        let mut children = Supervisor::new();
        let options = SpawnOptions::default();
        // `exec` so that SIGTERM reaches sleep itself.
        let first = children.spawn("first", Command::new("sh").args(["-c", "exec sleep 30"]), options).unwrap();
        let second = children.spawn("second", Command::new("sh").args(["-c", "exec sleep 30"]), options).unwrap();
        let failure = children.stop(StopOrder::InTurn(vec![second, first]), Duration::from_secs(5));
        assert_eq!(failure, Some((second, "was killed by signal 15 (SIGTERM)".to_string())));
        assert!(children.exited(first).is_some() && children.exited(second).is_some());
    }
}
