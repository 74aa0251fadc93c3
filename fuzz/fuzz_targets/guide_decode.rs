//! Any bytes as a path guide, as a worker would receive one (issue #60): decoding succeeds or
//! gives an error, never panics; a guide that decodes samples finite directions with finite,
//! non-negative densities at any point, samples its guide with a probability below 1 (the
//! cosine lobe's share is what keeps a guided estimate unbiased), refines, and encodes back to
//! the same bytes.
#![no_main]

use glam::{Vec2, Vec3A};
use libfuzzer_sys::fuzz_target;
use tessera_render::guide::{SdTree, ALPHAS};

fuzz_target!(|data: &[u8]| {
    let Ok(guide) = SdTree::decode(data) else {
        return;
    };
    assert_eq!(guide.encode(), data);
    for (i, p) in [Vec3A::ZERO, Vec3A::splat(1e30), Vec3A::splat(-0.5)]
        .into_iter()
        .enumerate()
    {
        let u = Vec2::new(0.1 + 0.3 * i as f32, 0.999_999);
        let (d, pdf) = guide.at(p).sample(u);
        assert!(d.is_finite() && pdf.is_finite() && pdf >= 0.0);
        let again = guide.at(p).pdf(d);
        assert!(again.is_finite() && again >= 0.0);
        let alpha = guide.alpha_at(p).1;
        assert!(ALPHAS.contains(&alpha) && alpha < 1.0, "{alpha}");
    }
    assert!(guide
        .second_moment_ratio()
        .is_none_or(|r| r.is_finite() && r >= 0.0));
    let next = guide.refined(1000, 0.01);
    assert!(SdTree::decode(&next.encode()).is_ok());
});
