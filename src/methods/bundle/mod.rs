//! `bundle`: stochastic iteration with global ray bundles (§5 and §6 of the
//! 1999 stochastic-iteration paper).
//!
//! The surfaces are cut into patches ([`patches`]), each holding one RGB
//! radiance for the current global direction (two with the bi-directional
//! transfer: +ω and −ω). Every iteration (one pass of the driver):
//!
//! 1. the radiance of all patches is transferred along ±ω_m through a
//!    visibility map on the transillumination plane ([`visibility`]: the
//!    painter's algorithm, or a z-buffer for comparison);
//! 2. the received radiance is reflected toward the eye and averaged into
//!    the image ([`image`]: Phong or Gouraud estimate);
//! 3. a new direction ω_{m+1} is drawn ([`sequence`]) and the received
//!    radiance is reflected into it: L_new\[i\] = L_i^e(ω_{m+1}) +
//!    4π Σ_j f̃_i(ω_m, ω_{m+1}) A(i, j, ω_m)/A_i · L\[j\] ([`transfer`]).
//!
//! First shot (`--direct nee`, the default; Castro et al.'s "first-shot"
//! for global lines, ref. 5 of the paper): light that arrives straight from
//! the emitters is not left to the few global directions that hit a small
//! luminaire. Every iteration, each pixel takes one light sample at its
//! visible point and each patch one from a uniform point of the patch
//! (next-event estimation, [`transfer::direct`]), the patches start from
//! that direct light instead of their emission, and the sweep carries no
//! sky. The bundles then carry only what non-emitting patches send: the
//! indirect light. Emission seen by the camera is still taken exactly per
//! pixel. `--direct bundles` is the paper's pure form.
//!
//! Final gather (`--gather glossy`, the default): a pixel whose visible
//! point x (after any delta chain) has a glossy lobe would get its bounced
//! light only from the one direction pair ±ω_m per iteration, which
//! rarely falls inside a narrow lobe. Instead, each iteration such a pixel
//! draws one direction wi from its BSDF (radiance mode), traces it to the
//! first surface y, on patch j, and takes
//!
//! L_gather = f(wo, wi) |cos θ_i| / pdf(wi) · L̂_j(−wi),
//!
//! L̂_j(w) = S_j(w) + 2π Σ_± f̃_j(±ω_m, w) E_±\[j\]/A_j,
//!
//! in place of the Phong (or Gouraud) estimate, where E_± is what j
//! received in this iteration's sweep and S_j the term the transfer starts
//! from ([`transfer::reflect_onto`]): L̂_j(w) is the radiance that patch j
//! sends toward w one transfer later, built exactly as the bundles build
//! L\[j\](ω_{m+1}), only in the direction of x instead of ω_{m+1}. Its
//! expectation over ω_m and the light samples is the patch solution's
//! radiance leaving j toward x, so the gather is an unbiased one-sample
//! estimate of ∫ f L_patch cos dω at the exact point x, and the image
//! average over iterations converges to the same patch solution as without
//! it (up to the receiver: the gather reads the field at x, the Phong
//! estimate averages it over x's patch). Nothing is counted twice, because
//! S_j and the escape term take exactly what the pixel's other terms leave
//! out:
//!
//! - paper's form (`--direct bundles`): the pixel has no light sample; S_j
//!   is j's emission L_j^e(−wi) and a gather ray that leaves the scene
//!   brings the sky, as the bundles carry both. The pixel is Le(x) plus
//!   L_gather.
//! - first shot (`--direct nee`): the pixel's light sample already holds
//!   all light that travels straight from an emitter (or the sky) to x, so
//!   the gather must bring only light that left a surface after at least
//!   one bounce. S_j is then j's first shot — the light j reflects of what
//!   reaches it straight from the emitters, by one light sample from a
//!   uniform point of j ([`transfer::direct`]), as for the patches — and
//!   not its emission; the reflected term carries what the bundles carry
//!   (light of non-emitting patches only); an escaping ray brings nothing.
//!   The pixel is Le(x) + L_direct(x) + L_gather: emission, one bounce,
//!   two bounces and more, each once.
//!
//! Pixels without a glossy lobe keep the Phong or Gouraud estimate. The
//! gather costs one ray per glossy pixel and iteration, plus the first
//! shot's shadow ray; its stream is its own, so `--gather off` gives the
//! image of the code without it, bit for bit. The paper's form is
//! `--direct bundles --positions fixed --gather off --glass off`.
//!
//! The image converges to the exact image up to the patch and map
//! discretisation: radiance is constant over a patch in each direction
//! (eq. (23)), and the painter's sort by centroid can misorder overlapping
//! patches. Memory is O(patches), independent of the BRDFs.
//!
//! Bias. That discretisation does not average out: `bundle` converges to
//! the patch solution, not to the image `path` converges to, and the
//! difference is darkening. Measured against Mitsuba 3 references (image
//! means, default settings; issue #38, at 30–60 s on 2 cores): about
//! 1.3 % dark on cbox, and about 8 % dark on a diffuse variant of
//! two-rooms-baffle, where the light reaches the camera's room through a
//! small gap that a patch's constant radiance blurs. Earlier figures, with
//! their commands, are in docs/notebook/bundle.md: cbox's channel means
//! within −1.3 % to +0.9 % of the reference at 300 iterations (first
//! shot), glass-mirror 11–12 % dark (light through glass, which the
//! transfer absorbs). A user who needs the unbiased image should use
//! `path`, `light` or `plb`.
//!
//! ```text
//! kalos render scenes/cbox/cbox.xml --method bundle --time 10 -o b.exr
//! kalos render scene.xml --method bundle --patches 57000 --map-res 1024 \
//!     --sequence random --bundle-image phong --visibility painter --discard 20
//! ```
//!
//! Left out: glass (dielectrics absorb in the transfer; the camera sees
//! through them, with a sampled chain, in the image estimate), and smooth
//! plastic's coat (its diffuse base is kept).

pub mod budget;
pub mod image;
pub mod patches;
pub mod sequence;
pub mod transfer;
pub mod visibility;

use std::time::Instant;

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use super::{
    film_item, no_exact_merge, Common, Method, MethodError, MethodSettings, StepStats, World, FILM,
    IMAGE,
};
use crate::film::Image;
use crate::memory::MemoryItem;
use crate::scene::Rgb;
use crate::state::{ShardKind, State};
use image::{ImageMode, Positions, View};
use patches::Patches;
use sequence::{Directions, Sequence};
use visibility::{SweepInput, Visibility};

/// Settings of the ray-bundle iteration.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct Settings {
    /// Master seed (set from [`super::Common`]).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub seed: u64,
    /// Most patches: the finest uniform mesh within this many (at least one
    /// patch per scene triangle), unless a patch edge is given.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 5_000))]
    pub patches: usize,
    /// Target patch edge length in scene units (overrides the number of
    /// patches).
    #[cfg_attr(feature = "cli", arg(long = "patch-edge"))]
    pub edge: Option<f32>,
    /// How the patches are spread: uniformly by area (the paper's mesh,
    /// the default), or by what the camera sees at the same count (see the
    /// `budget` module).
    #[cfg_attr(
        feature = "cli",
        arg(long = "patch-budget", value_enum, default_value = "area")
    )]
    pub budget: PatchBudget,
    /// Visibility-map resolution across the scene's bounding sphere; when
    /// not given, 8R/h (four pixels per patch edge), clamped to 1024..=4096.
    #[cfg_attr(feature = "cli", arg(long))]
    pub map_res: Option<u32>,
    /// The sequence of global directions.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "random"))]
    pub sequence: Sequence,
    /// Phong (per-pixel BRDF) or Gouraud (per-patch radiance interpolated
    /// over the vertices) image estimate.
    #[cfg_attr(
        feature = "cli",
        arg(long = "bundle-image", value_enum, default_value = "phong")
    )]
    pub image: ImageMode,
    /// Painter's algorithm (§6) or z-buffer depth peeling.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "painter"))]
    pub visibility: Visibility,
    /// Iterations left out of the image average (power defect, eq. (18)).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub discard: u64,
    /// Sub-pixel patches in the painter's map: kept by pixel-centre
    /// roulette (centre) or by single-pixel roulette (single), as the
    /// `visibility` module explains.
    #[cfg_attr(feature = "cli", arg(long = "subpixel", value_name = "centre|single", default_value = "centre", value_parser = subpixel_rule, action = clap::ArgAction::Set))]
    pub centre_rr: bool,
    /// Sub-pixel positions of the image estimate: a fresh jittered one per
    /// pixel and iteration, or four traced once (the paper's preprocessing).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "jittered"))]
    pub positions: Positions,
    /// Direct light: by next-event estimation (the first shot, the
    /// default), or carried by the bundles as the paper does.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "nee"))]
    pub direct: Direct,
    /// Final gather: pixels whose visible point is glossy take their
    /// bounced light through one BSDF-sampled ray into the patch solution
    /// (the default), or from the bundles' direction pair as the paper does.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "glossy"))]
    pub gather: Gather,
    /// Glass in the transfer: reflected and transmitted through widened
    /// lobes (the default), or left out as the paper's code did.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "lobes"))]
    pub glass: Glass,
}

/// How the patch count is spread over the surfaces ([`budget`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum PatchBudget {
    /// One uniform edge length: patches in proportion to area (the paper,
    /// and the default: at equal patch count and iterations it measured no
    /// worse than `projected`, see docs/notebook/bundle.md).
    Area,
    /// The same count, spread by area and by the camera's pixel footprint.
    Projected,
}

/// How glass (smooth and thin dielectrics) takes part in the transfer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Glass {
    /// Fresnel reflection and refraction, each widened to a narrow lobe
    /// (`transfer::eval_glass`).
    Lobes,
    /// Glass neither reflects nor transmits in the transfer (the camera
    /// still sees through it).
    Off,
}

/// Which pixels take their bounced light by a final gather.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Gather {
    /// Pixels whose visible point has a glossy lobe (`Bsdf::has_glossy`):
    /// one BSDF-sampled ray per pixel and iteration, reading the patch
    /// solution where it lands.
    Glossy,
    /// None: every pixel reflects the bundles' direction pair (the paper).
    Off,
}

/// How light that arrives straight from the emitters is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Direct {
    /// The first shot: per pixel and per patch, one light sample per
    /// iteration (next-event estimation without MIS); the bundles carry
    /// only what non-emitting patches send, and no sky.
    Nee,
    /// The paper's pure form: the bundles carry the emission of the
    /// luminaires and the sky like any other radiance.
    Bundles,
}

/// Parses `--subpixel`: true for pixel-centre roulette.
#[cfg(feature = "cli")]
fn subpixel_rule(s: &str) -> Result<bool, String> {
    match s {
        "centre" | "center" => Ok(true),
        "single" => Ok(false),
        _ => Err(format!("expected centre or single, got '{s}'")),
    }
}

impl Settings {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<(), MethodError> {
        if self.patches == 0 {
            return Err(MethodError("--patches must be at least 1".into()));
        }
        if let Some(e) = self.edge {
            if !(e.is_finite() && e > 0.0) {
                return Err(MethodError(format!(
                    "--patch-edge must be a positive length, got {e}"
                )));
            }
        }
        if let Some(r) = self.map_res {
            if !(8..=16384).contains(&r) {
                return Err(MethodError(format!(
                    "--map-res must be in 8..=16384, got {r}"
                )));
            }
        }
        Ok(())
    }

    /// Rejects a scene whose lights these settings cannot carry: in the
    /// paper's form (`--direct bundles`) the bundles carry the luminaires'
    /// emission as the radiance of patches, and a punctual light (a point
    /// or a direction) has no patch; the first shot (`--direct nee`, the
    /// default) reaches it by light sampling.
    pub fn check_lights(&self, world: &World) -> Result<(), MethodError> {
        match (self.direct, world.lights.punctual().first()) {
            (Direct::Bundles, Some(l)) => Err(MethodError(format!(
                "bundle --direct bundles cannot render punctual light '{}' ({} in all): \
                 the bundles carry emission as the radiance of patches, and a point, spot or \
                 directional light has no surface; use --direct nee (the default), which \
                 reaches it by light sampling",
                l.name,
                world.lights.punctual().len()
            ))),
            _ => Ok(()),
        }
    }
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            seed: 0,
            patches: 5_000,
            edge: None,
            budget: PatchBudget::Area,
            map_res: None,
            sequence: Sequence::Random,
            image: ImageMode::Phong,
            visibility: Visibility::Painter,
            discard: 0,
            centre_rr: true,
            positions: Positions::Jittered,
            direct: Direct::Nee,
            gather: Gather::Glossy,
            glass: Glass::Lobes,
        }
    }
}

impl MethodSettings for Settings {
    fn validate(&self) -> Result<(), MethodError> {
        Settings::validate(self)
    }

    /// Chains: each shard is an independent iteration with its own seed.
    fn shard_kind(&self) -> Result<ShardKind, MethodError> {
        Ok(ShardKind::Chains)
    }

    fn check_shard_count(&self, _count: u32) -> Result<(), MethodError> {
        Ok(())
    }

    fn resumable(&self) -> Result<(), &'static str> {
        Err("its patches' radiance is not saved")
    }

    fn merge_exact(&self, _: &[&State], _: u32, _: u32) -> Result<Image, MethodError> {
        Err(no_exact_merge("bundle"))
    }

    /// The film, the image and the stored pixel samples; the visibility
    /// map at [`MAX_AUTO_MAP_RES`] unless `--map-res` is given; the patches
    /// only when their number is given.
    fn memory(&self, width: u32, height: u32) -> Vec<MemoryItem> {
        let fixed = if self.positions == Positions::Fixed {
            // the stored samples, and the (sample, rays) pairs they
            // are collected from
            let sample = std::mem::size_of::<image::PixelSample>()
                + std::mem::size_of::<(image::PixelSample, u64)>();
            // and, in the paper's form, each sample's quiet part
            let quiet = if self.direct == Direct::Bundles && self.gather == Gather::Off {
                image::QUIET_BYTES
            } else {
                0
            };
            (image::SAMPLES * (sample + quiet)) as u64
        } else {
            0
        };
        let mut items = vec![film_item(width, height, FILM + IMAGE + fixed, "")];
        let res = self.map_res.unwrap_or(MAX_AUTO_MAP_RES);
        items.push(MemoryItem {
            what: format!("bundle's visibility map {res}×{res}"),
            bytes: visibility::map_bytes(res, self.visibility),
            remedy: "lower --map-res",
        });
        if self.edge.is_none() {
            let (state, transient) = Bundle::bytes_per_patch();
            items.push(MemoryItem {
                what: format!("bundle's {} patches", self.patches),
                bytes: (self.patches as u64).saturating_mul((state + transient) as u64),
                remedy: "lower --patches",
            });
        }
        items
    }

    /// Stochastic iteration cannot limit the path length (see its row), so
    /// only the seed is taken from `common`.
    fn create(&self, world: &World, common: &Common) -> Box<dyn Method> {
        Box::new(Bundle::new(
            world,
            Settings {
                seed: common.seed,
                ..self.clone()
            },
        ))
    }
}

/// The largest visibility-map resolution chosen when `--map-res` is not
/// given (the memory check counts a map this large).
pub const MAX_AUTO_MAP_RES: u32 = 4096;

/// Seconds spent in each phase, summed over the iterations. The image
/// estimate and the next direction's projection run at once, so their
/// times overlap.
#[derive(Clone, Copy, Debug, Default)]
pub struct Timings {
    /// Building the patches and the view (once).
    pub setup: f64,
    /// Projecting the patches into the map tiles' bins.
    pub project: f64,
    /// Sorting each tile by depth along ω and scan conversion.
    pub raster: f64,
    /// The tiles' sum into each patch and, fused with it, the transfer into
    /// ω_{m+1}.
    pub transfer: f64,
    /// The image estimate.
    pub image: f64,
}

/// What [`Method::prepare`] builds once: the patches, the preprocessed
/// view and the visibility-map resolution.
struct Setup {
    patches: Patches,
    view: View,
    res: u32,
    /// Per patch: it emits nothing (its L^e is +0 in every channel), so in
    /// the paper's operator it sends nothing unless it received something.
    dark: Vec<bool>,
}

/// The iteration's state.
pub struct Bundle {
    settings: Settings,
    /// None until prepared.
    setup: Option<Setup>,
    dirs: Directions,
    /// Current direction ω_m.
    d: Vec3,
    /// L[i] toward +ω_m and −ω_m.
    l_plus: Vec<Rgb>,
    l_minus: Vec<Rgb>,
    sum: Vec<DVec3>,
    iter: u64,
    counted: u64,
    timings: Timings,
    /// The sweep's buffers, reused from iteration to iteration.
    scratch: visibility::Scratch,
    /// What the last sweep brought each patch (buffers reused).
    incoming: visibility::Incoming,
}

impl Bundle {
    /// The iteration for `world`, not yet prepared: the patches and the
    /// view are built by [`Method::prepare`].
    pub fn new(world: &World, settings: Settings) -> Self {
        let npix = world.camera.width as usize * world.camera.height as usize;
        let dirs = Directions::new(settings.sequence, settings.seed);
        Bundle {
            setup: None,
            dirs,
            d: Vec3::Z,
            l_plus: Vec::new(),
            l_minus: Vec::new(),
            sum: vec![DVec3::ZERO; npix],
            iter: 0,
            counted: 0,
            scratch: Default::default(),
            incoming: Default::default(),
            timings: Timings::default(),
            settings,
        }
    }

    /// Tessellates the scene and precomputes the view (tracing its camera
    /// rays), once; returns the rays traced.
    fn build(&mut self, world: &World) -> u64 {
        if self.setup.is_some() {
            return 0;
        }
        let t0 = Instant::now();
        let settings = &self.settings;
        let edge = settings
            .edge
            .unwrap_or_else(|| patches::edge_for_count(&world.scene, settings.patches));
        let (mut patches, budget_rays) = match settings.budget {
            PatchBudget::Projected => {
                let (layout, rays) =
                    budget::projected(world, edge, settings.gather == Gather::Glossy);
                (
                    Patches::with_layout(&world.scene, &world.lights, layout, edge),
                    rays,
                )
            }
            PatchBudget::Area => (Patches::build(&world.scene, &world.lights, edge), 0),
        };
        patches.set_glass(settings.glass == Glass::Lobes);
        let radius = world.lights.radius;
        let res = settings.map_res.unwrap_or_else(|| {
            let r = (8.0 * radius / edge.max(1e-9)).ceil();
            (r.min(MAX_AUTO_MAP_RES as f32) as u32).max(1024)
        });
        let view = View::new(
            world,
            &patches,
            settings.seed,
            settings.positions,
            settings.direct == Direct::Nee,
            settings.gather == Gather::Glossy,
        );
        let rays = view.rays + budget_rays;
        let n = patches.len();
        self.l_plus = vec![Rgb::ZERO; n];
        self.l_minus = vec![Rgb::ZERO; n];
        let dark = patches
            .p
            .iter()
            .map(|p| p.le.to_array().iter().all(|c| c.to_bits() == 0))
            .collect();
        self.setup = Some(Setup {
            patches,
            view,
            res,
            dark,
        });
        self.timings.setup = t0.elapsed().as_secs_f64();
        rays
    }

    /// The patches, once prepared.
    pub fn patches(&self) -> Option<&Patches> {
        self.setup.as_ref().map(|s| &s.patches)
    }

    /// The visibility-map resolution in use, once prepared.
    pub fn map_res(&self) -> Option<u32> {
        self.setup.as_ref().map(|s| s.res)
    }

    /// Time per phase so far.
    pub fn timings(&self) -> Timings {
        self.timings
    }

    /// Iterations run.
    pub fn iterations(&self) -> u64 {
        self.iter
    }

    /// Bytes of per-patch state (geometry, BRDF, the corners again by
    /// coordinate for the projection, the two radiance values, corner ids,
    /// whether it emits) and of the transient per-iteration buffers per patch (incoming
    /// radiance, the projection, and the tile entries: a patch
    /// is in every map tile its projection crosses, with a copy of its
    /// projection and its two accumulators, and in the buffers of the
    /// thread that scans the tile its sort key twice, its two radiance
    /// values and its two accumulators; the figure counts two tiles, an upper bound while
    /// projections are shorter than a tile, 25 rows at the default map).
    /// The map itself is not per patch: one tile of it per thread
    /// ([`visibility::map_bytes`]).
    pub fn bytes_per_patch() -> (usize, usize) {
        use std::mem::size_of;
        // the patch, its corners again by coordinate, L(±ω), its vertex ids,
        // whether it is dark
        let state = size_of::<patches::Patch>()
            + size_of::<[glam::Vec3; 3]>()
            + 2 * size_of::<Rgb>()
            + size_of::<[u32; 3]>()
            + size_of::<bool>();
        // projection, the two accumulators, sort key and radix buffer, and
        // the two radiance values and two accumulators of a tile entry
        let tile_entry = visibility::PROJ_BYTES + 2 * size_of::<u64>() + 6 * size_of::<Rgb>();
        let transient = 2 * size_of::<Rgb>() + visibility::PROJ_BYTES + 2 * tile_entry;
        (state, transient)
    }
}

/// The stream of patch `i`'s first-shot light sample for direction ω_{m+1}
/// (`m` = 0 for ω_1): keyed, so the same whatever the thread count.
fn first_shot_rng(seed: u64, i: usize, m: u64) -> crate::sampling::Pcg32 {
    crate::sampling::Pcg32::keyed(&[seed, i as u64, m, 0x1C])
}

impl Method for Bundle {
    fn name(&self) -> &'static str {
        "bundle"
    }

    fn prepare(&mut self, world: &World) -> Result<StepStats, MethodError> {
        self.settings.check_lights(world)?;
        Ok(StepStats {
            rays: self.build(world),
        })
    }

    fn step(&mut self, world: &World, _pass: u64) -> StepStats {
        // The setup, if the caller skipped prepare (its rays count here)
        let mut rays = self.build(world);
        let setup = self.setup.as_ref().expect("built above");
        let patches = &setup.patches;
        let source = Source {
            world,
            nee: self.settings.direct == Direct::Nee,
            seed: self.settings.seed,
        };
        if self.iter == 0 {
            // ω_1 and L[i] = L_i^e(±ω_1), or the first shot's direct light
            self.d = self.dirs.next_dir();
            rays += source.first(patches, self.d, &mut self.l_plus, &mut self.l_minus);
        }
        let d = self.d;

        // Transfer along ±ω_m through the visibility map (its projection
        // was made during the last iteration, unless this is the first)
        let plane = |d: Vec3, iter: u64| sweep_plane(world, &self.settings, setup.res, d, iter);
        let inp = SweepInput {
            plane: plane(d, self.iter),
            l_plus: &self.l_plus,
            l_minus: &self.l_minus,
            sky_plus: source.sky(-d),
            sky_minus: source.sky(d),
        };
        let inc = &mut self.incoming;
        visibility::scan_into(patches, &inp, &mut self.scratch, inc);
        let t_scan = inc.t_raster;

        // Reflect what arrived into ±ω_{m+1}, on top of the emission (the
        // paper) or of the first shot: fused into the tiles' sum, each chunk
        // of patches right after its incoming radiance is summed, while that
        // is still in cache
        let dn = self.dirs.next_dir();
        let next = self.iter + 1;
        let reflect = Reflect {
            source,
            patches,
            dark: &setup.dark,
            d,
            dn,
            next,
        };
        let t = Instant::now();
        let transfer_rays = visibility::sum_into(
            patches,
            &self.scratch,
            inc,
            &mut self.l_plus,
            &mut self.l_minus,
            |first, e_plus, e_minus, l_plus, l_minus| {
                reflect.chunk(first, e_plus, e_minus, l_plus, l_minus)
            },
        );
        let t_sum = t.elapsed().as_secs_f64();
        self.timings.project += inc.t_project;
        self.timings.raster += t_scan;
        self.timings.transfer += t_sum;
        rays += inc.fragments + transfer_rays;
        let inc = &*inc;

        // Two tasks that need only what this sweep brought, run at once so
        // that each fills the other's idle core: the image estimate, and the
        // projection of the patches for ω_{m+1}, which depends on the
        // direction, not on the radiance. Their timings overlap.
        let (iter, discard, mode) = (self.iter, self.settings.discard, self.settings.image);
        let (sum, scratch) = (&mut self.sum, &mut self.scratch);
        let next_plane = plane(dn, next);
        let ((t_image, image_rays), t_project) = rayon::join(
            // Image estimate, averaged over the kept iterations
            || {
                let t = Instant::now();
                let r = if iter >= discard {
                    let (e_plus, e_minus) = (&inc.e_plus, &inc.e_minus);
                    let view = &setup.view;
                    view.accumulate(world, patches, mode, d, e_plus, e_minus, iter, sum)
                } else {
                    0
                };
                (t.elapsed().as_secs_f64(), r)
            },
            || {
                let t = Instant::now();
                visibility::project(patches, &next_plane, scratch);
                t.elapsed().as_secs_f64()
            },
        );
        if iter >= discard {
            self.counted += 1;
        }
        rays += image_rays;
        self.timings.image += t_image;
        self.timings.project += t_project;
        self.d = dn;
        self.iter += 1;
        StepStats { rays }
    }

    fn image(&self, world: &World) -> Image {
        let scale = if self.counted == 0 {
            0.0
        } else {
            1.0 / self.counted as f64
        };
        Image {
            width: world.camera.width,
            height: world.camera.height,
            data: self.sum.iter().map(|v| (*v * scale).as_vec3()).collect(),
        }
    }

    fn spp(&self) -> f64 {
        self.iter as f64
    }

    fn report(&self) -> Option<String> {
        let setup = self.setup.as_ref()?;
        let t = self.timings;
        let it = self.iter.max(1) as f64 * 1e-3;
        let (state, transient) = Bundle::bytes_per_patch();
        Some(format!(
            "bundle: {} patches ({} budget, edge {:.4}), map {}², {} iterations; setup {:.2} s; \
             per iteration: project {:.2} ms, scan {:.2} ms, transfer {:.2} ms, image {:.2} ms; \
             memory per patch {} B state + {} B transient",
            setup.patches.len(),
            match self.settings.budget {
                PatchBudget::Projected => "projected",
                PatchBudget::Area => "area",
            },
            setup.patches.edge,
            setup.res,
            self.iter,
            t.setup,
            t.project / it,
            t.raster / it,
            t.transfer / it,
            t.image / it,
            state,
            transient
        ))
    }
}

/// The visibility map of [`Bundle`]'s sweep along `d` in iteration `iter`:
/// resolution `res` over the scene's bounding sphere, its random streams
/// keyed by the seed and the iteration.
fn sweep_plane(
    world: &World,
    settings: &Settings,
    res: u32,
    d: Vec3,
    iter: u64,
) -> visibility::Plane {
    visibility::Plane {
        d,
        res,
        center: world.lights.center,
        radius: world.lights.radius,
        keys: [settings.seed, iter],
        visibility: settings.visibility,
        centre_rr: settings.centre_rr,
    }
}

/// What a patch sends along ±ω before any reflection: its emission (the
/// paper's operator) or, with the first shot (`nee`), the direct light of
/// one light sample from a uniform point of the patch.
#[derive(Clone, Copy)]
struct Source<'a> {
    world: &'a World,
    nee: bool,
    seed: u64,
}

impl Source<'_> {
    /// Patch `i`'s (L(+dir), L(−dir), rays traced) in iteration `it`.
    #[inline]
    fn at(&self, i: usize, p: &patches::Patch, dir: Vec3, it: u64) -> (Rgb, Rgb, u64) {
        if self.nee {
            transfer::direct(self.world, p, dir, &mut first_shot_rng(self.seed, i, it))
        } else {
            (p.le(dir), p.le(-dir), 0)
        }
    }

    /// The sky's radiance flowing along −`w` into the sweep: none with the
    /// first shot, where the sky is direct light, taken by the light samples.
    fn sky(&self, w: Vec3) -> Rgb {
        if self.nee {
            Rgb::ZERO
        } else {
            self.world.lights.le_env(w)
        }
    }

    /// L\[i\](±ω_1) for every patch, before the first sweep; returns the
    /// rays traced.
    fn first(&self, patches: &Patches, d: Vec3, l_plus: &mut [Rgb], l_minus: &mut [Rgb]) -> u64 {
        l_plus
            .par_iter_mut()
            .zip(l_minus.par_iter_mut())
            .zip(patches.p.par_iter())
            .enumerate()
            .map(|(i, ((lp, lm), p))| {
                let (sp, sm, r) = self.at(i, p, d, 0);
                (*lp, *lm) = (sp, sm);
                r
            })
            .sum::<u64>()
    }
}

/// The transfer into ω_{m+1} (§5 of the paper): L_new\[i\] = S_i(ω_{m+1}) +
/// 4π Σ_j f̃_i(ω_m, ω_{m+1}) A(i, j, ω_m)/A_i · L\[j\], S_i from [`Source`]
/// (and the same for −ω_{m+1}), for a chunk of patches once what they
/// received, E_±, is summed.
struct Reflect<'a> {
    source: Source<'a>,
    patches: &'a Patches,
    /// [`Setup::dark`].
    dark: &'a [bool],
    /// ω_m.
    d: Vec3,
    /// ω_{m+1}.
    dn: Vec3,
    /// The iteration m + 1 (the key of the first shot's streams).
    next: u64,
}

impl Reflect<'_> {
    /// L(±ω_{m+1}) of patches `first..` from what they received, E_±;
    /// returns the rays the first shot traced.
    #[inline]
    fn chunk(
        &self,
        first: usize,
        e_plus: &[Rgb],
        e_minus: &[Rgb],
        l_plus: &mut [Rgb],
        l_minus: &mut [Rgb],
    ) -> u64 {
        let (d, dn) = (self.d, self.dn);
        let mut r = 0;
        for (k, ((lp, lm), (&ep, &em))) in l_plus
            .iter_mut()
            .zip(l_minus.iter_mut())
            .zip(e_plus.iter().zip(e_minus))
            .enumerate()
        {
            let i = first + k;
            // With the paper's operator a dark patch that received
            // nothing sends L^e = +0 and reflects nothing: skip
            // reading it (the bits are those of the general line)
            if !self.source.nee && self.dark[i] && ep == Rgb::ZERO && em == Rgb::ZERO {
                (*lp, *lm) = (Rgb::ZERO, Rgb::ZERO);
                continue;
            }
            let p = &self.patches.p[i];
            let (sp, sm, rays) = self.source.at(i, p, dn, self.next);
            *lp = transfer::reflect_onto(sp, p, d, ep, em, dn);
            *lm = transfer::reflect_onto(sm, p, d, ep, em, -dn);
            r += rays;
        }
        r
    }
}
