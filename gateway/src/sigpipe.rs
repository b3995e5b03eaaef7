//! Printing commands end quietly when the reader of their output goes away.
//!
//! Rust programs start with SIGPIPE ignored, so a write to a closed pipe returns `EPIPE` and
//! `println!` panics on it: `gateway check --config FILE | head -1` printed a panic message once
//! `head` had its line. The commands that only print (`check`, `tags`, `fleet`, `scan`) take the
//! Unix default back instead: the process ends on SIGPIPE, as `grep` or `cat` would. `run` and
//! `demo` keep SIGPIPE ignored: they write to sockets (which never raise SIGPIPE: std and tokio
//! send with `MSG_NOSIGNAL`) and to their log, and must not end because a log reader did.
#![allow(unsafe_code)]

/// Restores the default action of SIGPIPE (end the process) for a command that only prints.
pub fn end_on_closed_stdout() {
    #[cfg(unix)]
    {
        // SAFETY: `signal` with SIG_DFL installs no handler of ours; it only changes the
        // disposition the runtime set, before any other thread exists.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
}
