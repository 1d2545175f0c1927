//! Lines that reach the user whether or not a progress bar is drawn: above the bar on a
//! terminal, as plain lines on stdout when the bar is hidden (output to a file, `nohup`, a batch
//! scheduler), where indicatif would drop them.

use indicatif::ProgressBar;

/// Steps between plain progress lines when the bar is hidden.
pub const PLAIN_PROGRESS_EVERY: u64 = 50;

/// Prints `line` above `bar`, or on stdout when `bar` is hidden.
pub fn line(bar: &ProgressBar, line: impl AsRef<str>) {
    if bar.is_hidden() {
        println!("{}", line.as_ref());
    } else {
        bar.println(line.as_ref());
    }
}

/// A progress line for step `done` of `total` when the bar is hidden (every
/// [`PLAIN_PROGRESS_EVERY`] steps and at the last), with the bar's elapsed time.
pub fn progress(bar: &ProgressBar, done: u64, total: u64, message: &str) {
    if bar.is_hidden() && (done % PLAIN_PROGRESS_EVERY == 0 || done == total) {
        println!(
            "[{:>6.0} s] step {done}/{total} {message}",
            bar.elapsed().as_secs_f64()
        );
    }
}
