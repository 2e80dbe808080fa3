//! Process-wide set-up: how panics are reported, and the file-size signal.

/// Panics print one line at error level saying where (the first of each place; later
/// ones at debug level): input errors are values, so a panic is a bug, and the services
/// catch it per message and go on (`nodes::EstimatorNode::handle`).
pub fn install_panic_hook() {
    static SEEN: std::sync::Mutex<std::collections::BTreeSet<String>> =
        std::sync::Mutex::new(std::collections::BTreeSet::new());
    std::panic::set_hook(Box::new(|info| {
        let location = info
            .location()
            .map_or_else(|| "an unknown place".to_string(), |l| l.to_string());
        let message = posestream::error::panic_text(info.payload());
        let first = SEEN
            .lock()
            .map(|mut seen| seen.insert(location.clone()))
            .unwrap_or(true);
        let thread = std::thread::current()
            .name()
            .map(|n| format!(" (thread {n})"))
            .unwrap_or_default();
        // A dependency's parser failing on a bad file: the caller reports the file.
        if posestream::error::panic_is_contained() {
            tracing::debug!("contained panic at {location}{thread}: {message}");
        } else if first {
            tracing::error!("panic at {location}{thread}: {message}");
        } else {
            tracing::debug!("panic at {location}{thread}: {message}");
        }
    }));
}

/// A full file-size budget (`ulimit -f`) makes writes fail with `EFBIG`, which the
/// recorder reports, instead of killing the process with `SIGXFSZ`.
pub fn ignore_file_size_signal() {
    // SAFETY: setting a signal's disposition to "ignore" at start-up, before any other
    // thread exists, has no memory-safety preconditions.
    #[allow(unsafe_code, reason = "libc::signal is an FFI call; see SAFETY above")]
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}
