//! A spinner on stderr while a scene loads and its world (BVH, lights) is
//! built: shown only once the work has taken a second, so that small scenes
//! print nothing, and large ones never look hung.

use std::sync::mpsc;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use kalos::methods::World;
use kalos::scene::Scene;
use kalos::world::BuildEvent;

/// How long work runs before the spinner appears.
const QUIET: Duration = Duration::from_secs(1);

/// Runs `work` with a spinner showing `what`; `work` may change the message
/// through the callback it is given (one [`BuildEvent`] at a time).
/// Warnings are printed at once, above the spinner.
pub fn with_spinner<T>(what: &str, work: impl FnOnce(&mut dyn FnMut(BuildEvent)) -> T) -> T {
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
    let out = work(&mut |e| match e {
        BuildEvent::Phase(p) => bar.set_message(p),
        BuildEvent::Warning(w) => bar.suspend(|| eprintln!("warning: {w}")),
    });
    drop(done);
    let _ = shower.join();
    bar.finish_and_clear();
    out
}

/// [`World::build`] under a spinner.
pub fn build_world(scene: Scene) -> World {
    with_spinner("building the world", |on| World::build(scene, on))
}
