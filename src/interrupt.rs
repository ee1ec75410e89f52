//! Cleaning up after an interrupted run: what a verb registers here is
//! removed if the process gets SIGINT, SIGTERM or SIGHUP, and the process
//! then exits as the signal would have ended it (128 + its number).

use std::path::PathBuf;

/// Removes the directory `dir` if the process is interrupted from now on.
/// Call it before starting threads: they inherit the blocked signals, so
/// that only the watcher thread receives them.
#[cfg(unix)]
pub fn remove_on_interrupt(dir: PathBuf) {
    // SAFETY: `sigset_t` is plain data, initialised by `sigemptyset` before
    // use; the calls only read and write the set and this thread's mask.
    let set = unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&raw mut set);
        for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
            libc::sigaddset(&raw mut set, signal);
        }
        libc::pthread_sigmask(libc::SIG_BLOCK, &raw const set, std::ptr::null_mut());
        set
    };
    std::thread::spawn(move || {
        let mut signal = 0;
        // SAFETY: `set` is initialised; `sigwait` writes the signal it took.
        if unsafe { libc::sigwait(&raw const set, &raw mut signal) } == 0 {
            let _ = std::fs::remove_dir_all(&dir);
            std::process::exit(128 + signal);
        }
    });
}

/// Elsewhere, an interrupted run leaves its staging for the next run.
#[cfg(not(unix))]
pub fn remove_on_interrupt(_dir: PathBuf) {}
