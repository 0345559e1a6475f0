//! The one progress bar on screen (stderr, hidden when it is not a terminal), which log output
//! suspends so that log lines are never drawn over it.

use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// The progress bar on screen, if any: log lines are printed around it.
static PROGRESS: Mutex<Option<ProgressBar>> = Mutex::new(None);

/// A progress bar of `len` steps drawn with `template` (indicatif's syntax), shown as the one bar that
/// log output suspends until [`clear`].
pub fn bar(len: u64, template: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style.progress_chars("=> "));
    }
    set(Some(bar.clone()));
    bar
}

/// Removes `bar` from the screen; log output goes straight to stderr again.
pub fn clear(bar: &ProgressBar) {
    bar.finish_and_clear();
    set(None);
}

fn set(bar: Option<ProgressBar>) {
    if let Ok(mut g) = PROGRESS.lock() {
        *g = bar;
    }
}

/// Runs `f` with the bar on screen (if any) cleared for the duration.
pub fn suspended(f: impl FnOnce()) {
    let bar = PROGRESS.lock().ok().and_then(|g| g.clone());
    match bar {
        Some(bar) => bar.suspend(f),
        None => f(),
    }
}
