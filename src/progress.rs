//! The progress bar `build` and `verify` draw on a terminal: one place for
//! its look, so neither command depends on the other for it.

/// A progress bar on stderr over `len` items named `what` (`"chunks"`), or a
/// hidden one where `enabled` is false (not a terminal, or in tests).
pub(crate) fn bar(enabled: bool, len: u64, what: &str) -> indicatif::ProgressBar {
    if !enabled {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!("[{{bar:40}}] {{pos}}/{{len}} {what} {{elapsed}}"))
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar
}
