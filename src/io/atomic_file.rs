//! Output files that appear whole or not at all.
//!
//! [`PendingFile::create`] opens an unnamed file in the target's directory (Linux `O_TMPFILE`):
//! whatever happens to the process — an error, Ctrl-C, `SIGKILL`, a power cut — nothing of it is
//! ever visible, at the target path or beside it, until [`PendingFile::commit`] syncs it and links
//! it into place. Where the file system cannot make unnamed files (or off Linux) it is a hidden
//! file `.NAME.mireg-PID-XXXXXX.partial` beside the target, removed on error and on
//! `SIGINT`/`SIGTERM` ([`install_signal_handlers`]); one left by a killed run is removed by the
//! next run towards the same target.
//!
//! The target itself is only ever replaced when it is a regular file (and `overwrite` is set):
//! a device node, FIFO, socket or directory at the target path is an error, never replaced.

use std::fs::File;
use std::path::{Path, PathBuf};

use super::io_err;
use crate::{Error, Result};

/// An output file being written; [`commit`](Self::commit) puts it at its target.
#[derive(Debug)]
pub struct PendingFile {
    target: PathBuf,
    overwrite: bool,
    temp: Temp,
}

#[derive(Debug)]
enum Temp {
    /// An `O_TMPFILE` file: no name until it is linked into place.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    Unnamed,
    /// A hidden file beside the target, deleted on drop.
    Named(tempfile::TempPath),
}

/// Fails unless `target` may be written: in a folder that exists, and absent, or a regular file
/// when `overwrite` is set. The error names `target` as the user gave it and says what to do.
pub fn check_target(target: &Path, overwrite: bool) -> Result<()> {
    check_folder(target)?;
    match std::fs::metadata(target) {
        Ok(meta) if !meta.is_file() => Err(Error::InvalidInput(format!(
            "{}: is {}; mireg only ever replaces regular files",
            target.display(),
            super::file_kind(&meta)
        ))),
        Ok(_) if !overwrite => Err(Error::InvalidInput(format!(
            "{} exists (use --force to replace it)",
            target.display()
        ))),
        _ => Ok(()),
    }
}

/// Fails unless the folder `target` is to be written in exists and is a folder, naming `target`
/// and the folder (not a temporary file beside it).
fn check_folder(target: &Path) -> Result<()> {
    let dir = target_dir(target);
    let problem = match std::fs::metadata(&dir) {
        Ok(meta) if meta.is_dir() => return Ok(()),
        Ok(meta) => format!("is {}, not a folder", super::file_kind(&meta)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => "does not exist".to_string(),
        Err(e) => format!("cannot be read ({e})"),
    };
    Err(Error::InvalidInput(format!(
        "{}: cannot be written: its folder {} {problem}; create the folder first or choose \
         another output path",
        target.display(),
        dir.display()
    )))
}

/// Fails when `output` is one of `inputs` ([`same_file`]): mireg never writes over what it reads.
/// `inputs_are` names them in the error ("the input", "one of the inputs", ...).
pub fn check_not_an_input<'a>(
    output: &Path,
    inputs: impl IntoIterator<Item = &'a Path>,
    inputs_are: &str,
) -> Result<()> {
    if inputs.into_iter().any(|input| same_file(input, output)) {
        return Err(Error::InvalidInput(format!(
            "output {} is {inputs_are}; mireg never writes over its input",
            output.display()
        )));
    }
    Ok(())
}

/// Whether `a` and `b` are the same file (same device and inode; same canonical path elsewhere).
/// False when either does not exist.
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(a), std::fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

fn target_dir(target: &Path) -> PathBuf {
    match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn file_name(target: &Path) -> String {
    target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

impl PendingFile {
    /// Opens a file that will become `target`, after [`check_target`].
    pub fn create(target: &Path, overwrite: bool) -> Result<(File, Self)> {
        check_target(target, overwrite)?;
        let dir = target_dir(target);
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        {
            use std::os::unix::fs::OpenOptionsExt;
            let unnamed = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .custom_flags(libc::O_TMPFILE)
                .mode(0o600)
                .open(&dir);
            if let Ok(file) = unnamed {
                let pending = Self {
                    target: target.to_path_buf(),
                    overwrite,
                    temp: Temp::Unnamed,
                };
                return Ok((file, pending));
            }
        }
        remove_stale_partials(&dir, &file_name(target));
        let temp = tempfile::Builder::new()
            .prefix(&partial_prefix(&file_name(target), std::process::id()))
            .suffix(".partial")
            .tempfile_in(&dir)
            .map_err(|e| io_err(&dir, e))?;
        let (file, path) = temp.into_parts();
        signals::remove_on_signal(&path);
        let pending = Self {
            target: target.to_path_buf(),
            overwrite,
            temp: Temp::Named(path),
        };
        Ok((file, pending))
    }

    /// The target path.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Makes `file` (the one [`create`](Self::create) returned, fully written) an ordinary file
    /// (mode 0644), syncs it and puts it at the target: atomically, and without replacing a file
    /// that appeared there meanwhile unless `overwrite` was set. On error nothing is left at the
    /// target path.
    pub fn commit(self, file: File) -> Result<()> {
        let target = &self.target;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            file.set_permissions(std::fs::Permissions::from_mode(0o644))
                .map_err(|e| io_err(target, e))?;
        }
        file.sync_all().map_err(|e| io_err(target, e))?;
        check_target(target, self.overwrite)?;
        match self.temp {
            #[cfg(all(target_os = "linux", target_env = "gnu"))]
            Temp::Unnamed => {
                if !self.overwrite {
                    return link_unnamed(&file, target);
                }
                // Link under a hidden name, then rename over the target (rename is atomic; a
                // link cannot replace). Only this instant has a name beside the target.
                let dir = target_dir(target);
                let name = partial_prefix(&file_name(target), std::process::id());
                for k in 0u32.. {
                    let beside = dir.join(format!("{name}link{k}.partial"));
                    match link_unnamed(&file, &beside) {
                        Ok(()) => {
                            signals::remove_on_signal(&beside);
                            let renamed = std::fs::rename(&beside, target);
                            signals::forget(&beside);
                            return renamed.map_err(|e| {
                                let _ = std::fs::remove_file(&beside);
                                io_err(target, e)
                            });
                        }
                        Err(Error::Io { source, .. })
                            if source.kind() == std::io::ErrorKind::AlreadyExists && k < 100 => {}
                        Err(e) => return Err(e),
                    }
                }
                unreachable!("the loop returns")
            }
            Temp::Named(path) => {
                drop(file);
                signals::forget(&path);
                if self.overwrite {
                    path.persist(target).map_err(|e| io_err(target, e.error))
                } else {
                    path.persist_noclobber(target)
                        .map_err(|e| io_err(target, e.error))
                }
            }
        }
    }
}

/// Gives the `O_TMPFILE` file `file` the name `at` (fails if `at` exists).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn link_unnamed(file: &File, at: &Path) -> Result<()> {
    use std::ffi::CString;
    use std::os::fd::AsRawFd;
    use std::os::unix::ffi::OsStrExt;
    let c_at = CString::new(at.as_os_str().as_bytes())
        .map_err(|_| Error::InvalidInput(format!("{}: path holds a NUL byte", at.display())))?;
    let proc_path = CString::new(format!("/proc/self/fd/{}", file.as_raw_fd())).expect("no NUL");
    // SAFETY: both paths are NUL-terminated strings that live across the calls; the descriptor is
    // open for as long as `file` lives.
    let linked = unsafe {
        libc::linkat(
            libc::AT_FDCWD,
            proc_path.as_ptr(),
            libc::AT_FDCWD,
            c_at.as_ptr(),
            libc::AT_SYMLINK_FOLLOW,
        )
    };
    if linked == 0 {
        return Ok(());
    }
    let first = std::io::Error::last_os_error();
    if first.kind() != std::io::ErrorKind::NotFound {
        return Err(io_err(at, first));
    }
    // No /proc: AT_EMPTY_PATH (needs CAP_DAC_READ_SEARCH).
    // SAFETY: as above; the empty path is a valid NUL-terminated string.
    let linked = unsafe {
        libc::linkat(
            file.as_raw_fd(),
            c"".as_ptr(),
            libc::AT_FDCWD,
            c_at.as_ptr(),
            libc::AT_EMPTY_PATH,
        )
    };
    if linked == 0 {
        Ok(())
    } else {
        Err(io_err(at, std::io::Error::last_os_error()))
    }
}

/// The start of the hidden name of a partial output of process `pid` towards file `name`.
fn partial_prefix(name: &str, pid: u32) -> String {
    format!(".{name}.mireg-{pid}-")
}

/// Removes partial outputs towards `name` in `dir` left by processes that no longer run.
fn remove_stale_partials(dir: &Path, name: &str) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let prefix = format!(".{name}.mireg-");
    for entry in entries.flatten() {
        let file = entry.file_name();
        let Some(rest) = file.to_str().and_then(|f| f.strip_prefix(&prefix)) else {
            continue;
        };
        let Some(pid) = rest.split('-').next().and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        if rest.ends_with(".partial") && !process_runs(pid) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

#[cfg(target_os = "linux")]
fn process_runs(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
}

/// Elsewhere a partial file is only removed by the run that made it.
#[cfg(not(target_os = "linux"))]
fn process_runs(_pid: u32) -> bool {
    true
}

pub use signals::{forget_dir, install_signal_handlers, remove_dir_on_signal};

/// `SIGINT`/`SIGTERM`: remove the named partial outputs and temporary directories, say so on one
/// line, exit 130/143.
mod signals {
    use std::path::Path;

    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    mod imp {
        use std::cell::UnsafeCell;
        use std::os::unix::ffi::OsStrExt;
        use std::path::Path;
        use std::sync::atomic::{AtomicU8, Ordering};

        /// Longest path kept for removal, NUL included (Linux `PATH_MAX`).
        const MAX_PATH: usize = 4096;

        /// A path the handler removes: static storage (the handler never reads freed memory,
        /// and nothing is allocated or leaked), written only while its state is `FREE`/`WRITING`.
        struct Slot {
            state: AtomicU8,
            path: UnsafeCell<[u8; MAX_PATH]>,
        }

        const FREE: u8 = 0;
        const WRITING: u8 = 1;
        const READY: u8 = 2;

        // SAFETY: `path` is written only by the thread that moved `state` from FREE to WRITING,
        // and read only while `state` is READY.
        unsafe impl Sync for Slot {}

        static SLOTS: [Slot; 8] = [const {
            Slot {
                state: AtomicU8::new(FREE),
                path: UnsafeCell::new([0; MAX_PATH]),
            }
        }; 8];

        /// Temporary directories the handler empties and removes.
        static DIR_SLOTS: [Slot; 4] = [const {
            Slot {
                state: AtomicU8::new(FREE),
                path: UnsafeCell::new([0; MAX_PATH]),
            }
        }; 4];

        pub fn remove_on_signal(path: &Path) {
            hold(&SLOTS, path);
        }

        pub fn forget(path: &Path) {
            release(&SLOTS, path);
        }

        pub fn remove_dir_on_signal(path: &Path) {
            hold(&DIR_SLOTS, path);
        }

        pub fn forget_dir(path: &Path) {
            release(&DIR_SLOTS, path);
        }

        /// Stores `path` in a free slot of `slots` (none free, or a path too long: not kept).
        fn hold(slots: &[Slot], path: &Path) {
            let bytes = path.as_os_str().as_bytes();
            if bytes.len() >= MAX_PATH || bytes.contains(&0) {
                return;
            }
            for slot in slots {
                if slot
                    .state
                    .compare_exchange(FREE, WRITING, Ordering::SeqCst, Ordering::SeqCst)
                    .is_ok()
                {
                    // SAFETY: this thread owns the slot (state WRITING) until it publishes it.
                    let buf = unsafe { &mut *slot.path.get() };
                    buf[..bytes.len()].copy_from_slice(bytes);
                    buf[bytes.len()] = 0;
                    slot.state.store(READY, Ordering::SeqCst);
                    return;
                }
            }
        }

        /// Frees the slots of `slots` that hold `path`.
        fn release(slots: &[Slot], path: &Path) {
            let bytes = path.as_os_str().as_bytes();
            for slot in slots {
                if slot.state.load(Ordering::SeqCst) != READY {
                    continue;
                }
                // SAFETY: READY slots are not written; a NUL ends the stored path.
                let buf = unsafe { &*slot.path.get() };
                let end = buf.iter().position(|&b| b == 0).unwrap_or(MAX_PATH);
                if &buf[..end] == bytes {
                    slot.state.store(FREE, Ordering::SeqCst);
                }
            }
        }

        /// Unlinks every entry of the directory at `path` (files only: our temporary
        /// directories hold no subdirectory), then the directory. Only system calls (open,
        /// getdents64, unlinkat, lseek, close, rmdir): safe in a signal handler.
        ///
        /// # Safety
        /// `path` is a NUL-terminated path.
        unsafe fn remove_dir(path: *const libc::c_char) {
            // SAFETY: a NUL-terminated path; the buffer outlives the calls that fill it.
            unsafe {
                let fd = libc::open(path, libc::O_RDONLY | libc::O_DIRECTORY | libc::O_CLOEXEC);
                if fd >= 0 {
                    // linux_dirent64 records: d_ino (8), d_off (8), d_reclen (2), d_type (1),
                    // d_name (NUL-terminated); 8-byte aligned.
                    let mut buf = [0u64; 1024];
                    // Unlinking while reading may hide entries from this pass: read again from
                    // the start until a pass removes nothing (bounded).
                    for _ in 0..16 {
                        let mut removed = false;
                        loop {
                            let n = libc::syscall(
                                libc::SYS_getdents64,
                                fd,
                                buf.as_mut_ptr(),
                                std::mem::size_of_val(&buf),
                            );
                            if n <= 0 {
                                break;
                            }
                            let base = buf.as_ptr().cast::<u8>();
                            let mut off = 0usize;
                            while off < n as usize {
                                let rec = base.add(off);
                                let reclen = u16::from_ne_bytes([*rec.add(16), *rec.add(17)]);
                                let name = rec.add(19);
                                let dot = *name == b'.'
                                    && (*name.add(1) == 0
                                        || (*name.add(1) == b'.' && *name.add(2) == 0));
                                if !dot && libc::unlinkat(fd, name.cast(), 0) == 0 {
                                    removed = true;
                                }
                                off += reclen.max(1) as usize;
                            }
                        }
                        if !removed {
                            break;
                        }
                        libc::lseek(fd, 0, libc::SEEK_SET);
                    }
                    libc::close(fd);
                }
                libc::rmdir(path);
            }
        }

        extern "C" fn on_signal(sig: libc::c_int) {
            // Only async-signal-safe calls here: unlink, the system calls of `remove_dir`,
            // write, _exit.
            for slot in &SLOTS {
                if slot.state.load(Ordering::SeqCst) == READY {
                    // SAFETY: a READY slot holds a NUL-terminated path in static storage.
                    unsafe { libc::unlink(slot.path.get().cast::<libc::c_char>()) };
                }
            }
            for slot in &DIR_SLOTS {
                if slot.state.load(Ordering::SeqCst) == READY {
                    // SAFETY: a READY slot holds a NUL-terminated path in static storage.
                    unsafe { remove_dir(slot.path.get().cast::<libc::c_char>()) };
                }
            }
            let msg: &[u8] = if sig == libc::SIGINT {
                b"mireg: interrupted (SIGINT); no output written\n"
            } else {
                b"mireg: terminated (SIGTERM); no output written\n"
            };
            // SAFETY: write and _exit are async-signal-safe; the buffer is static.
            unsafe {
                libc::write(2, msg.as_ptr().cast(), msg.len());
                libc::_exit(128 + sig);
            }
        }

        pub fn install() {
            let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            for sig in [libc::SIGINT, libc::SIGTERM] {
                // SAFETY: installs a handler that only makes async-signal-safe calls.
                unsafe { libc::signal(sig, handler) };
            }
        }
    }

    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    mod imp {
        use std::path::Path;
        pub fn remove_on_signal(_path: &Path) {}
        pub fn forget(_path: &Path) {}
        pub fn remove_dir_on_signal(_path: &Path) {}
        pub fn forget_dir(_path: &Path) {}
        pub fn install() {}
    }

    /// Makes `SIGINT` and `SIGTERM` end the process at once with exit code 130 / 143 and one line
    /// on stderr, after removing any partial output file that has a name (outputs being written
    /// as unnamed files vanish by themselves). Call it once, at the start of a command that
    /// writes files.
    pub fn install_signal_handlers() {
        imp::install();
    }

    pub(super) fn remove_on_signal(path: &Path) {
        imp::remove_on_signal(path);
    }

    pub(super) fn forget(path: &Path) {
        imp::forget(path);
    }

    /// Has the signal handler empty and remove the directory at `path` (a temporary directory
    /// of files only, e.g. the private copies of a ROS 2 bag); at most 4 at a time, and a path
    /// of at most 4095 bytes (others are left to the next run's clean-up of stale directories).
    pub fn remove_dir_on_signal(path: &Path) {
        imp::remove_dir_on_signal(path);
    }

    /// Undoes [`remove_dir_on_signal`]: call it before removing the directory.
    pub fn forget_dir(path: &Path) {
        imp::forget_dir(path);
    }
}
