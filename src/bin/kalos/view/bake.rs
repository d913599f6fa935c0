//! `kalos bake --lightmap --view`: the asset shown in the browser as soon as
//! its uv set is made (with a black atlas), then each preview of the atlas
//! as the bake makes it, then the final atlas; the page swaps three.js's
//! lightmap textures in place (assets/view/lightmap.js, `showLive`).
//!
//! `/image` sends an atlas as `KLM1`, its width and height (u32 LE), the
//! scale S (f32 LE: the .glb's `MOZ_lightmap.intensity` for this atlas),
//! then E/S and σ/S per texel as RGB f32 LE, top row first, each clipped to
//! [0, 1] as the .glb's 16-bit PNGs are: so the page shows what `kalos
//! view` will show of the written .glb.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Result;

use kalos::bake::job::BakeEvent;
use kalos::bake::lightmap::glb::scale_of;
use kalos::bake::lightmap::Lightmap;
use kalos::color::Rgb;
use kalos::methods::density::control::{Phase, Tick};

use super::server::{self, BakeStatus, Content, LiveState, Viewer};

/// The viewer of a lightmap bake as it runs.
pub struct LiveBake {
    viewer: Viewer,
    /// The page's clock: its elapsed seconds run until the bake ends.
    start: Instant,
}

impl LiveBake {
    /// Starts the server (before the scene loads, so that a port in use
    /// fails at once) and prints its address on stderr.
    pub fn start(port: u16, name: &str) -> Result<LiveBake> {
        let viewer = server::start(Content::Bake, name, port)?;
        eprintln!("view the bake at {}", viewer.url);
        let live = LiveBake {
            viewer,
            start: Instant::now(),
        };
        live.update(|s| {
            s.bake = Some(BakeStatus::default());
            s.phase = Some("loading the scene");
        });
        Ok(live)
    }

    /// Shows what `e` tells of the bake.
    pub fn event(&self, e: &BakeEvent) {
        match e {
            BakeEvent::Tick(t) => self.tick(t),
            BakeEvent::Texels { done, total } => self.texels(*done, *total),
            BakeEvent::Asset(glb) => self.asset(glb),
            BakeEvent::Previewing { .. } => self.update(|s| s.phase = Some("estimating a preview")),
            BakeEvent::Preview {
                lightmap,
                particles,
                seconds,
            } => self.preview(lightmap, *particles, *seconds),
            BakeEvent::Writing => self.update(|s| s.phase = Some("writing")),
            BakeEvent::Setup(_) | BakeEvent::Started | BakeEvent::Exchanged { .. } => {}
        }
    }

    /// The asset, as the bake will write it (with a black atlas).
    fn asset(&self, glb: &[u8]) {
        let glb = Arc::new(glb.to_vec());
        self.update(|s| s.glb = Some(glb));
    }

    /// Progress within a phase of the bake.
    fn tick(&self, t: &Tick) {
        self.update(|s| {
            s.phase = Some(t.phase.name());
            s.rays = t.rays;
            s.fraction = t.bake_fraction();
            let b = s.bake.get_or_insert_with(Default::default);
            if t.phase == Phase::Trace {
                b.particles = t.done;
                b.particles_total = t.total;
            }
            (b.done, b.total) = (t.done, t.total);
        });
    }

    /// Progress of the final estimate's texels.
    fn texels(&self, done: u64, total: u64) {
        self.update(|s| {
            s.phase = Some("estimating texels");
            let b = s.bake.get_or_insert_with(Default::default);
            (b.done, b.total) = (done, total);
        });
    }

    /// A preview, from `particles` particles, that took `seconds`.
    fn preview(&self, lm: &Lightmap, particles: u64, seconds: f64) {
        self.atlas(lm, particles);
        self.update(|s| {
            s.phase = Some(Phase::Trace.name());
            let b = s.bake.get_or_insert_with(Default::default);
            b.previews += 1;
            b.preview_seconds += seconds;
        });
    }

    /// The bake is written: its final atlas, from `particles` particles.
    pub fn finish(&self, lm: &Lightmap, particles: u64) {
        self.atlas(lm, particles);
        self.update(|s| {
            s.bake.get_or_insert_with(Default::default).particles = particles;
            s.phase = Some("finished");
            s.fraction = 1.0;
            s.done = true;
        });
    }

    /// Keeps the page served until Ctrl-C or SIGTERM (whose handlers the
    /// bake installed).
    pub fn serve_until_signal(&self) {
        eprintln!(
            "the bake is written; its viewer stays at {} until Ctrl-C",
            self.viewer.url
        );
        while !crate::signals::cancel_flag().load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The figures of the previews: how many, and their seconds in all.
    pub fn previews(&self) -> (u64, f64) {
        self.viewer
            .live
            .lock()
            .ok()
            .and_then(|s| s.bake.as_ref().map(|b| (b.previews, b.preview_seconds)))
            .unwrap_or_default()
    }

    fn atlas(&self, lm: &Lightmap, particles: u64) {
        let bytes = Arc::new(encode_atlas(lm));
        self.update(|s| {
            s.image = Some(bytes);
            s.version += 1;
            s.bake.get_or_insert_with(Default::default).atlas_particles = particles;
        });
    }

    fn update(&self, f: impl FnOnce(&mut LiveState)) {
        // a poisoned lock means the server thread panicked: the bake goes on
        if let Ok(mut s) = self.viewer.live.lock() {
            if !s.done {
                s.elapsed = self.start.elapsed().as_secs_f64();
            }
            f(&mut s);
        }
    }
}

/// `lm` as `/image` sends it (see the module doc).
fn encode_atlas(lm: &Lightmap) -> Vec<u8> {
    let scale = scale_of(lm);
    let n = lm.width as usize * lm.height as usize;
    let mut out = Vec::with_capacity(16 + n * 24);
    out.extend_from_slice(b"KLM1");
    out.extend_from_slice(&lm.width.to_le_bytes());
    out.extend_from_slice(&lm.height.to_le_bytes());
    out.extend_from_slice(&scale.to_le_bytes());
    for data in [&lm.irradiance, &lm.std_error] {
        for i in 0..n {
            let c = data.get(i).copied().unwrap_or(Rgb::ZERO) / scale;
            for v in c.to_array() {
                let v = if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_atlas_is_sent_over_its_scale_and_clipped() {
        let lm = Lightmap {
            width: 2,
            height: 1,
            irradiance: vec![Rgb::new(2.0, 4.0, 1.0), Rgb::new(8.0, 0.0, f32::NAN)],
            std_error: vec![Rgb::new(0.5, 0.5, 0.5), Rgb::ZERO],
            covered: vec![true, false],
        };
        let b = encode_atlas(&lm);
        assert_eq!(&b[..4], b"KLM1");
        assert_eq!(b.len(), 16 + 2 * 2 * 12);
        let f = |k: usize| f32::from_le_bytes(b[k..k + 4].try_into().unwrap());
        // the scale: the covered texels' largest channel (one texel); the
        // other texel clipped at 1, its NaN sent as 0
        assert_eq!(f(12), 4.0);
        let values: Vec<f32> = (0..12).map(|i| f(16 + 4 * i)).collect();
        assert_eq!(
            values,
            [0.5, 1.0, 0.25, 1.0, 0.0, 0.0, 0.125, 0.125, 0.125, 0.0, 0.0, 0.0]
        );
    }
}
