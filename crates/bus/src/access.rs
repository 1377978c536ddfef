//! Who may touch a service set's files: its user only, or also one group.
//!
//! Every file a set creates (iceoryx2's shared memory, the doorbells, the
//! Unix sockets of the socket transport and of the simulated CAN bus, their
//! folders, the pty links, the namespace lock) is readable and writable by the
//! user who started it and nobody else: each process of a set sets its file
//! mode creation mask to `077` before it creates anything ([`restrict`]), and
//! the files created with an explicit mode get `0600`.
//!
//! A bench where several people may watch a running set names a group in the
//! bench config (`[bench] group = "jetbench"`); the launcher passes it on as
//! [`GROUP_ENV`], the mask becomes `007` and the explicit modes `0660`. The
//! files then belong to the group of the process that creates them, so the set
//! must run with that group as its own (`sg jetbench -c "jetbench up ..."`),
//! which the launcher checks. iceoryx2 0.10 fixes the mode of its own shared
//! memory when it is built (owner only, or everyone with its `dev_permissions`
//! feature, nothing in between), so a group member reaches a set over the
//! socket transport (`--transport uds`), not the shared memory.

use std::ffi::CString;
use std::io;

/// Environment variable naming the group that shares a set's files (name or id).
pub const GROUP_ENV: &str = "JETBENCH_GROUP";

/// Why the group setting cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum GroupError {
    /// No group of that name (or id) exists here (the name given).
    #[error("no group named {0:?} on this machine ([bench] group / {GROUP_ENV})")]
    Unknown(String),
    /// The process does not run with the group as its own, so files it creates would
    /// not be shared.
    #[error(
        "[bench] group = {name:?} shares the set's files with that group, so the set must run with it as its group: \
         start it with `sg {name} -c \"jetbench up ...\"` (you must be a member)"
    )]
    NotOurGroup {
        /// The group's name.
        name: String,
    },
}

/// The group that shares the set's files, from [`GROUP_ENV`] (its name and id).
pub fn group() -> Result<Option<(String, u32)>, GroupError> {
    let Ok(name) = std::env::var(GROUP_ENV) else { return Ok(None) };
    if name.is_empty() {
        return Ok(None);
    }
    gid_of(&name).map(|gid| Some((name.clone(), gid))).ok_or(GroupError::Unknown(name))
}

fn gid_of(name: &str) -> Option<u32> {
    if let Ok(gid) = name.parse() {
        return Some(gid);
    }
    let cname = CString::new(name).ok()?;
    // SAFETY: getgrnam reads the group database and returns a pointer into
    // static storage, read at once; no other thread of this process calls it.
    let entry = unsafe { libc::getgrnam(cname.as_ptr()) };
    // SAFETY: a non-null result points at a valid `struct group`.
    (!entry.is_null()).then(|| unsafe { (*entry).gr_gid })
}

/// Mode of a file created with an explicit mode: `0600`, or `0660` with a group.
pub fn file_mode() -> u32 {
    if matches!(group(), Ok(Some(_))) {
        0o660
    } else {
        0o600
    }
}

/// Sets this process's file mode creation mask so that everything it creates
/// from now on is its user's only (`077`), or also its group's (`007`) when a
/// group shares the set, which must then be this process's group. Called by the
/// launcher and by every service before they create a file.
pub fn restrict() -> Result<(), GroupError> {
    let mask = match group()? {
        None => 0o077,
        Some((name, gid)) => {
            // SAFETY: getegid has no preconditions.
            if unsafe { libc::getegid() } != gid {
                return Err(GroupError::NotOurGroup { name });
            }
            0o007
        }
    };
    // SAFETY: umask only swaps the process's mask.
    unsafe { libc::umask(mask) };
    Ok(())
}

/// Gives `path` the mode of a set's file, if this process owns it (a file
/// another process made is left as it is). For files whose creator sets its
/// own mode (iceoryx2's node counter, which it opens to everyone).
pub fn tighten(path: &std::path::Path) -> io::Result<()> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let meta = std::fs::metadata(path)?;
    // SAFETY: geteuid has no preconditions.
    if meta.uid() != unsafe { libc::geteuid() } || meta.mode() & 0o007 == 0 {
        return Ok(());
    }
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(file_mode()))
}
