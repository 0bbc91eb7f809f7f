//! The progress bars of the long passes (perceiving images, extracting ORB
//! features, inserting into a service, replaying a stream).
//!
//! One helper, shared by every pass, so that they all look alike and stay
//! quiet when stderr is not a terminal (logs and CI keep only the results);
//! a leaf module so that any pass can use it without taking in the run.

use std::io::IsTerminal;

/// A bar of `len` steps labelled `what`, hidden unless stderr is a terminal.
pub(crate) fn progress(len: usize, what: &str) -> indicatif::ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(len as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>24} [{bar:30}] {pos}/{len} {elapsed}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}
