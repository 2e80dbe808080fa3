//! Panics of outside code contained at the call ([`contain_panics`]), and the text of a
//! panic's payload ([`panic_text`]).

thread_local! {
    static CONTAINING: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// Runs `f`, a call into a dependency's parser of outside data that is known to panic on
/// some malformed inputs (`matrw`, the `mcap` reader's arithmetic), and turns a panic
/// into `Err` with its message. While `f` runs, [`panic_is_contained`] is true on this
/// thread, so a panic hook can tell a contained parser failure (a bad file: one error
/// follows) from a bug of ours (logged at error level).
pub fn contain_panics<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    CONTAINING.with(|c| c.set(c.get() + 1));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    CONTAINING.with(|c| c.set(c.get().saturating_sub(1)));
    result.map_err(|payload| panic_text(payload.as_ref()))
}

/// True while [`contain_panics`] runs its function on this thread.
pub fn panic_is_contained() -> bool {
    CONTAINING.with(|c| c.get() > 0)
}

/// The text of a panic's payload (`panic!("…")` gives a `&str` or a `String`).
pub fn panic_text(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic".into())
}
