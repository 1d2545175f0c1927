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
    if bar.is_hidden() && (done.is_multiple_of(PLAIN_PROGRESS_EVERY) || done == total) {
        println!(
            "[{:>6.0} s] step {done}/{total} {message}",
            bar.elapsed().as_secs_f64()
        );
    }
}

/// Plain progress lines of a phase (`done` of `total` images) when `bar` is hidden: at the
/// start, about every tenth and at the end.
pub fn phase(bar: &ProgressBar, name: &str, done: usize, total: usize) {
    let every = total.div_ceil(10).max(1);
    if bar.is_hidden() && (done == 0 || done == total || done.is_multiple_of(every)) {
        println!(
            "[{:>6.0} s] {name}: {done}/{total} images",
            bar.elapsed().as_secs_f64()
        );
    }
}

/// The bar of a phase (generation, validation, final evaluation) under the run's bar while the
/// phase lasts: created at its first report, cleared at its last.
#[derive(Default)]
pub struct PhaseBar {
    bar: Option<ProgressBar>,
}

impl PhaseBar {
    /// Shows `done` of `total` images of the phase `name` in `multi`.
    pub fn update(
        &mut self,
        multi: &indicatif::MultiProgress,
        name: &str,
        done: usize,
        total: usize,
    ) {
        let bar = self.bar.get_or_insert_with(|| {
            let bar = multi.add(ProgressBar::new(total as u64));
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} {prefix} [{elapsed_precise}] {bar:30} {pos}/{len} images (eta {eta})",
                )
                .expect("static progress template"),
            );
            bar.set_prefix(name.to_string());
            bar
        });
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        if done >= total {
            bar.finish_and_clear();
            multi.remove(bar);
            self.bar = None;
        }
    }
}
