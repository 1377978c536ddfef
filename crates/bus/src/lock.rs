//! One service set per bus namespace.
//!
//! The launcher takes the namespace's lock before it starts anything: an
//! exclusive `flock` on a small file next to the doorbells, which names the
//! launcher (pid, start time). Its services inherit the lock's descriptor, so
//! the namespace stays taken until the last process of the set is gone, even
//! when the launcher itself was killed and its services are still stopping; the
//! kernel lets go of it when they have all exited, so a lock is never stale.
//!
//! ```no_run
//! use jetbench_bus::lock::{NamespaceLock, LockError};
//!
//! match NamespaceLock::acquire("jetbench up") {
//!     Ok(lock) => println!("namespace taken ({})", lock.path().display()),
//!     Err(LockError::InUse { holder, .. }) => eprintln!("in use by {holder}"),
//!     Err(e) => eprintln!("{e}"),
//! }
//! ```

use std::fs::{File, OpenOptions};
use std::io::{self, Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::error::EnvError;

/// Why the namespace could not be taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// The process's bus settings are not usable.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// Another service set holds the namespace.
    #[error(
        "bus namespace {namespace} is in use by {holder}; stop that set first (Ctrl-C in its terminal, or kill -TERM \
         its pid), or run this one in another namespace (JETBENCH_BUS=NAME)"
    )]
    InUse {
        /// The namespace.
        namespace: String,
        /// Who holds it, as its lock file names it (launcher pid and start time).
        holder: String,
    },
    /// The lock file could not be opened, locked or written.
    #[error("cannot take the lock {path} of the bus namespace: {source}")]
    Io {
        /// The lock file.
        path: PathBuf,
        /// The system's reason.
        source: io::Error,
    },
}

/// The namespace's lock, held while this value (and any child that inherited
/// it) lives.
#[derive(Debug)]
pub struct NamespaceLock {
    file: File,
    path: PathBuf,
}

/// Where the lock of the current namespace lives (`/dev/shm/jetbench.<namespace>.set.lock`).
pub fn lock_path() -> Result<PathBuf, EnvError> {
    Ok(crate::bell::path_of(Some(&crate::namespace_name()?), "set").with_extension("lock"))
}

/// How long a new set waits for the services of a set whose launcher is gone
/// (killed) to finish stopping: they stop within a second.
const ORPHANS_WAIT: Duration = Duration::from_secs(5);

impl NamespaceLock {
    /// Takes the current namespace for the set `what` launches (e.g. `jetbench
    /// up`). If the namespace is held by a set whose launcher is gone, waits
    /// up to a few seconds for its services to finish stopping; if its
    /// launcher is alive, fails at once naming it.
    pub fn acquire(what: &str) -> Result<NamespaceLock, LockError> {
        Self::acquire_at(lock_path()?, what)
    }

    fn acquire_at(path: PathBuf, what: &str) -> Result<NamespaceLock, LockError> {
        let io_err = |source| LockError::Io { path: path.clone(), source };
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(crate::access::file_mode())
            .open(&path)
            .map_err(io_err)?;
        let deadline = Instant::now() + ORPHANS_WAIT;
        let mut told = false;
        while !try_flock(&file).map_err(io_err)? {
            let holder = holder_of(&mut file);
            let launcher_alive = holder.pid.is_some_and(pid_alive);
            if launcher_alive || Instant::now() >= deadline {
                let namespace = crate::namespace_name()?;
                return Err(LockError::InUse { namespace, holder: holder.describe(launcher_alive) });
            }
            if !told {
                eprintln!("waiting for the services of {} to finish stopping", holder.describe(false));
                told = true;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let record = format!("{}\n{}\n{what}\n", std::process::id(), unix_time_s());
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(record.as_bytes()))
            .map_err(io_err)?;
        Ok(NamespaceLock { file, path })
    }

    /// The lock file, next to the namespace's doorbells (it names the launcher).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Lets the children started from now on inherit the lock (they hold the
    /// namespace until they exit). Only the launcher's services should: call
    /// it before starting them.
    pub fn inherit(&self) -> io::Result<()> {
        let fd = self.file.as_raw_fd();
        // SAFETY: F_GETFD on a descriptor this value owns.
        let flags = unsafe { libc::fcntl(fd, libc::F_GETFD) };
        if flags < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: F_SETFD on the same descriptor, with its own flags less FD_CLOEXEC.
        if unsafe { libc::fcntl(fd, libc::F_SETFD, flags & !libc::FD_CLOEXEC) } < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }
}

fn unix_time_s() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

fn try_flock(file: &File) -> io::Result<bool> {
    loop {
        // SAFETY: flock on an open descriptor.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
            return Ok(true);
        }
        let e = io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EWOULDBLOCK) => return Ok(false),
            Some(libc::EINTR) => continue,
            _ => return Err(e),
        }
    }
}

/// Who holds the lock, as its file says.
struct Holder {
    pid: Option<u32>,
    started_s: Option<u64>,
    what: String,
}

impl Holder {
    fn describe(&self, alive: bool) -> String {
        let pid = self.pid.map_or("an unknown pid".to_string(), |p| format!("pid {p}"));
        let since =
            self.started_s.map_or(String::new(), |s| format!(", started {} s ago", unix_time_s().saturating_sub(s)));
        let state = if alive { "" } else { ", now gone; its services are still stopping" };
        format!("the service set of {} ({pid}{since}{state})", self.what)
    }
}

fn holder_of(file: &mut File) -> Holder {
    let mut text = String::new();
    let _ = file.rewind().and_then(|()| file.read_to_string(&mut text));
    let mut lines = text.lines();
    let pid = lines.next().and_then(|l| l.trim().parse().ok());
    let started_s = lines.next().and_then(|l| l.trim().parse().ok());
    let what = lines.next().filter(|w| !w.is_empty()).unwrap_or("a launcher").to_string();
    Holder { pid, started_s, what }
}

fn pid_alive(pid: u32) -> bool {
    // SAFETY: kill(pid, 0) only checks that the process exists.
    pid != 0
        && (unsafe { libc::kill(pid as libc::pid_t, 0) } == 0
            || io::Error::last_os_error().raw_os_error() == Some(libc::EPERM))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_set_is_refused_naming_the_first_and_the_lock_goes_with_its_holder() {
        let path = crate::bell::path_of(Some(&format!("locktest{}", std::process::id())), "set").with_extension("lock");
        let first = NamespaceLock::acquire_at(path.clone(), "jetbench up --sim").expect("a free namespace is taken");
        // A second open file description is a second set, as far as flock goes.
        let err = NamespaceLock::acquire_at(path.clone(), "jetbench up").expect_err("the namespace is taken");
        let text = err.to_string();
        assert!(
            text.contains(&format!("pid {}", std::process::id())) && text.contains("jetbench up --sim"),
            "names the running set: {text}"
        );
        drop(first);
        let again = NamespaceLock::acquire_at(path.clone(), "jetbench up").expect("free again once its holder is gone");
        drop(again);
        let _ = std::fs::remove_file(path);
    }
}
