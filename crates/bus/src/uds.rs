//! The copying transport: every sample through Unix domain sockets.
//!
//! With `JETBENCH_TRANSPORT=uds` (`jetbench up --transport uds`) the same
//! service set runs with its samples copied through the kernel instead of
//! shared through iceoryx2: the baseline `jetbench latency` measures the
//! zero-copy bus against. It is built the way a careful socket design would
//! be, not handicapped:
//! - each subscriber listens on a `SOCK_SEQPACKET` socket in its channel's
//!   folder (a connected seqpacket queue is bounded by the sender's buffer,
//!   not by the 10-datagram `net.unix.max_dgram_qlen` of datagram sockets);
//! - each publisher keeps one connection per subscriber and sends every
//!   sample to each, woken consumers first (so a consumer above the
//!   publisher in priority preempts it at the first send), never waiting: a
//!   full queue drops the sample, which the subscriber sees as a `seq` gap;
//! - a consumer sleeps in `ppoll` on its connections and reads everything
//!   queued with one `recvmmsg` per connection.
//!
//! Publishers find subscribers by listing the folder, only when the
//! channel's doorbell file says a subscriber came or went (a generation
//! word in shared memory), so discovery costs the hot path nothing.

use std::cell::{Cell, RefCell};
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use crate::bell::{Doorbell, Woke};

/// The largest sample the transport carries.
pub const MAX_SAMPLE_BYTES: usize = 512;
/// Messages one fill of an inbox takes at most.
const BATCH: usize = 32;
/// How often an inbox looks for new publishers when nothing told it of one.
const ACCEPT_EVERY: Duration = Duration::from_millis(100);
/// How soon a publisher tries again a subscriber it could not connect to.
const RETRY_CONNECT_AFTER: Duration = Duration::from_millis(20);
/// Room a subscriber's queue gets per sample it asked to hold: a small
/// message costs the kernel about this much (its buffer plus bookkeeping).
const BYTES_PER_QUEUED: usize = 1024;

/// The folder of `channel`'s sockets in bus namespace `namespace`.
pub fn channel_dir(namespace: Option<&str>, channel: &str) -> PathBuf {
    let flat: String =
        channel.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '.' }).collect();
    std::env::temp_dir().join("jetbench-uds").join(namespace.unwrap_or("default")).join(flat)
}

/// The channels of bus namespace `namespace` with at least one socket
/// subscriber: a jetbench channel by its name, any other by its folder's name.
pub fn live_channels(namespace: Option<&str>) -> Vec<String> {
    let root = channel_dir(namespace, "x").parent().map(Path::to_path_buf).unwrap_or_default();
    let Ok(entries) = std::fs::read_dir(&root) else { return Vec::new() };
    let mut names = Vec::new();
    for entry in entries.flatten() {
        let live = std::fs::read_dir(entry.path())
            .map(|files| files.flatten().any(|f| f.file_name().to_str().and_then(parse_inbox_name).is_some()))
            .unwrap_or(false);
        if !live {
            continue;
        }
        let flat = entry.file_name();
        let known = jetbench_msgs::channel_names()
            .into_iter()
            .find(|name| channel_dir(namespace, name).file_name() == Some(flat.as_os_str()));
        names.push(known.map_or_else(|| flat.to_string_lossy().into_owned(), str::to_string));
    }
    names
}

fn sockaddr(path: &Path) -> io::Result<(libc::sockaddr_un, libc::socklen_t)> {
    // SAFETY: sockaddr_un is plain data; all zeros is a valid value.
    let mut addr: libc::sockaddr_un = unsafe { std::mem::zeroed() };
    addr.sun_family = libc::AF_UNIX as libc::sa_family_t;
    let bytes = path.as_os_str().as_bytes();
    if bytes.len() >= addr.sun_path.len() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "socket path {} is longer than {} bytes (set TMPDIR to a shorter folder)",
                path.display(),
                addr.sun_path.len() - 1
            ),
        ));
    }
    for (dst, &src) in addr.sun_path.iter_mut().zip(bytes) {
        *dst = src as libc::c_char;
    }
    let len = std::mem::size_of::<libc::sa_family_t>() + bytes.len() + 1;
    Ok((addr, len as libc::socklen_t))
}

fn seqpacket() -> io::Result<OwnedFd> {
    // SAFETY: plain socket creation; the result is checked.
    let fd = unsafe { libc::socket(libc::AF_UNIX, libc::SOCK_SEQPACKET | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC, 0) };
    if fd < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: a fresh descriptor nothing else owns.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}

fn check(ret: libc::c_int) -> io::Result<()> {
    if ret < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(())
    }
}

/// A subscriber's socket file name: `<pid>-<n>-<depth>-<w|p>.sock`, so a
/// publisher knows how deep to make the queue and whom to send to first.
fn inbox_name(depth: usize, woken: bool) -> String {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    format!("{}-{n}-{depth}-{}.sock", std::process::id(), if woken { 'w' } else { 'p' })
}

/// The name a subscriber's socket has while it is being set up: publishers
/// pass over it (it does not end in `.sock`).
fn listening_name(name: &str) -> String {
    format!(".{name}.binding")
}

/// Removes the half-set-up sockets ([`listening_name`]) left in `dir` by subscribers
/// killed between the bind and the rename: nothing else ever would. A file whose
/// process still runs is left alone (it may be setting up now).
fn sweep_stale_bindings(dir: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(binding_pid) else { continue };
        // SAFETY: signal 0 only asks whether the process exists.
        let gone = unsafe { libc::kill(pid, 0) } < 0 && io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
        if gone {
            tracing::debug!("removing {}, left by subscriber process {pid} that is gone", name.to_string_lossy());
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// The process that made a half-set-up socket file ([`listening_name`]).
fn binding_pid(name: &str) -> Option<libc::pid_t> {
    let inbox = name.strip_prefix('.')?.strip_suffix(".binding")?;
    parse_inbox_name(inbox)?;
    inbox.split('-').next()?.parse().ok().filter(|pid: &libc::pid_t| *pid > 0)
}

/// What a publisher reads off a subscriber's socket file name.
fn parse_inbox_name(name: &str) -> Option<(usize, bool)> {
    let stem = name.strip_suffix(".sock")?;
    let mut parts = stem.rsplitn(3, '-');
    let woken = match parts.next()? {
        "w" => true,
        "p" => false,
        _ => return None,
    };
    let depth = parts.next()?.parse().ok()?;
    Some((depth, woken))
}

struct Outlet {
    path: PathBuf,
    fd: OwnedFd,
    woken: bool,
}

/// A publisher's end: one connection per subscriber.
pub struct Outbox {
    dir: PathBuf,
    generation_seen: Option<u32>,
    outlets: Vec<Outlet>,
    /// A subscriber could not be connected for a passing reason (its queue
    /// of connections full): the folder is looked at again after this.
    retry_at: Option<Instant>,
}

impl Outbox {
    /// A publisher's end for the channel whose folder is `dir` (created if missing);
    /// it connects to the subscribers listening there when they come.
    pub fn open(dir: &Path) -> io::Result<Outbox> {
        std::fs::create_dir_all(dir)?;
        Ok(Outbox { dir: dir.to_path_buf(), generation_seen: None, outlets: Vec::new(), retry_at: None })
    }

    /// Sends `bytes` to every subscriber; rescans first if subscribers came or went.
    pub fn send(&mut self, bytes: &[u8], bell: &Doorbell) -> io::Result<()> {
        let generation = bell.generation();
        let retry = self.retry_at.is_some_and(|at| Instant::now() >= at);
        if self.generation_seen != Some(generation) || retry {
            self.generation_seen = Some(generation);
            self.rescan();
        }
        let mut gone = false;
        for outlet in &mut self.outlets {
            // SAFETY: sends from a live buffer of `bytes.len()` bytes.
            let n = unsafe {
                libc::send(
                    outlet.fd.as_raw_fd(),
                    bytes.as_ptr().cast(),
                    bytes.len(),
                    libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
                )
            };
            if n >= 0 {
                continue;
            }
            let e = io::Error::last_os_error();
            match e.raw_os_error() {
                // The subscriber's queue is full: the sample is dropped, and the
                // subscriber counts it as a `seq` gap.
                Some(libc::EAGAIN) => {}
                Some(libc::EPIPE | libc::ECONNRESET | libc::ENOTCONN) => {
                    outlet.woken = false;
                    outlet.path.clear();
                    gone = true;
                }
                _ => return Err(e),
            }
        }
        if gone {
            self.outlets.retain(|o| !o.path.as_os_str().is_empty());
        }
        Ok(())
    }

    /// Connects to every subscriber in the folder not yet connected, and lets
    /// go of those whose file is gone. Woken consumers come first.
    fn rescan(&mut self) {
        self.retry_at = None;
        let Ok(entries) = std::fs::read_dir(&self.dir) else {
            self.retry_at = Some(Instant::now() + RETRY_CONNECT_AFTER);
            return;
        };
        let mut present = Vec::new();
        for entry in entries.flatten() {
            let name = entry.file_name();
            let Some((depth, woken)) = name.to_str().and_then(parse_inbox_name) else { continue };
            let path = entry.path();
            present.push(path.clone());
            if self.outlets.iter().any(|o| o.path == path) {
                continue;
            }
            match connect(&path, depth) {
                Ok(fd) => self.outlets.push(Outlet { path, fd, woken }),
                // Nobody listens there: the file of a subscriber that was killed.
                Err(e) if e.raw_os_error() == Some(libc::ECONNREFUSED) => {
                    let _ = std::fs::remove_file(&path);
                }
                Err(e) => {
                    tracing::debug!("cannot connect to subscriber {} yet: {e}", path.display());
                    self.retry_at = Some(Instant::now() + RETRY_CONNECT_AFTER);
                }
            }
        }
        self.outlets.retain(|o| present.contains(&o.path));
        self.outlets.sort_by_key(|o| !o.woken);
    }
}

fn connect(path: &Path, depth: usize) -> io::Result<OwnedFd> {
    let fd = seqpacket()?;
    let (addr, len) = sockaddr(path)?;
    // Room for the subscriber's queue. Root may exceed `net.core.wmem_max`;
    // others get what the kernel allows.
    let bytes = (depth.max(1) * BYTES_PER_QUEUED).min(i32::MAX as usize) as libc::c_int;
    for option in [libc::SO_SNDBUFFORCE, libc::SO_SNDBUF] {
        // SAFETY: setsockopt with an int-sized option value.
        let ret = unsafe {
            libc::setsockopt(
                fd.as_raw_fd(),
                libc::SOL_SOCKET,
                option,
                (&bytes as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            )
        };
        if ret == 0 {
            break;
        }
    }
    // SAFETY: a valid sockaddr_un of `len` bytes.
    check(unsafe { libc::connect(fd.as_raw_fd(), (&addr as *const libc::sockaddr_un).cast(), len) })?;
    Ok(fd)
}

/// One queued message: which connection it came from and its bytes.
#[derive(Clone, Copy)]
struct Slot {
    conn: u64,
    len: usize,
    bytes: [u8; MAX_SAMPLE_BYTES],
}

struct Inlet {
    id: u64,
    fd: OwnedFd,
}

/// A subscriber's end: a listening socket and one connection per publisher.
pub struct Inbox {
    listener: OwnedFd,
    path: PathBuf,
    woken: bool,
    inlets: RefCell<Vec<Inlet>>,
    next_id: Cell<u64>,
    /// Messages read but not yet taken: `slots[head..head + len]` (filled
    /// from 0 when empty).
    slots: RefCell<Box<[Slot; BATCH]>>,
    head: Cell<usize>,
    len: Cell<usize>,
    /// The last fill emptied every connection: the next take that finds no
    /// message ends the drain without another system call (woken inboxes).
    drained: Cell<bool>,
    /// A poll saw a connection readable (woken inboxes).
    ready: Cell<bool>,
    accepted_at: Cell<Option<Instant>>,
}

impl Inbox {
    /// Listens in `dir` for publishers; `depth` samples may queue per publisher.
    ///
    /// The socket is bound and listening under a name publishers pass over
    /// ([`listening_name`]) before it is renamed to the one they connect to:
    /// a publisher that looked between the bind and the listen would be
    /// refused, take the file for a killed subscriber's and remove it, and
    /// this subscriber would never hear from it.
    pub fn open(dir: &Path, depth: usize, woken: bool, bell: &Doorbell) -> io::Result<Inbox> {
        std::fs::create_dir_all(dir)?;
        sweep_stale_bindings(dir);
        let name = inbox_name(depth, woken);
        let path = dir.join(&name);
        let staging = dir.join(listening_name(&name));
        let _ = std::fs::remove_file(&path);
        let _ = std::fs::remove_file(&staging);
        let listener = seqpacket()?;
        let (addr, len) = sockaddr(&staging)?;
        // SAFETY: a valid sockaddr_un of `len` bytes.
        check(unsafe { libc::bind(listener.as_raw_fd(), (&addr as *const libc::sockaddr_un).cast(), len) })?;
        // SAFETY: plain listen on a bound socket.
        let listening = check(unsafe { libc::listen(listener.as_raw_fd(), 64) });
        if let Err(e) = listening.and_then(|()| std::fs::rename(&staging, &path)) {
            let _ = std::fs::remove_file(&staging);
            return Err(e);
        }
        bell.bump_generation();
        let empty = Slot { conn: 0, len: 0, bytes: [0; MAX_SAMPLE_BYTES] };
        Ok(Inbox {
            listener,
            path,
            woken,
            inlets: RefCell::new(Vec::new()),
            next_id: Cell::new(1),
            slots: RefCell::new(Box::new([empty; BATCH])),
            head: Cell::new(0),
            len: Cell::new(0),
            drained: Cell::new(false),
            ready: Cell::new(false),
            accepted_at: Cell::new(None),
        })
    }

    /// Removes the socket file and tells publishers.
    pub fn close(&self, bell: &Doorbell) {
        let _ = std::fs::remove_file(&self.path);
        bell.bump_generation();
    }

    /// Accepts every pending publisher connection.
    fn accept_all(&self) {
        self.accepted_at.set(Some(Instant::now()));
        loop {
            // SAFETY: accept4 without an address; the result is checked.
            let fd = unsafe {
                libc::accept4(
                    self.listener.as_raw_fd(),
                    std::ptr::null_mut(),
                    std::ptr::null_mut(),
                    libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC,
                )
            };
            if fd < 0 {
                return;
            }
            let id = self.next_id.get();
            self.next_id.set(id + 1);
            // SAFETY: a fresh descriptor nothing else owns.
            self.inlets.borrow_mut().push(Inlet { id, fd: unsafe { OwnedFd::from_raw_fd(fd) } });
        }
    }

    /// Takes the oldest message as (connection, bytes) and hands it to `f`.
    ///
    /// A drain (takes until `None`) reads every connection once, with one
    /// `recvmmsg` each. A woken inbox then ends the drain without a further
    /// system call when that read emptied them: anything that arrived since
    /// makes its next `ppoll` return at once. A polled one always reads
    /// again, so a `None` it gives is never stale.
    pub fn take<R>(&self, f: impl FnOnce(u64, &[u8]) -> R) -> io::Result<Option<R>> {
        if self.len.get() == 0 {
            if self.drained.replace(false) && self.woken {
                return Ok(None);
            }
            self.fill()?;
            if self.len.get() == 0 {
                // This `None` ends the drain; the next one reads again.
                self.drained.set(false);
                return Ok(None);
            }
        }
        let slots = self.slots.borrow();
        let slot = &slots[self.head.get()];
        self.head.set(self.head.get() + 1);
        self.len.set(self.len.get() - 1);
        Ok(Some(f(slot.conn, &slot.bytes[..slot.len])))
    }

    /// Reads every connection into the (empty) buffer.
    fn fill(&self) -> io::Result<()> {
        // A woken inbox accepts when its poll sees the listener ready; until it
        // has a publisher it also looks here, in case it is read without waiting.
        let look = !self.woken || self.inlets.borrow().is_empty();
        if look && self.accepted_at.get().is_none_or(|t| t.elapsed() >= ACCEPT_EVERY) {
            self.accept_all();
        }
        debug_assert_eq!(self.len.get(), 0, "filled only when empty");
        self.head.set(0);
        let mut drained = true;
        let mut closed = Vec::new();
        let mut slots = self.slots.borrow_mut();
        for inlet in self.inlets.borrow().iter() {
            let start = self.len.get();
            let room = BATCH - start;
            if room == 0 {
                drained = false;
                break;
            }
            let mut iov = [libc::iovec { iov_base: std::ptr::null_mut(), iov_len: 0 }; BATCH];
            // SAFETY: mmsghdr is plain data; zeroed is valid (no name, no control).
            let mut msgs: [libc::mmsghdr; BATCH] = unsafe { std::mem::zeroed() };
            for (k, (iov, msg)) in iov.iter_mut().zip(msgs.iter_mut()).take(room).enumerate() {
                *iov = libc::iovec { iov_base: slots[start + k].bytes.as_mut_ptr().cast(), iov_len: MAX_SAMPLE_BYTES };
                msg.msg_hdr.msg_iov = iov;
                msg.msg_hdr.msg_iovlen = 1;
            }
            // SAFETY: `room` headers, each pointing at a live slot of MAX_SAMPLE_BYTES.
            let n = unsafe {
                libc::recvmmsg(
                    inlet.fd.as_raw_fd(),
                    msgs.as_mut_ptr(),
                    room as libc::c_uint,
                    libc::MSG_DONTWAIT,
                    std::ptr::null_mut(),
                )
            };
            let Ok(n) = usize::try_from(n) else {
                let e = io::Error::last_os_error();
                match e.raw_os_error() {
                    Some(libc::EAGAIN) => continue,
                    Some(libc::ECONNRESET) => {
                        closed.push(inlet.id);
                        continue;
                    }
                    _ => return Err(e),
                }
            };
            let mut eof = false;
            for (k, msg) in msgs.iter().take(n).enumerate() {
                let len = msg.msg_len as usize;
                if len == 0 {
                    // An empty read on a seqpacket socket: the publisher left.
                    eof = true;
                    break;
                }
                slots[start + k].conn = inlet.id;
                slots[start + k].len = len;
                self.len.set(start + k + 1);
            }
            if eof {
                closed.push(inlet.id);
            } else if n == room {
                drained = false;
            }
        }
        if !closed.is_empty() {
            self.inlets.borrow_mut().retain(|i| !closed.contains(&i.id));
        }
        self.drained.set(drained);
        Ok(())
    }

    /// True if a poll saw data since the last call (woken inboxes).
    pub fn take_ready(&self) -> bool {
        self.ready.replace(false)
    }

    /// The descriptors a waiting consumer polls: the listener, then each connection.
    fn poll_fds(&self, out: &mut Vec<libc::pollfd>) {
        let fd = |fd: RawFd| libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
        out.push(fd(self.listener.as_raw_fd()));
        out.extend(self.inlets.borrow().iter().map(|i| fd(i.fd.as_raw_fd())));
    }

    /// Reads what a poll found: accepts new publishers, notes readable connections.
    fn polled(&self, revents: &[libc::pollfd]) {
        if let Some((listener, inlets)) = revents.split_first() {
            if listener.revents != 0 {
                self.accept_all();
            }
            if inlets.iter().any(|p| p.revents != 0) {
                self.ready.set(true);
                // Data (or a departure) is waiting: the next drain must read.
                self.drained.set(false);
            }
        }
    }
}

/// Sleeps until one of `inboxes` has a message (or a publisher leaves),
/// `deadline` passes, or a signal arrives. `fds` is scratch space, reused.
pub fn wait_any(inboxes: &[&Inbox], deadline: Instant, fds: &mut Vec<libc::pollfd>) -> io::Result<Woke> {
    fds.clear();
    let mut spans = [(0usize, 0usize); crate::bell::MAX_WAIT];
    if inboxes.len() > spans.len() {
        return Err(io::Error::other(format!("cannot wait on {} inputs, at most {}", inboxes.len(), spans.len())));
    }
    for (inbox, span) in inboxes.iter().zip(spans.iter_mut()) {
        let start = fds.len();
        inbox.poll_fds(fds);
        *span = (start, fds.len());
    }
    let left = deadline.saturating_duration_since(Instant::now());
    let timeout =
        libc::timespec { tv_sec: left.as_secs() as libc::time_t, tv_nsec: left.subsec_nanos() as libc::c_long };
    // SAFETY: `fds` holds fds.len() valid pollfds; the timespec outlives the call.
    let n = unsafe { libc::ppoll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, &timeout, std::ptr::null()) };
    if n < 0 {
        let e = io::Error::last_os_error();
        return if e.kind() == io::ErrorKind::Interrupted { Ok(Woke::Interrupted) } else { Err(e) };
    }
    if n == 0 {
        return Ok(Woke::Timeout);
    }
    for (inbox, &(start, end)) in inboxes.iter().zip(spans.iter()) {
        inbox.polled(&fds[start..end]);
    }
    Ok(Woke::Rang)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn socket_names_carry_depth_and_role() {
        let name = inbox_name(512, false);
        assert_eq!(parse_inbox_name(&name), Some((512, false)));
        assert_eq!(parse_inbox_name(&inbox_name(16, true)), Some((16, true)));
        for bad in ["x.sock", "1-2-3-q.sock", "1-2-w.txt", "1-2-many-w.sock"] {
            assert_eq!(parse_inbox_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn a_half_set_up_socket_of_a_process_that_is_gone_is_swept_and_a_live_ones_kept() {
        let dir = std::env::temp_dir().join(format!("jetbench-sweep-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("folder");
        let mut child = std::process::Command::new("true").spawn().expect("a child process");
        let dead = child.id();
        child.wait().expect("reaped");
        let live = std::process::id();
        let stale = dir.join(format!(".{dead}-0-16-w.sock.binding"));
        let setting_up = dir.join(format!(".{live}-0-16-w.sock.binding"));
        let other = dir.join(format!(".{dead}-notes.txt"));
        for path in [&stale, &setting_up, &other] {
            std::fs::write(path, b"").expect("file");
        }
        sweep_stale_bindings(&dir);
        assert!(!stale.exists(), "the binding of process {dead}, which is gone, is left");
        assert!(setting_up.exists(), "the binding of this live process was removed");
        assert!(other.exists(), "a file that is no binding was removed");
        assert_eq!(binding_pid(&format!(".{live}-3-512-p.sock.binding")), Some(live as libc::pid_t));
        assert_eq!(binding_pid(&format!("{live}-3-512-p.sock")), None);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
