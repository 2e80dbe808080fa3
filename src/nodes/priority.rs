//! The image detector's threads below the rest of the process in the scheduler's eyes
//! (`[detector] nice`). With the detector and the estimator in one process (`posestream
//! run`) on few cores, the next frame's detection (the landmark model on every core)
//! otherwise takes the cores from the estimator finishing the frame before: a frame
//! already detected now gets its skeleton published first (README, "Against MediaPipe
//! Pose").

/// Makes the calling thread at least `nice` nice (Linux's nice values, 0-19: the
/// thread's own, which threads it starts later inherit; never less nice than it is).
/// Elsewhere nothing; a refusal is logged, not an error (the detector runs as before).
#[allow(
    unsafe_code,
    reason = "getpriority/setpriority are FFI calls; see SAFETY below"
)]
pub fn at_least(nice: u8) {
    if nice == 0 {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        let now = this_thread_nice();
        let target = now.max(i32::from(nice.min(19)));
        if target == now {
            return;
        }
        // SAFETY: a system call on this thread's own id, no pointers.
        let set =
            unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, target) };
        // Said once, not once per thread.
        static SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
        if set != 0 && !SAID.swap(true, std::sync::atomic::Ordering::Relaxed) {
            tracing::warn!(
                "the detector's threads stay at nice {now}: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

/// Makes the calling thread and every worker of rayon's global pool (the detector's
/// parallel model runs) at least `nice` nice ([`at_least`]). The workers are asked, not
/// waited for (waiting from inside a worker would never end); the pool, made here if
/// it is not yet, is for good: a thread cannot be made less nice again.
pub fn detector_threads_at_least(nice: u8) {
    if nice == 0 {
        return;
    }
    at_least(nice);
    rayon::spawn_broadcast(move |_| at_least(nice));
}

/// The calling thread's nice value (Linux; elsewhere 0).
#[allow(unsafe_code, reason = "getpriority is an FFI call; see SAFETY below")]
pub fn this_thread_nice() -> i32 {
    #[cfg(target_os = "linux")]
    // SAFETY: a system call on this thread's own id, no pointers.
    unsafe {
        libc::getpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t)
    }
    #[cfg(not(target_os = "linux"))]
    0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[cfg(target_os = "linux")]
    fn a_thread_made_nicer_stays_so_and_so_do_the_threads_it_starts() {
        let own = this_thread_nice();
        let named = |name: &str| std::thread::Builder::new().name(name.into());
        named("lowered")
            .spawn(move || {
                let before = this_thread_nice();
                at_least(3);
                let after = this_thread_nice();
                assert_eq!(after, before.max(3));
                let child = named("child")
                    .spawn(this_thread_nice)
                    .expect("starts")
                    .join()
                    .expect("joins");
                assert_eq!(child, after);
                // Not lowered twice, never less nice, never past 19.
                at_least(3);
                assert_eq!(this_thread_nice(), after);
                at_least(1);
                assert_eq!(this_thread_nice(), after);
                at_least(30);
                assert_eq!(this_thread_nice(), 19);
            })
            .expect("starts")
            .join()
            .expect("the thread ran");
        // Other threads keep theirs.
        assert_eq!(this_thread_nice(), own);
    }
}
