//! Doorbells: the wake-up that goes with a channel's samples.
//!
//! A doorbell is a 32-bit ring counter in a small shared-memory file per
//! channel. A publisher rings it after each sample is in the queue; a
//! subscriber sleeps on it with a futex until it changes or a deadline passes.
//! One ring costs an atomic add and, only while someone sleeps, one
//! `futex(FUTEX_WAKE)`; one wake costs the return from `futex(FUTEX_WAIT)`.
//! That is the same work as the bare eventfd ping `jetbench latency` measures
//! as the machine's floor; why it replaced iceoryx2's event services, with the
//! figures, is in the crate's README.
//!
//! Several doorbells are waited on at once with `futex_waitv(2)` (Linux 5.16).
//!
//! The files live in `/dev/shm` next to iceoryx2's, named after the channel
//! and the bus namespace. Every process holding a doorbell holds a shared
//! `flock` on its file; the last one to let go removes it.

use std::fs::{File, OpenOptions};
use std::io;
use std::os::fd::AsRawFd;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

/// The shared words of one doorbell.
#[repr(C)]
struct Shared {
    /// Rings so far, wrapping: the futex word.
    rings: AtomicU32,
    /// Processes asleep on `rings` now; a ring skips the wake system call
    /// while this is 0. A process killed in its sleep leaves it raised, which
    /// only costs later rings a system call that wakes nobody.
    sleepers: AtomicU32,
    /// Bumped whenever a socket subscriber comes or goes (the Unix-socket
    /// transport, [`crate::uds`]): its publishers look for subscribers only then.
    generation: AtomicU32,
}

const FILE_SIZE: u64 = 64;

/// One process's handle on a channel's doorbell.
pub struct Doorbell {
    shared: NonNull<Shared>,
    /// Keeps the shared lock that marks the file in use.
    file: File,
    path: PathBuf,
    /// The ring count this handle last took (subscribers).
    seen: std::cell::Cell<u32>,
}

// SAFETY: the mapping belongs to the process, not to a thread, and is only
// touched through atomics; `Cell` keeps the handle itself to one thread at a time.
unsafe impl Send for Doorbell {}

impl std::fmt::Debug for Doorbell {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Doorbell").field("path", &self.path).field("seen", &self.seen.get()).finish()
    }
}

/// Where the doorbell of `channel` in the bus namespace `namespace` lives.
pub fn path_of(namespace: Option<&str>, channel: &str) -> PathBuf {
    let clean = |s: &str| -> String {
        s.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '.' }).collect()
    };
    let name = match namespace {
        Some(ns) => format!("jetbench.{}.{}.bell", clean(ns), clean(channel)),
        None => format!("jetbench.{}.bell", clean(channel)),
    };
    Path::new("/dev/shm").join(name)
}

impl Doorbell {
    /// Opens (or creates) the doorbell at `path` and maps it.
    pub fn open(path: &Path) -> io::Result<Doorbell> {
        // Another process may be removing the file as it lets go of it: the
        // lock is taken on what the path names, then checked to still be it.
        for _ in 0..16 {
            let file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .mode(crate::access::file_mode())
                .open(path)?;
            flock(&file, libc::LOCK_SH)?;
            let held = file.metadata()?;
            match std::fs::metadata(path) {
                Ok(now) if now.ino() == held.ino() && now.dev() == held.dev() => {}
                _ => continue,
            }
            if held.len() < FILE_SIZE {
                file.set_len(FILE_SIZE)?;
            }
            // SAFETY: a fresh shared mapping of a file at least FILE_SIZE long;
            // the result is checked before use.
            let ptr = unsafe {
                libc::mmap(
                    std::ptr::null_mut(),
                    FILE_SIZE as usize,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_SHARED,
                    file.as_raw_fd(),
                    0,
                )
            };
            if ptr == libc::MAP_FAILED {
                return Err(io::Error::last_os_error());
            }
            let shared = NonNull::new(ptr.cast::<Shared>()).ok_or_else(|| io::Error::other("mmap returned null"))?;
            let bell = Doorbell { shared, file, path: path.to_path_buf(), seen: std::cell::Cell::new(0) };
            bell.seen.set(bell.shared().rings.load(Ordering::Acquire));
            return Ok(bell);
        }
        Err(io::Error::other(format!("{} kept being replaced while it was opened", path.display())))
    }

    fn shared(&self) -> &Shared {
        // SAFETY: the mapping lives as long as `self`; both words are atomics,
        // so concurrent access from other processes is sound.
        unsafe { self.shared.as_ref() }
    }

    /// Rings: every subscriber asleep on this doorbell wakes.
    pub fn ring(&self) -> io::Result<()> {
        let shared = self.shared();
        shared.rings.fetch_add(1, Ordering::SeqCst);
        if shared.sleepers.load(Ordering::SeqCst) > 0 {
            // SAFETY: FUTEX_WAKE on a word of a live shared mapping.
            let woken = unsafe { libc::syscall(libc::SYS_futex, &shared.rings, libc::FUTEX_WAKE, i32::MAX) };
            if woken < 0 {
                return Err(io::Error::last_os_error());
            }
        }
        Ok(())
    }

    /// Rings so far (wrapping). A subscriber that read this before finding
    /// its queue empty knows the queue is still empty while it is unchanged.
    pub fn rings(&self) -> u32 {
        self.shared().rings.load(Ordering::Acquire)
    }

    /// The subscriber generation (see [`Shared::generation`]).
    pub fn generation(&self) -> u32 {
        self.shared().generation.load(Ordering::Acquire)
    }

    /// Tells publishers that a subscriber came or went.
    pub fn bump_generation(&self) {
        self.shared().generation.fetch_add(1, Ordering::AcqRel);
    }

    /// True if it rang since [`take`](Self::take) last ran.
    pub fn pending(&self) -> bool {
        self.shared().rings.load(Ordering::Acquire) != self.seen.get()
    }

    /// Takes the rings so far; true if there were new ones. Take before
    /// reading the queue: a sample published after that rings again.
    pub fn take(&self) -> bool {
        let now = self.shared().rings.load(Ordering::Acquire);
        now != self.seen.replace(now)
    }

    /// Total rings seen by this handle's last [`take`](Self::take).
    pub fn seen(&self) -> u32 {
        self.seen.get()
    }
}

impl Drop for Doorbell {
    fn drop(&mut self) {
        // SAFETY: unmaps the mapping made in `open`; nothing borrows it past `self`.
        unsafe {
            libc::munmap(self.shared.as_ptr().cast(), FILE_SIZE as usize);
        }
        // The last holder removes the file (the lock upgrade fails while
        // another process holds its shared lock).
        if flock(&self.file, libc::LOCK_EX | libc::LOCK_NB).is_ok() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Removes the doorbell files nobody holds (left by killed processes) and
/// returns how many. A file someone opens meanwhile is safe: openers check
/// that the file they locked is still the one the path names.
pub fn remove_unheld() -> usize {
    let Ok(dir) = std::fs::read_dir("/dev/shm") else { return 0 };
    let mut removed = 0;
    for entry in dir.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with("jetbench.") && name.ends_with(".bell")) {
            continue;
        }
        let Ok(file) = File::open(entry.path()) else { continue };
        if flock(&file, libc::LOCK_EX | libc::LOCK_NB).is_ok() && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

fn flock(file: &File, op: libc::c_int) -> io::Result<()> {
    loop {
        // SAFETY: flock on an open descriptor.
        if unsafe { libc::flock(file.as_raw_fd(), op) } == 0 {
            return Ok(());
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

/// How a [`wait_any`] ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Woke {
    /// At least one doorbell rang (check them with [`Doorbell::pending`]).
    Rang,
    /// The deadline passed.
    Timeout,
    /// A signal interrupted the sleep.
    Interrupted,
}

/// Sleeps until one of `bells` rings (since its last take), `deadline`
/// passes, or a signal arrives. Returns at once if one is already pending.
/// Never spins: the only loop is the kernel's.
pub fn wait_any(bells: &[&Doorbell], deadline: Instant) -> io::Result<Woke> {
    if bells.iter().any(|b| b.pending()) {
        return Ok(Woke::Rang);
    }
    let timeout = monotonic_deadline(deadline);
    for b in bells {
        b.shared().sleepers.fetch_add(1, Ordering::SeqCst);
    }
    // A ring between the check above and the count above may have skipped the
    // wake: the kernel compares each word with what this handle saw first.
    let result = match bells {
        [] => sleep_until(&timeout),
        [one] => futex_wait_until(one, &timeout),
        many => futex_waitv_until(many, &timeout),
    };
    for b in bells {
        b.shared().sleepers.fetch_sub(1, Ordering::SeqCst);
    }
    result
}

/// `deadline` as an absolute CLOCK_MONOTONIC time, the clock `Instant` reads.
fn monotonic_deadline(deadline: Instant) -> libc::timespec {
    let mut now = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut now) };
    let left = deadline.saturating_duration_since(Instant::now());
    let ns = now.tv_nsec as u64 + u64::from(left.subsec_nanos());
    libc::timespec {
        tv_sec: now.tv_sec + left.as_secs() as libc::time_t + (ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (ns % 1_000_000_000) as libc::c_long,
    }
}

fn woke_from(ret: libc::c_long) -> io::Result<Woke> {
    if ret >= 0 {
        return Ok(Woke::Rang);
    }
    let e = io::Error::last_os_error();
    match e.raw_os_error() {
        // The word had already moved on: it rang.
        Some(libc::EAGAIN) => Ok(Woke::Rang),
        Some(libc::ETIMEDOUT) => Ok(Woke::Timeout),
        Some(libc::EINTR) => Ok(Woke::Interrupted),
        _ => Err(e),
    }
}

fn futex_wait_until(bell: &Doorbell, deadline: &libc::timespec) -> io::Result<Woke> {
    // FUTEX_WAIT_BITSET takes an absolute CLOCK_MONOTONIC deadline. Not the
    // private variant: the word is shared between processes.
    // SAFETY: the word lives in a mapping held by `bell`; the timespec outlives the call.
    let ret = unsafe {
        libc::syscall(
            libc::SYS_futex,
            &bell.shared().rings,
            libc::FUTEX_WAIT_BITSET,
            bell.seen.get(),
            deadline as *const libc::timespec,
            std::ptr::null::<u32>(),
            libc::FUTEX_BITSET_MATCH_ANY,
        )
    };
    woke_from(ret)
}

/// `struct futex_waitv` of `<linux/futex.h>`.
#[repr(C)]
struct FutexWaitv {
    val: u64,
    uaddr: u64,
    flags: u32,
    reserved: u32,
}

/// `FUTEX2_SIZE_U32`: the word is 32 bits (and shared: no `FUTEX2_PRIVATE`).
const FUTEX2_SIZE_U32: u32 = 0x02;
/// The most doorbells one wait takes (the kernel allows 128; a loop has a few
/// inputs, and the list lives on the stack so a wait allocates nothing).
pub const MAX_WAIT: usize = 16;

fn futex_waitv_until(bells: &[&Doorbell], deadline: &libc::timespec) -> io::Result<Woke> {
    if bells.len() > MAX_WAIT {
        return Err(io::Error::other(format!("cannot wait on {} doorbells, at most {MAX_WAIT}", bells.len())));
    }
    let mut waiters: [FutexWaitv; MAX_WAIT] =
        std::array::from_fn(|_| FutexWaitv { val: 0, uaddr: 0, flags: 0, reserved: 0 });
    for (w, b) in waiters.iter_mut().zip(bells) {
        *w = FutexWaitv {
            val: u64::from(b.seen.get()),
            uaddr: &b.shared().rings as *const AtomicU32 as u64,
            flags: FUTEX2_SIZE_U32,
            reserved: 0,
        };
    }
    // SAFETY: every address is a word in a mapping held by its doorbell; the
    // array and the timespec outlive the call.
    let ret = unsafe {
        libc::syscall(
            libc::SYS_futex_waitv,
            waiters.as_ptr(),
            bells.len() as libc::c_uint,
            0 as libc::c_uint,
            deadline as *const libc::timespec,
            libc::CLOCK_MONOTONIC,
        )
    };
    let woke = woke_from(ret);
    if let Err(e) = &woke {
        if e.raw_os_error() == Some(libc::ENOSYS) {
            return Err(io::Error::other(
                "this kernel has no futex_waitv (Linux 5.16 or newer waits on several inputs)",
            ));
        }
    }
    woke
}

fn sleep_until(deadline: &libc::timespec) -> io::Result<Woke> {
    // SAFETY: an absolute sleep on CLOCK_MONOTONIC; the remainder is not asked for.
    let ret =
        unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, deadline, std::ptr::null_mut()) };
    match ret {
        0 => Ok(Woke::Timeout),
        libc::EINTR => Ok(Woke::Interrupted),
        e => Err(io::Error::from_raw_os_error(e)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn scratch(name: &str) -> PathBuf {
        path_of(Some(&format!("test{}", std::process::id())), name)
    }

    #[test]
    fn a_ring_wakes_a_sleeper_in_another_thread_and_a_silent_bell_times_out() {
        let path = scratch("ring");
        let sleeper = Doorbell::open(&path).unwrap();
        let t0 = Instant::now();
        assert_eq!(wait_any(&[&sleeper], t0 + Duration::from_millis(30)).unwrap(), Woke::Timeout);
        assert!(t0.elapsed() >= Duration::from_millis(30));
        assert!(!sleeper.take());

        let ringer_path = path.clone();
        let ringer = std::thread::spawn(move || {
            let bell = Doorbell::open(&ringer_path).unwrap();
            std::thread::sleep(Duration::from_millis(20));
            bell.ring().unwrap();
            bell
        });
        let t0 = Instant::now();
        let woke = wait_any(&[&sleeper], t0 + Duration::from_secs(5)).unwrap();
        assert_eq!(woke, Woke::Rang);
        assert!(t0.elapsed() < Duration::from_secs(5));
        assert!(sleeper.take() && !sleeper.take());
        drop(ringer.join().unwrap());
        // A ring while nobody sleeps is kept for the next wait.
        let late = Doorbell::open(&path).unwrap();
        late.ring().unwrap();
        assert_eq!(wait_any(&[&sleeper], Instant::now() + Duration::from_secs(5)).unwrap(), Woke::Rang);
    }

    #[test]
    fn several_bells_wake_on_whichever_rings_and_the_last_holder_removes_the_file() {
        let (a, b) = (scratch("a"), scratch("b"));
        let (bell_a, bell_b) = (Doorbell::open(&a).unwrap(), Doorbell::open(&b).unwrap());
        let ring_b = b.clone();
        let ringer = std::thread::spawn(move || {
            let bell = Doorbell::open(&ring_b).unwrap();
            std::thread::sleep(Duration::from_millis(20));
            bell.ring().unwrap();
        });
        let woke = wait_any(&[&bell_a, &bell_b], Instant::now() + Duration::from_secs(5)).unwrap();
        ringer.join().unwrap();
        assert_eq!(woke, Woke::Rang);
        assert!(!bell_a.take() && bell_b.take());
        assert!(a.exists() && b.exists());
        drop((bell_a, bell_b));
        assert!(!a.exists() && !b.exists(), "the last holder removes the doorbell");
    }
}
