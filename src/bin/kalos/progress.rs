//! A spinner on stderr while a scene loads and its world (BVH, lights) is
//! built: shown only once the work has taken a second, so that small scenes
//! print nothing, and large ones never look hung.

use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use kalos::job::SetupEvent;
use kalos::methods::World;
use kalos::scene::Scene;
use kalos::world::BuildEvent;

/// How long work runs before the spinner appears.
const QUIET: Duration = Duration::from_secs(1);

/// A spinner showing what is being done, drawn once it has run for
/// [`QUIET`]; cleared when dropped.
pub struct Spinner {
    bar: ProgressBar,
    /// Dropped when the work ends, which wakes the thread that shows the
    /// spinner.
    done: Option<mpsc::Sender<()>>,
    shower: Option<JoinHandle<()>>,
}

impl Spinner {
    /// Starts a spinner showing `what`.
    pub fn start(what: &str) -> Spinner {
        let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::hidden());
        if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
            bar.set_style(style);
        }
        bar.set_message(what.to_string());
        let (done, wait) = mpsc::channel::<()>();
        let shower = {
            let bar = bar.clone();
            std::thread::spawn(move || {
                if let Err(mpsc::RecvTimeoutError::Timeout) = wait.recv_timeout(QUIET) {
                    bar.set_draw_target(ProgressDrawTarget::stderr());
                    bar.enable_steady_tick(Duration::from_millis(120));
                }
            })
        };
        Spinner {
            bar,
            done: Some(done),
            shower: Some(shower),
        }
    }

    /// Shows `what` instead.
    pub fn set_message(&self, what: String) {
        self.bar.set_message(what);
    }

    /// Prints `line` on stderr, above the spinner.
    pub fn println(&self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }
}

impl Drop for Spinner {
    fn drop(&mut self) {
        drop(self.done.take());
        if let Some(shower) = self.shower.take() {
            let _ = shower.join();
        }
        self.bar.finish_and_clear();
    }
}

/// Runs `work` with a spinner showing `what`; `work` may change the message
/// through the callback it is given (one [`BuildEvent`] at a time).
/// Warnings are printed at once, above the spinner.
pub fn with_spinner<T>(what: &str, work: impl FnOnce(&mut dyn FnMut(BuildEvent)) -> T) -> T {
    let spinner = Spinner::start(what);
    work(&mut |e| match e {
        BuildEvent::Phase(p) => spinner.set_message(p),
        BuildEvent::Warning(w) => spinner.println(&format!("warning: {w}")),
    })
}

/// [`World::build`] under a spinner.
pub fn build_world(scene: Scene) -> World {
    with_spinner("building the world", |on| World::build(scene, on))
}

/// What a job's setup shows: a spinner while a scene file loads and while
/// the world is built (with the build's phases), and the warnings and notes
/// above it.
#[derive(Default)]
pub struct Setup {
    spinner: Option<Spinner>,
}

impl Setup {
    /// Shows `e`.
    pub fn event(&mut self, e: SetupEvent) {
        match e {
            SetupEvent::Load(path) => {
                self.finish();
                // the built-in scene loads at once
                if let Some(p) = path {
                    self.spinner = Some(Spinner::start(&format!("loading {}", p.display())));
                }
            }
            SetupEvent::Build => {
                self.finish();
                self.spinner = Some(Spinner::start("building the world"));
            }
            SetupEvent::Phase(p) => {
                if let Some(s) = &self.spinner {
                    s.set_message(p);
                }
            }
            SetupEvent::Warning(w) => self.println(&format!("warning: {w}")),
            SetupEvent::Note(n) => self.println(&format!("note: {n}")),
        }
    }

    /// Clears the spinner, when one is shown.
    pub fn finish(&mut self) {
        self.spinner = None;
    }

    fn println(&self, line: &str) {
        match &self.spinner {
            Some(s) => s.println(line),
            None => eprintln!("{line}"),
        }
    }
}
