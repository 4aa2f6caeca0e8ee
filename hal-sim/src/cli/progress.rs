//! One progress-bar style for every long command (on stderr; hidden when stderr is not a
//! terminal, so reports, pipes and tests print nothing extra).

use indicatif::{ProgressBar, ProgressStyle};

/// A bar of `len` units named `label` ("rescues", "runs", …).
pub fn bar(len: u64, label: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{bar:40}} {{pos}}/{{len}} {label}, {{elapsed}} elapsed, eta {{eta}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar
}
