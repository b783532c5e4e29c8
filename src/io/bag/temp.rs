//! The temporary files of a ROS 2 bag: decompressed copies of a `file`-mode bag's files, private
//! copies of a `.db3` with its write-ahead log.
//!
//! Nothing named is left behind, whatever ends the process:
//! - a decompressed MCAP file is an unnamed file (Linux `O_TMPFILE`) in `$TMPDIR`, read through
//!   its `/proc/self/fd/N` link: the kernel frees it when the process ends, Ctrl-C, SIGTERM and
//!   SIGKILL included. Where the file system cannot make unnamed files, and for SQLite files
//!   (a decompressed `.db3`, the private copies of a `.db3` with its `-wal`: SQLite opens files
//!   by name), the files go into a directory `$TMPDIR/.mireg-bag-PID-XXXXXX`, removed when the
//!   bag is dropped, and by the signal handler on Ctrl-C or SIGTERM
//!   ([`crate::io::atomic_file::remove_dir_on_signal`]);
//! - such a directory left by a process that was killed (no `/proc/PID`) is removed by the
//!   next run that opens a bag ([`remove_stale`]).

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::Result;
use crate::io::io_err;

/// Prefix of our temporary directories in `$TMPDIR`; the process id and a random suffix follow.
pub const TEMP_PREFIX: &str = ".mireg-bag-";

/// The temporary files of one bag; dropping it removes them.
#[derive(Debug, Default)]
pub struct TempFiles {
    /// Unnamed files, each read through `/proc/self/fd/N` while it is held here.
    unnamed: Vec<File>,
    /// The named directory, made on first need.
    dir: Option<tempfile::TempDir>,
}

impl TempFiles {
    /// A new file for writing: with `may_be_unnamed`, unnamed where the file system allows it,
    /// else `name` in our directory (made on first need, after the stale ones of dead processes
    /// are removed). Returns the file and the path it is read through. (SQLite resolves the
    /// `/proc/self/fd/N` link to a name that no longer exists: its files must be named.)
    pub fn create(&mut self, name: &str, may_be_unnamed: bool) -> Result<(File, PathBuf)> {
        let tmp = std::env::temp_dir();
        remove_stale(&tmp);
        if let Some(file) = unnamed(&tmp).filter(|_| may_be_unnamed) {
            // The link names the descriptor held here, which outlives the caller's.
            let held = file.try_clone().map_err(|e| io_err(&tmp, e))?;
            let path = fd_path(&held);
            self.unnamed.push(held);
            return Ok((file, path));
        }
        let path = self.dir()?.join(name);
        let file = File::create(&path).map_err(|e| io_err(&path, e))?;
        Ok((file, path))
    }

    /// Our named directory, when made.
    pub fn path(&self) -> Option<&Path> {
        self.dir.as_ref().map(|d| d.path())
    }

    /// Our named directory `$TMPDIR/.mireg-bag-PID-XXXXXX`, made on first call.
    pub fn dir(&mut self) -> Result<&Path> {
        if self.dir.is_none() {
            let tmp = std::env::temp_dir();
            remove_stale(&tmp);
            let dir = tempfile::Builder::new()
                .prefix(&format!("{TEMP_PREFIX}{}-", std::process::id()))
                .tempdir_in(&tmp)
                .map_err(|e| io_err(&tmp, e))?;
            crate::io::atomic_file::remove_dir_on_signal(dir.path());
            self.dir = Some(dir);
        }
        Ok(self.dir.as_ref().expect("made above").path())
    }
}

impl Drop for TempFiles {
    fn drop(&mut self) {
        // The directory itself is removed when `dir` is dropped, after this.
        if let Some(dir) = &self.dir {
            crate::io::atomic_file::forget_dir(dir.path());
        }
    }
}

/// An unnamed file in `dir`; `None` off Linux or where the file system cannot make one.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn unnamed(dir: &Path) -> Option<File> {
    use std::os::unix::fs::OpenOptionsExt;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .mode(0o600)
        .custom_flags(libc::O_TMPFILE)
        .open(dir)
        .ok()?;
    fd_path(&file).exists().then_some(file)
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn unnamed(_dir: &Path) -> Option<File> {
    None
}

/// The `/proc/self/fd/N` link of `file`.
#[cfg(unix)]
fn fd_path(file: &File) -> PathBuf {
    use std::os::fd::AsRawFd;
    PathBuf::from(format!("/proc/self/fd/{}", file.as_raw_fd()))
}

#[cfg(not(unix))]
fn fd_path(_file: &File) -> PathBuf {
    unreachable!("no unnamed files off Linux")
}

/// Removes the directories `.mireg-bag-PID-*` in `tmp` whose process is gone (Linux: no
/// `/proc/PID`) and that belong to this user; errors are ignored (another run may be removing
/// the same directory). Off Linux, nothing is removed.
pub fn remove_stale(tmp: &Path) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::MetadataExt;
        let Ok(entries) = std::fs::read_dir(tmp) else {
            return;
        };
        // SAFETY: geteuid has no preconditions.
        #[cfg(target_env = "gnu")]
        let me = Some(unsafe { libc::geteuid() });
        #[cfg(not(target_env = "gnu"))]
        let me: Option<u32> = None;
        for e in entries.flatten() {
            let name = e.file_name();
            let Some(pid) = name
                .to_str()
                .and_then(|n| n.strip_prefix(TEMP_PREFIX))
                .and_then(|rest| rest.split_once('-'))
                .and_then(|(pid, _)| pid.parse::<u32>().ok())
            else {
                continue;
            };
            let path = e.path();
            let Ok(meta) = std::fs::symlink_metadata(&path) else {
                continue;
            };
            let ours = me.is_none_or(|uid| meta.uid() == uid);
            if meta.is_dir() && ours && !Path::new(&format!("/proc/{pid}")).exists() {
                let _ = std::fs::remove_dir_all(&path);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = tmp;
}
