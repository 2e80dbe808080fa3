//! LiteRT's own log lines, passed through `tracing`.
//!
//! LiteRT 2.3 writes `INFO: [...]` and `WARNING: [...]` lines to stderr whenever an
//! environment or a compiled model is made or destroyed (which accelerators it tried, the
//! XNNPACK delegate), and its C API exports no logger setting (`LiteRtSetMinLoggerSeverity`
//! is not in the wheel's `libLiteRt.so`). So those calls run with file descriptor 2 pointed
//! at an anonymous memory file ([`quietly`]); afterwards each line written is passed on:
//! LiteRT's lines through `tracing` (target `litert`: INFO at debug; the warnings that the
//! GPU and NPU accelerators are absent, expected since only the CPU is asked for, at debug;
//! other warnings and errors at warn), anything else (another thread's output in that
//! moment) to stderr unchanged. `RUST_LOG=litert=debug` shows them all.

use std::io::{Read, Seek, Write};
use std::sync::{Mutex, PoisonError};

/// Bytes of a call's output read back at most (LiteRT writes a few hundred).
const KEPT: u64 = 64 * 1024;

/// One redirection at a time, process-wide (file descriptor 2 is the process's).
static REDIRECT: Mutex<()> = Mutex::new(());

/// Runs `call` with stderr captured, then passes what it wrote on (module docs).
pub fn quietly<T>(call: impl FnOnce() -> T) -> T {
    let _one = REDIRECT.lock().unwrap_or_else(PoisonError::into_inner);
    let Some(redirect) = Redirect::start() else {
        return call();
    };
    let out = call();
    let text = redirect.finish();
    pass_on(&text);
    out
}

/// What [`pass_on`] does with a line.
#[derive(Debug, PartialEq, Eq)]
enum Line<'a> {
    /// LiteRT's chatter: debug.
    Debug(&'a str),
    /// A LiteRT warning or error worth a user's eyes.
    Warn(&'a str),
    /// Not LiteRT's: back to stderr as it was.
    Other(&'a str),
}

/// LiteRT's warnings that say nothing wrong for us: only the CPU is asked for, so the
/// other accelerators' absence is expected; the person detector's sparse constants
/// (`DENSIFY`) are supported (its outputs equal Python LiteRT's: tests/models.rs).
const EXPECTED: [&str; 4] = [
    "accelerator could not be loaded",
    "NPU accelerator",
    "GPU accelerator",
    "Sparsity tensors may not yet be fully supported",
];

fn classify(line: &str) -> Line<'_> {
    if let Some(rest) = line.strip_prefix("INFO: ") {
        return Line::Debug(rest);
    }
    for prefix in ["WARNING: ", "ERROR: "] {
        if let Some(rest) = line.strip_prefix(prefix) {
            return if EXPECTED.iter().any(|e| rest.contains(e)) {
                Line::Debug(rest)
            } else {
                Line::Warn(rest)
            };
        }
    }
    Line::Other(line)
}

fn pass_on(text: &str) {
    let mut others = String::new();
    let mut warned: Vec<&str> = Vec::new();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        match classify(line) {
            Line::Debug(l) => tracing::debug!(target: "litert", "{l}"),
            // Once per call: LiteRT repeats a warning per tensor.
            Line::Warn(l) if !warned.contains(&l) => {
                warned.push(l);
                tracing::warn!(target: "litert", "{l}");
            }
            Line::Warn(_) => {}
            Line::Other(l) => {
                others.push_str(l);
                others.push('\n');
            }
        }
    }
    if !others.is_empty() {
        let _ = std::io::stderr().write_all(others.as_bytes());
    }
}

/// Descriptor 2 on a memory file until [`finish`](Redirect::finish), or until dropped
/// (a panic in the call): then the original stderr is back and what was captured is
/// written to it.
#[cfg(target_os = "linux")]
struct Redirect {
    saved: Option<std::os::fd::OwnedFd>,
    capture: std::fs::File,
}

#[cfg(target_os = "linux")]
impl Redirect {
    #[allow(unsafe_code, reason = "file descriptor 2 swapped with fcntl/dup2")]
    fn start() -> Option<Self> {
        use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
        let _ = std::io::stderr().flush();
        // The original stderr first, close-on-exec (a child another thread spawns
        // meanwhile does not inherit it), at 3 or above; none (stderr closed): no
        // redirection, so descriptor 2 is never taken from whoever holds it.
        // SAFETY: F_DUPFD_CLOEXEC returns a new descriptor we own, or -1.
        let saved = unsafe { libc::fcntl(2, libc::F_DUPFD_CLOEXEC, 3) };
        if saved < 0 {
            return None;
        }
        // SAFETY: `saved` is a fresh descriptor owned by nothing else.
        let saved = unsafe { OwnedFd::from_raw_fd(saved) };
        // SAFETY: memfd_create with a NUL-terminated name returns a new descriptor we
        // own, or -1; below 3 only when 0 or 1 was closed: then not used.
        let memfd = unsafe { libc::memfd_create(c"litert-log".as_ptr(), libc::MFD_CLOEXEC) };
        if memfd < 0 {
            return None;
        }
        // SAFETY: `memfd` is a fresh descriptor owned by nothing else.
        let capture = unsafe { std::fs::File::from_raw_fd(memfd) };
        if capture.as_raw_fd() <= 2 {
            return None;
        }
        // SAFETY: both descriptors are open; dup2 replaces descriptor 2 atomically.
        if unsafe { libc::dup2(memfd, 2) } < 0 {
            return None;
        }
        Some(Self {
            saved: Some(saved),
            capture,
        })
    }

    /// Puts the original stderr back and returns what was written meanwhile (at most
    /// `KEPT` bytes; a longer output is said so).
    #[allow(unsafe_code, reason = "file descriptor 2 restored with dup2")]
    fn restore(&mut self) -> Option<String> {
        use std::os::fd::AsRawFd;
        let saved = self.saved.take()?;
        // SAFETY: `saved` is open (owned here); dup2 puts the original stderr back.
        unsafe { libc::dup2(saved.as_raw_fd(), 2) };
        let mut bytes = Vec::new();
        if self.capture.rewind().is_ok() {
            let _ = (&mut self.capture).take(KEPT + 1).read_to_end(&mut bytes);
        }
        let cut = bytes.len() as u64 > KEPT;
        bytes.truncate(KEPT as usize);
        let mut text = String::from_utf8_lossy(&bytes).into_owned();
        if cut {
            text.push_str("\nWARNING: [posestream] LiteRT's output cut at 64 KiB\n");
        }
        Some(text)
    }

    fn finish(mut self) -> String {
        self.restore().unwrap_or_default()
    }
}

#[cfg(target_os = "linux")]
impl Drop for Redirect {
    fn drop(&mut self) {
        // Unwinding from a panic in the call: stderr back, and what it held shown.
        if let Some(text) = self.restore() {
            let _ = std::io::stderr().write_all(text.as_bytes());
        }
    }
}

/// Elsewhere LiteRT's lines go to stderr as they are.
#[cfg(not(target_os = "linux"))]
struct Redirect;

#[cfg(not(target_os = "linux"))]
impl Redirect {
    fn start() -> Option<Self> {
        None
    }

    fn finish(self) -> String {
        String::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn litert_lines_are_told_from_others() {
        assert_eq!(
            classify("INFO: [environment.cc:36] Creating LiteRT environment with options"),
            Line::Debug("[environment.cc:36] Creating LiteRT environment with options")
        );
        assert!(matches!(
            classify(
                "WARNING: [gpu_registry.cc:160] GPU accelerator could not be loaded and registered."
            ),
            Line::Debug(_)
        ));
        assert!(matches!(
            classify(
                "WARNING: [model_load.cc:329] Sparsity tensors may not yet be fully supported."
            ),
            Line::Debug(_)
        ));
        assert!(matches!(
            classify("ERROR: [compiled_model.cc:1] Failed to compile"),
            Line::Warn(_)
        ));
        assert_eq!(
            classify("thread 'x' panicked"),
            Line::Other("thread 'x' panicked")
        );
    }

    #[test]
    fn what_a_call_writes_to_stderr_is_captured_and_the_rest_kept() {
        // The call's own write (as LiteRT's C code does, straight to descriptor 2).
        let got = {
            let _one = REDIRECT.lock().unwrap_or_else(PoisonError::into_inner);
            let redirect = Redirect::start().expect("redirects on Linux");
            #[allow(unsafe_code, reason = "a raw write to descriptor 2, as C code does")]
            // SAFETY: writes a live buffer's bytes to descriptor 2.
            unsafe {
                let text = b"INFO: [x.cc:1] hello\n";
                libc::write(2, text.as_ptr().cast(), text.len());
            }
            redirect.finish()
        };
        // (Another test's thread may have written to stderr meanwhile.)
        assert!(got.contains("INFO: [x.cc:1] hello\n"), "{got}");
        // Descriptor 2 is the original again: a second capture starts empty.
        let again = quietly(|| 7);
        assert_eq!(again, 7);
    }

    #[test]
    fn a_panic_in_the_call_gives_stderr_back() {
        let stderr = || std::fs::read_link("/proc/self/fd/2").expect("fd 2");
        let before = stderr();
        let caught = std::panic::catch_unwind(|| {
            quietly(|| {
                assert!(stderr().to_string_lossy().contains("memfd:litert-log"));
                panic!("inside LiteRT's call");
            })
        });
        assert!(caught.is_err());
        assert_eq!(stderr(), before);
    }
}
