//! Panics, as the user sees them.
//!
//! With `RUST_BACKTRACE` set, Rust reports a panic as it always does. Without
//! it, [`install_hook`] makes a panic one line on stderr, `gardefou: internal
//! error: … at file:line`, or nothing while a [`Containment`] is alive: a
//! library that expects a dependency to panic on bad input (polars on a
//! malformed Parquet file) catches the panic and reports it as the input's
//! error, which the user then reads alone. A panic of the main thread is
//! left to the binary, which catches it and prints the same line.

use std::sync::atomic::{AtomicUsize, Ordering};

/// How many containments are alive, on any thread: a dependency may panic on
/// a thread of its own pool, not the one that contains it.
static CONTAINED: AtomicUsize = AtomicUsize::new(0);

/// Installs the hook, unless `RUST_BACKTRACE` asks for Rust's own report.
pub fn install_hook() {
    if std::env::var_os("RUST_BACKTRACE").is_some() {
        return;
    }
    std::panic::set_hook(Box::new(|info| {
        // `main` reports its own panics when it catches them.
        let main = std::thread::current().name() == Some("main");
        if main || expected() {
            return;
        }
        let location = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!(
            "gardefou: internal error: {}{location} (RUST_BACKTRACE=1 shows where)",
            message(info.payload())
        );
    }));
}

/// What a panic said, if it said it as text.
pub fn message(payload: &(dyn std::any::Any + Send)) -> String {
    match (
        payload.downcast_ref::<&str>(),
        payload.downcast_ref::<String>(),
    ) {
        (Some(message), _) => (*message).to_string(),
        (_, Some(message)) => message.clone(),
        _ => "a panic without a message".to_string(),
    }
}

/// Whether a [`Containment`] is alive on some thread: a panic now is one its
/// catcher reports.
pub fn contained() -> bool {
    CONTAINED.load(Ordering::SeqCst) > 0
}

/// Whether a panic on this thread, now, is reported by someone else: a
/// [`Containment`] is alive, or this is one of polars' pool threads. polars
/// turns a panic of its pool into the error of the query that ran it, which
/// the log layer reports; one task may panic after that query has already
/// failed and its containment ended.
pub fn expected() -> bool {
    let pool = std::thread::current()
        .name()
        .is_some_and(|name| name.starts_with("async-executor") || name.starts_with("polars"));
    contained() || pool
}

/// While alive, panics are not printed: their catcher reports them.
#[must_use = "panics are contained only while this lives"]
pub struct Containment(());

impl Containment {
    /// Starts containing panics.
    pub fn start() -> Containment {
        CONTAINED.fetch_add(1, Ordering::SeqCst);
        Containment(())
    }
}

impl Drop for Containment {
    fn drop(&mut self) {
        CONTAINED.fetch_sub(1, Ordering::SeqCst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panics_on_polars_threads_or_under_a_containment_are_expected() {
        let on = |name: &str| {
            let name = name.to_string();
            std::thread::Builder::new()
                .name(name)
                .spawn(expected)
                .expect("a thread")
                .join()
                .expect("joined")
        };
        assert!(on("async-executor-1") && on("polars-3"));
        assert!(!on("gardefou-read") || contained());
        let quiet = Containment::start();
        assert!(on("gardefou-read"));
        drop(quiet);
    }
}
