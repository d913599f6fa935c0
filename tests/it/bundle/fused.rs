//! The paper's form's short cuts give the general code's bits: the image
//! estimate's quiet pixels, the transfer fused into the tiles' sum, and the
//! transfer's skip of dark patches that received nothing.

use glam::{DVec3, Vec3};
use kalos::emitter::Lights;
use kalos::methods::bundle::image::{ImageMode, Positions, View};
use kalos::methods::bundle::patches::Patches;
use kalos::methods::bundle::transfer::{brdf, reflect_onto};
use kalos::methods::bundle::visibility::{
    scan_into, sum_into, sweep, Incoming, Plane, SweepInput, Visibility,
};
use kalos::sampling::{uniform_sphere, Pcg32};
use kalos::scene::{self, Rgb};
use kalos::world::World;

fn cbox() -> World {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    World::new(scene::load(&root.join("scenes/cbox/cbox.xml")).expect("scene"))
}

/// Incoming radiance for `n` patches, zero (+0 or −0) for most of them, as
/// in an iteration of the paper's form.
fn sparse(n: usize, rng: &mut Pcg32) -> Vec<Rgb> {
    (0..n)
        .map(|_| match rng.next_f32() {
            u if u < 0.6 => Rgb::ZERO,
            u if u < 0.7 => Rgb::splat(-0.0),
            _ => Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 3.0,
        })
        .collect()
}

/// `View::accumulate` in the paper's form (fixed positions, no first
/// shot, no gather, Phong) against the general line written out: l = Le +
/// 0, plus thr · Σ_± f̃(±d → wo) E_± · 2π/A where E_± ≠ 0, added when finite.
/// The sums must agree bit for bit in every pixel; the short cut reads only
/// the pixels whose patch received something.
#[test]
fn quiet_pixels_match_the_general_line() {
    let world = cbox();
    let patches = Patches::build(&world.scene, &world.lights, 40.0);
    let view = View::new(&world, &patches, 5, Positions::Fixed, false, false);
    let npix = (world.camera.width * world.camera.height) as usize;
    let mut rng = Pcg32::keyed(&[11, 0]);
    for iter in 0..6u64 {
        let d = uniform_sphere(rng.next_2d());
        let e_plus = sparse(patches.len(), &mut rng);
        let e_minus = sparse(patches.len(), &mut rng);
        let mut got = vec![DVec3::ZERO; npix];
        view.accumulate(
            &world,
            &patches,
            ImageMode::Phong,
            d,
            &e_plus,
            &e_minus,
            iter,
            &mut got,
        );
        let block = &view.samples[(iter as usize % 4) * npix..][..npix];
        let mut reflecting = 0;
        for (pix, s) in block.iter().enumerate() {
            let mut l = s.le + Rgb::ZERO;
            if s.patch != u32::MAX {
                let i = s.patch as usize;
                let p = &patches.p[i];
                let k = 2.0 * std::f32::consts::PI / p.area;
                let mut r = Rgb::ZERO;
                if e_plus[i] != Rgb::ZERO {
                    r += brdf(p, s.ns, d, s.wo) * e_plus[i];
                }
                if e_minus[i] != Rgb::ZERO {
                    r += brdf(p, s.ns, -d, s.wo) * e_minus[i];
                }
                reflecting += usize::from(r != Rgb::ZERO);
                l += s.thr * r * k;
            }
            let want = if l.is_finite() {
                l.as_dvec3()
            } else {
                DVec3::ZERO
            };
            assert_eq!(
                got[pix].to_array().map(f64::to_bits),
                want.to_array().map(f64::to_bits),
                "iteration {iter}, pixel {pix}"
            );
        }
        // both kinds of pixel occur
        assert!(reflecting > 0 && reflecting < npix / 2, "{reflecting}");
    }
}

/// `sum_into` hands each chunk of patches its own incoming radiance and
/// its own range of the caller's buffers, and its sums are `sweep`'s.
#[test]
fn sum_into_hands_each_chunk_its_sums() {
    let world = cbox();
    let lights = Lights::new(&world.scene);
    let patches = Patches::build(&world.scene, &lights, 40.0);
    let n = patches.len();
    let mut rng = Pcg32::keyed(&[12, 0]);
    let l_plus = sparse(n, &mut rng);
    let l_minus = sparse(n, &mut rng);
    for k in 0..4u64 {
        let inp = SweepInput {
            plane: Plane {
                d: uniform_sphere(rng.next_2d()),
                res: 256,
                center: lights.center,
                radius: lights.radius,
                keys: [3, k],
                visibility: Visibility::Painter,
                centre_rr: true,
            },
            l_plus: &l_plus,
            l_minus: &l_minus,
            sky_plus: Rgb::splat(0.5),
            sky_minus: Rgb::ZERO,
        };
        let whole = sweep(&patches, &inp, &mut Default::default());
        let mut scratch = Default::default();
        let mut out = Incoming::default();
        scan_into(&patches, &inp, &mut scratch, &mut out);
        let (mut a, mut b) = (vec![Rgb::NAN; n], vec![Rgb::NAN; n]);
        let ranges = std::sync::Mutex::new(Vec::new());
        let handed = sum_into(
            &patches,
            &scratch,
            &mut out,
            &mut a,
            &mut b,
            |first, ep, em, a, b| {
                assert!(ep.len() == em.len() && ep.len() == a.len() && a.len() == b.len());
                a.copy_from_slice(ep);
                b.copy_from_slice(em);
                ranges.lock().unwrap().push(first..first + ep.len());
                ep.len() as u64
            },
        );
        assert_eq!(handed, n as u64);
        // the chunks' ranges of ids cover the patches once each
        let mut ranges = ranges.into_inner().unwrap();
        ranges.sort_by_key(|r| r.start);
        assert_eq!(ranges.first().map(|r| r.start), Some(0));
        assert_eq!(ranges.last().map(|r| r.end), Some(n));
        assert!(ranges.windows(2).all(|w| w[0].end == w[1].start));
        let bits = |v: &[Rgb]| {
            v.iter()
                .map(|x| x.to_array().map(f32::to_bits))
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&out.e_plus), bits(&whole.e_plus));
        assert_eq!(bits(&out.e_minus), bits(&whole.e_minus));
        assert_eq!(bits(&a), bits(&whole.e_plus));
        assert_eq!(bits(&b), bits(&whole.e_minus));
        assert_eq!(out.fragments, whole.fragments);
        assert!(whole.e_plus.iter().any(|e| *e != Rgb::ZERO));
    }
}

/// The fused transfer skips the dark patches (L^e all +0) that received
/// nothing, writing +0: what the paper's operator gives them, bit for bit.
#[test]
fn dark_patches_that_received_nothing_send_zero() {
    let world = cbox();
    let patches = Patches::build(&world.scene, &world.lights, 40.0);
    let mut rng = Pcg32::keyed(&[13, 0]);
    let mut dark = 0;
    for p in &patches.p {
        if !p.le.to_array().iter().all(|c| c.to_bits() == 0) {
            continue;
        }
        dark += 1;
        for _ in 0..8 {
            let (d, w) = (uniform_sphere(rng.next_2d()), uniform_sphere(rng.next_2d()));
            for (ep, em) in [(Rgb::ZERO, Rgb::ZERO), (Rgb::splat(-0.0), Rgb::ZERO)] {
                for w in [w, -w] {
                    let l = reflect_onto(p.le(w), p, d, ep, em, w);
                    assert_eq!(l.to_array().map(f32::to_bits), [0; 3]);
                }
            }
        }
    }
    assert!(dark > 0 && dark < patches.len());
}
