//! Progress on stderr for reports that take more than a second: a bar over the report's stages,
//! hidden automatically when stderr is not a terminal (CI logs, pipes).

use indicatif::{ProgressBar, ProgressStyle};
use std::time::Duration;

/// A bar over `stages` named steps.
pub fn stages(stages: u64) -> ProgressBar {
    let bar = ProgressBar::new(stages);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.enable_steady_tick(Duration::from_millis(100));
    bar
}
