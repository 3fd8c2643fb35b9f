//! Progress display on standard error: spinners for steps whose length is unknown, hidden
//! when standard error is not a terminal (CI logs stay clean).

use indicatif::{ProgressBar, ProgressStyle};
use std::time::Duration;

/// Refresh interval of spinners.
const TICK: Duration = Duration::from_millis(120);

/// A spinner with a message, ticking until `finish` is called or it is dropped.
pub fn spinner(message: impl Into<String>) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.set_message(message.into());
    bar.enable_steady_tick(TICK);
    bar
}
